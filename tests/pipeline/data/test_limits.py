"""Read-time limits (bt_pipeline.data.limits): absurd but format-valid files are one clear error.

Each case once made a later stage hang or crash; here each must be refused by the reader with a
message naming the file, the demo and the value.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np
import pytest

from bt_pipeline.cli import main
from bt_pipeline.data.limits import ReadLimits
from bt_pipeline.data.recording import read_recording, write_recording
from bt_pipeline.data.records import Recording
from bt_pipeline.exceptions import ConfigError, RecordingError


@pytest.fixture
def example(tmp_path: Path, make_recording: Callable[..., Recording]) -> Path:
    return write_recording(tmp_path / "ex.hdf5", make_recording(n_demos=3, n_samples=40))


def _edit(path: Path, edit: Callable[[h5py.File], None]) -> Path:
    with h5py.File(path, "r+") as file:
        edit(file)
    return path


def _set(path: Path, key: str, index: tuple[int, ...] | slice, value: float) -> None:
    def edit(file: h5py.File) -> None:
        dataset = file[key]
        assert isinstance(dataset, h5py.Dataset)
        data = dataset[()]
        data[index] = value
        dataset[...] = data

    _edit(path, edit)


@pytest.mark.parametrize("value", [1e30, -1e300, 10.5])
def test_a_position_beyond_the_bound_names_file_demo_and_sample(example, value) -> None:
    origin = np.asarray(read_recording(example).plane.origin)
    _set(example, "data/demo_1/obs/ee_pos", (7, 0), origin[0] + value)
    with pytest.raises(RecordingError) as info:
        read_recording(example)
    message = str(info.value)
    assert message.startswith(f"{example}: demo_1: obs/ee_pos[7]")
    assert "at most 10 m" in message


def test_the_position_bound_is_configurable(example) -> None:
    origin = np.asarray(read_recording(example).plane.origin)
    _set(example, "data/demo_0/obs/ee_pos", (3, 1), origin[1] + 15.0)
    with pytest.raises(RecordingError, match="demo_0"):
        read_recording(example)
    assert read_recording(example, ReadLimits(max_distance_m=20.0)).demos["demo_0"]
    with pytest.raises(ConfigError, match="max_distance_m"):
        ReadLimits(max_distance_m=0.0)


@pytest.mark.parametrize(
    ("attr", "value", "expected"),
    [
        ("rho", 1e-300, "attr rho is 1e-300"),
        ("rho", 1e308, "attr rho is 1e\\+308"),
        ("rho", 1e300, "attr rho"),
        ("theta_deg", 1e12, "attr theta_deg"),
    ],
)
def test_preferences_out_of_physical_range_are_refused(example, attr, value, expected) -> None:
    _edit(example, lambda f: f["data/demo_2"].attrs.__setitem__(attr, value))
    with pytest.raises(RecordingError, match=f"demo_2: {expected}"):
        read_recording(example)


def test_unknown_preferences_stay_allowed(example) -> None:
    _edit(example, lambda f: f["data/demo_0"].attrs.__setitem__("rho", np.nan))
    assert np.isnan(read_recording(example).demos["demo_0"].rho)


def test_a_far_plane_origin_is_refused(example) -> None:
    _edit(example, lambda f: f["data"].attrs.__setitem__("plane_origin", [1e30, 0.0, 0.0]))
    with pytest.raises(RecordingError, match=r"plane_origin is 1e\+30 m from the world origin"):
        read_recording(example)


def test_a_huge_time_gap_is_refused(example) -> None:
    def edit(file: h5py.File) -> None:
        dataset = file["data/demo_1/timestamps"]
        assert isinstance(dataset, h5py.Dataset)
        dataset[...] = np.arange(40) * 0.02 + np.where(np.arange(40) >= 20, 5000.0, 0.0)

    _edit(example, edit)
    with pytest.raises(RecordingError, match="demo_1: timestamps jump by 5e\\+03 s between"):
        read_recording(example)


def test_too_many_samples_are_refused_before_loading(example) -> None:
    with pytest.raises(RecordingError, match="demo_0 has 40 samples; at most 30 are read"):
        read_recording(example, ReadLimits(max_samples=30))
    # An attr that lies about the length: the dataset's shape is checked before it is loaded.
    _edit(example, lambda f: f["data/demo_0"].attrs.__setitem__("num_samples", 20))
    with pytest.raises(RecordingError, match=r"obs/ee_pos has shape \(40, 3\); at most 30"):
        read_recording(example, ReadLimits(max_samples=30))


def test_nul_bytes_and_invalid_utf8_in_text_are_refused(example, tmp_path) -> None:
    nul = np.bytes_(b"al\x00ice")  # fixed-length: h5py's variable-length strings refuse NUL
    _edit(example, lambda f: f["data/demo_1"].attrs.__setitem__("demonstrator", nul))
    with pytest.raises(RecordingError, match="demo_1: attr 'demonstrator' contains a NUL byte"):
        read_recording(example)
    bad = np.bytes_(b"al\xffice")
    _edit(example, lambda f: f["data/demo_1"].attrs.__setitem__("demonstrator", bad))
    with pytest.raises(RecordingError, match="demonstrator' is not valid UTF-8 \\(byte 2"):
        read_recording(example)


def test_the_writer_refuses_nul_text_before_any_work(tmp_path, make_recording) -> None:
    recording = make_recording(n_demos=1)
    demo = dataclasses.replace(recording.demos["demo_0"], demonstrator="bad\x00name")
    bad = dataclasses.replace(recording, demos={"demo_0": demo})
    with pytest.raises(RecordingError, match=r"cannot write .*demonstrator contains a NUL"):
        write_recording(tmp_path / "out.hdf5", bad)
    assert not (tmp_path / "out.hdf5").exists()


def test_an_absurd_demo_index_is_refused(example) -> None:
    huge = "demo_" + "7" * 5000
    _edit(example, lambda f: f.move("data/demo_2", f"data/{huge}"))
    with pytest.raises(RecordingError, match="has an index of 5000 digits; at most 9"):
        read_recording(example)


def test_bt_clean_on_a_huge_value_exits_2_with_one_line(example, capsys) -> None:
    origin = np.asarray(read_recording(example).plane.origin)
    _set(example, "data/demo_0/obs/ee_pos", (1, 2), origin[2] + 1e30)
    with pytest.raises(SystemExit) as exit_:
        main(["clean", str(example), "--out", str(example.parent / "out"), "--strict"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"bt: error: {example}: demo_0: obs/ee_pos[1]")
    assert not (example.parent / "out").exists()
