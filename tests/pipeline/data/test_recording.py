"""Tests of bt_pipeline.data.recording: format v1 round trip, atomic writes, every malformed
input."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import os
import pickle
import re
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, cast

import h5py
import numpy as np
import pytest

import bt_pipeline.data.recording
from bt_pipeline.data.paths import expand_paths
from bt_pipeline.data.recording import read_recording, read_recordings, write_recording
from bt_pipeline.data.records import DemoRecord, Recording, forward_difference_actions
from bt_pipeline.exceptions import RecordingError

MakeRecording = Callable[..., Recording]
WriteExample = Callable[..., Path]
Editor = Callable[[h5py.File], object]
"""Edits a valid file in place to make it malformed."""
REPO_ROOT = Path(bt_pipeline.data.recording.__file__).resolve().parents[1]


def _array(group: h5py.Group, key: str) -> np.ndarray:
    dataset = group[key]
    assert isinstance(dataset, h5py.Dataset)
    return np.asarray(dataset[()])


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _assert_same_demo(got: DemoRecord, want: DemoRecord) -> None:
    for field in ("ee_pos", "timestamps", "ee_quat", "joint_pos", "gripper", "states"):
        want_value = getattr(want, field)
        if want_value is None:
            assert getattr(got, field) is None, field
        else:
            np.testing.assert_array_equal(getattr(got, field), want_value, err_msg=field)
            assert getattr(got, field).dtype == np.float64
    np.testing.assert_array_equal(got.resolved_actions(), want.resolved_actions())
    assert got.demonstrator == want.demonstrator
    assert got.source == want.source
    assert got.created == want.created
    assert got.ep_meta == want.ep_meta
    for key in ("theta_deg", "rho"):
        a, b = getattr(got, key), getattr(want, key)
        assert (math.isnan(a) and math.isnan(b)) or a == b, key
    assert got.attrs.keys() == want.attrs.keys()
    for key, value in want.attrs.items():
        assert got.attrs[key] == value, key
        assert type(got.attrs[key]) is type(value), key


# --- round trip -------------------------------------------------------------------------------


def test_round_trip_keeps_every_array_and_attr(make_recording: MakeRecording, tmp_path: Path):
    recording = make_recording(
        task="weaving",
        optional=True,
        masks={"train": ["demo_0", "demo_2"], "valid": ["demo_1"], "empty": []},
        attrs={"best_file": "runs/a.hdf5", "weights": np.array([0.2, 0.8]), "n_runs": 4},
    )
    path = write_recording(tmp_path / "r.hdf5", recording)
    got = read_recording(path)

    assert got.path == path
    assert got.task == "weaving"
    np.testing.assert_array_equal(got.plane.origin, recording.plane.origin)
    np.testing.assert_array_equal(got.plane.axes, recording.plane.axes)
    assert got.env_args == recording.env_args
    assert got.masks == recording.masks
    assert got.attrs["best_file"] == "runs/a.hdf5"
    assert got.attrs["n_runs"] == 4
    np.testing.assert_array_equal(got.attrs["weights"], [0.2, 0.8])
    assert list(got.demos) == ["demo_0", "demo_1", "demo_2"]
    for name, demo in recording.demos.items():
        _assert_same_demo(got.demos[name], demo)
    assert got.total == 150


def test_actions_are_forward_difference_unless_given(make_recording: MakeRecording, tmp_path):
    recording = make_recording(n_demos=2)
    given = np.random.default_rng(3).standard_normal((50, 3))
    given[-1] = 0.0
    demos = dict(recording.demos)
    demos["demo_1"] = dataclasses.replace(demos["demo_1"], actions=given)
    path = write_recording(tmp_path / "a.hdf5", dataclasses.replace(recording, demos=demos))
    with h5py.File(path, "r") as file:
        first = file["data/demo_0"]
        assert isinstance(first, h5py.Group)
        actions = np.asarray(first["actions"])
        expected = forward_difference_actions(
            _array(first, "obs/ee_pos"), _array(first, "timestamps")
        )
        np.testing.assert_allclose(actions, expected)
        np.testing.assert_array_equal(actions[-1], 0.0)
        np.testing.assert_array_equal(_array(file, "data/demo_1/actions"), given)


def test_demos_sort_by_integer_index(make_recording: MakeRecording, tmp_path: Path):
    path = write_recording(tmp_path / "many.hdf5", make_recording(n_demos=12, n_samples=20))
    assert list(read_recording(path).demos) == [f"demo_{k}" for k in range(12)]


def test_robomimic_style_access(make_recording: MakeRecording, tmp_path: Path):
    """What robomimic's SequenceDataset and FileUtils do with a dataset, step by step."""
    recording = make_recording(n_demos=11, n_samples=20, masks={"train": ["demo_10", "demo_3"]})
    path = write_recording(tmp_path / "r.hdf5", recording)
    with h5py.File(path, "r", swmr=True, libver="latest") as file:
        data = file["data"]
        assert isinstance(data, h5py.Group)
        env_meta = json.loads(str(data.attrs["env_args"]))
        assert set(env_meta) == {"env_name", "type", "env_kwargs"}
        demos = list(data.keys())
        demos = [demos[i] for i in np.argsort([int(name[5:]) for name in demos])]
        assert demos[-2:] == ["demo_9", "demo_10"]
        lengths = [int(cast(Any, data[name]).attrs["num_samples"]) for name in demos]
        assert sum(lengths) == int(cast(Any, data.attrs["total"])) == 220
        mask = [name.decode("utf-8") for name in _array(file, "mask/train")]
        assert mask == ["demo_10", "demo_3"]
        assert _array(file, "data/demo_10/obs/ee_pos").shape == (20, 3)
        assert _array(file, "data/demo_10/actions").shape == (20, 3)


def test_float32_data_and_foreign_datasets_are_read(write_example_file: WriteExample, tmp_path):
    path = write_example_file(tmp_path)
    with h5py.File(path, "r+") as file:
        ee_pos = _array(file, "data/demo_0/obs/ee_pos")
        del file["data/demo_0/obs/ee_pos"]
        file["data/demo_0/obs/ee_pos"] = ee_pos.astype(np.float32)
        file["data/demo_0/rewards"] = np.zeros(50)
    demo = read_recording(path).demos["demo_0"]
    assert demo.ee_pos.dtype == np.float64
    np.testing.assert_allclose(demo.ee_pos, ee_pos, atol=1e-6)


def test_reading_never_modifies_the_file(write_example_file: WriteExample, tmp_path: Path):
    path = write_example_file(tmp_path)
    path.chmod(0o444)
    before = (_digest(path), path.stat().st_mtime_ns)
    read_recording(path)
    read_recordings([path, path])
    assert (_digest(path), path.stat().st_mtime_ns) == before


# --- writing ----------------------------------------------------------------------------------


def test_existing_destination_is_kept_unless_overwrite(make_recording: MakeRecording, tmp_path):
    path = write_recording(tmp_path / "r.hdf5", make_recording(n_demos=2))
    old = _digest(path)
    with pytest.raises(RecordingError, match=r"r\.hdf5: the file exists; .*overwrite=True"):
        write_recording(path, make_recording(n_demos=3))
    assert _digest(path) == old
    write_recording(path, make_recording(n_demos=3), overwrite=True)
    assert len(read_recording(path).demos) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.hdf5"]


def test_write_creates_parent_folders(make_recording: MakeRecording, tmp_path: Path):
    path = write_recording(tmp_path / "a" / "b" / "r.hdf5", make_recording())
    assert path.is_file()


def _with_demo(recording: Recording, **changes: Any) -> Recording:
    demos = dict(recording.demos)
    demos["demo_1"] = dataclasses.replace(demos["demo_1"], **changes)
    return dataclasses.replace(recording, demos=demos)


def _rename_demo(recording: Recording) -> Recording:
    demos = dict(recording.demos)
    demos["demo_a"] = demos.pop("demo_1")
    return dataclasses.replace(recording, demos=demos)


INVALID_IN_MEMORY: list[tuple[str, Callable[[Recording], Recording], str]] = [
    ("short", lambda r: _with_demo(r, ee_pos=r.demos["demo_1"].ee_pos[:2],
                                   timestamps=r.demos["demo_1"].timestamps[:2]),
     "demo_1 has 2 samples; at least 16 are needed"),
    ("task", lambda r: dataclasses.replace(r, task="../mopping"),
     r"task: invalid task name '\.\./mopping'; a task name is 1-64 characters"),
    ("source", lambda r: _with_demo(r, source=cast(Any, "dream")),
     "demo_1: unknown source 'dream'; valid sources are teleop, synthetic, import"),
    ("int dtype", lambda r: _with_demo(r, ee_pos=np.ones((50, 3), dtype=np.int64)),
     "demo_1: obs/ee_pos has dtype int64; expected float64"),
    ("nan", lambda r: _with_demo(r, ee_pos=np.full((50, 3), np.nan)),
     "demo_1: obs/ee_pos has NaN or infinite values"),
    ("timestamps", lambda r: _with_demo(r, timestamps=np.zeros(50)),
     r"demo_1: timestamps must be strictly increasing; timestamps\[1\]"),
    ("actions", lambda r: _with_demo(r, actions=np.ones((50, 3))),
     "demo_1: the last row of actions must be 0"),
    ("rho", lambda r: _with_demo(r, rho=-1.0), "demo_1: attr rho must be positive"),
    ("created", lambda r: _with_demo(r, created="yesterday"),
     "demo_1: attr created must be an ISO"),
    ("ep_meta", lambda r: _with_demo(r, ep_meta={"x": object()}),
     "demo_1: ep_meta cannot be stored as JSON"),
    ("reserved attr", lambda r: _with_demo(r, attrs={"num_samples": 3}),
     "demo_1: extra attr 'num_samples' clashes with a format v1 attr"),
    ("dict attr", lambda r: dataclasses.replace(r, attrs={"cfg": {"a": 1}}),
     "/data: attr 'cfg' has unsupported value of type dict"),
    ("name", _rename_demo, "'demo_a' is not a valid demo name"),
    ("mask", lambda r: dataclasses.replace(r, masks={"train": ["demo_9"]}),
     "mask 'train' names 'demo_9', which is not a demo of this file"),
    ("env_args", lambda r: dataclasses.replace(r, env_args={"env_name": "x"}),
     "env_args lacks type, env_kwargs"),
    ("no demos", lambda r: dataclasses.replace(r, demos={}), "no demos under /data"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("change", "message"),
    [(c, m) for _, c, m in INVALID_IN_MEMORY],
    ids=[i for i, _, _ in INVALID_IN_MEMORY],
)
def test_invalid_recording_is_not_written(
    make_recording: MakeRecording, tmp_path: Path, change, message: str
):
    path = tmp_path / "bad.hdf5"
    with pytest.raises(RecordingError, match=message) as info:
        write_recording(path, change(make_recording()))
    assert str(info.value).startswith(f"cannot write {path}: ")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("error", [RuntimeError, KeyboardInterrupt])
@pytest.mark.parametrize("existing", [False, True])
def test_exception_mid_write_leaves_no_trace(
    make_recording: MakeRecording,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    error: type[BaseException],
    existing: bool,
):
    path = tmp_path / "r.hdf5"
    old = _digest(write_recording(path, make_recording(n_demos=2))) if existing else None
    original = h5py.Group.create_dataset
    calls = []

    def failing_create_dataset(self, *args: Any, **kwargs: Any) -> Any:
        calls.append(args[0])
        if len(calls) == 4:
            temps = list(tmp_path.glob(".r.hdf5.tmp-*"))
            assert len(temps) == 1 and temps[0].stat().st_size > 0  # really mid-write
            raise error("interrupted")
        return original(self, *args, **kwargs)

    monkeypatch.setattr(h5py.Group, "create_dataset", failing_create_dataset)
    with pytest.raises(error, match="interrupted"):
        write_recording(path, make_recording(), overwrite=True)
    assert len(calls) == 4
    assert [p.name for p in tmp_path.iterdir()] == (["r.hdf5"] if existing else [])
    if existing:
        assert _digest(path) == old


def test_failed_rename_leaves_no_temp_file(
    make_recording: MakeRecording, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    def no_link(src: Any, dst: Any) -> None:
        raise PermissionError("read-only folder")

    monkeypatch.setattr(os, "link", no_link)
    monkeypatch.setattr(os, "replace", no_link)
    with pytest.raises(PermissionError):
        write_recording(tmp_path / "r.hdf5", make_recording())
    assert list(tmp_path.iterdir()) == []


WRITER_SCRIPT = """
import os, pickle, sys, time
import h5py
from bt_pipeline.data.recording import write_recording

recording_file, destination, stall_at, overwrite = sys.argv[1:]


def stall(*args, **kwargs):
    print("stalled", flush=True)
    time.sleep(600)


if stall_at == "dataset":
    original = h5py.Group.create_dataset
    calls = []

    def create_dataset(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 7:
            stall()
        return original(self, *args, **kwargs)

    h5py.Group.create_dataset = create_dataset
elif stall_at == "flush":
    h5py.File.flush = stall
elif stall_at == "rename":
    os.replace = os.link = stall
with open(recording_file, "rb") as fh:
    recording = pickle.load(fh)
write_recording(destination, recording, overwrite=overwrite == "1")
print("finished", flush=True)
"""


@pytest.mark.parametrize(
    ("stall_at", "existing"),
    [("dataset", False), ("flush", False), ("rename", False), ("dataset", True), ("rename", True)],
)
def test_killed_writer_never_leaves_a_partial_file(
    make_recording: MakeRecording, tmp_path: Path, stall_at: str, existing: bool
):
    """A writer killed with SIGKILL while writing leaves the destination as it was."""
    out = tmp_path / "out"
    destination = out / "r.hdf5"
    old = None
    if existing:
        old = _digest(write_recording(destination, make_recording(n_demos=2)))
    script, recording_file = tmp_path / "writer.py", tmp_path / "recording.pkl"
    script.write_text(WRITER_SCRIPT)
    recording_file.write_bytes(pickle.dumps(make_recording(n_demos=20, n_samples=200)))
    python_path = os.pathsep.join([str(REPO_ROOT), os.environ.get("PYTHONPATH", "")])
    env = {**os.environ, "PYTHONPATH": python_path}
    args = [str(script), str(recording_file), str(destination), stall_at, "1" if existing else "0"]
    proc = subprocess.Popen(
        [sys.executable, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line == "stalled\n", f"writer did not stall: {line!r} {proc.stderr}"
        temps = list(out.glob(".r.hdf5.tmp-*"))
        assert len(temps) == 1 and temps[0].stat().st_size > 0
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    if existing:
        assert _digest(destination) == old
        assert len(read_recording(destination).demos) == 2
        assert expand_paths([out]) == [destination]  # the stray temp file is not a recording
    else:
        assert not destination.exists()
        with pytest.raises(RecordingError, match="no recordings found"):
            expand_paths([out])


# --- malformed files --------------------------------------------------------------------------


def _replace(file: h5py.File, key: str, value: Any) -> None:
    del file[key]
    file[key] = value


def _shorten_demo_2(file: h5py.File) -> None:
    for key in ("obs/ee_pos", "actions", "timestamps"):
        _replace(file, f"data/demo_2/{key}", _array(file, f"data/demo_2/{key}")[:2])
    file["data/demo_2"].attrs["num_samples"] = 2
    file["data"].attrs["total"] = 102


def _set_attr(key: str, value: Any, group: str = "data/demo_1") -> Editor:
    def edit(file: h5py.File) -> None:
        file[group].attrs[key] = value

    return edit


def _del(key: str) -> Editor:
    def edit(file: h5py.File) -> None:
        if key.startswith("@"):
            group, attr = key[1:].rsplit("@", 1)
            del file[group].attrs[attr]
        else:
            del file[key]

    return edit


def _set_data(key: str, change: Callable[[np.ndarray], np.ndarray]) -> Editor:
    def edit(file: h5py.File) -> None:
        _replace(file, key, change(_array(file, key)))

    return edit


def _with(array: np.ndarray, index: Any, value: float) -> np.ndarray:
    array[index] = value
    return array


def _rename(old: str, new: str) -> Editor:
    def edit(file: h5py.File) -> None:
        file.move(old, new)

    return edit


def _no_demos(file: h5py.File) -> None:
    data = file["data"]
    assert isinstance(data, h5py.Group)
    for name in list(data):
        del data[name]


def _obs_as_group(file: h5py.File) -> None:
    data = _array(file, "data/demo_1/obs/ee_pos")
    del file["data/demo_1/obs/ee_pos"]
    file.create_group("data/demo_1/obs/ee_pos").create_dataset("x", data=data)


MALFORMED: list[tuple[str, Editor, str]] = [
    ("no data", _del("data"), "missing group /data; not a bt recording"),
    ("no ee_pos", _del("data/demo_1/obs/ee_pos"), "demo_1: missing dataset obs/ee_pos"),
    ("no actions", _del("data/demo_1/actions"), "demo_1: missing dataset actions"),
    ("no timestamps", _del("data/demo_1/timestamps"), "demo_1: missing dataset timestamps"),
    ("ee_pos group", _obs_as_group, "demo_1: obs/ee_pos is a group; expected a dataset"),
    ("no source", _del("@data/demo_1@source"), "demo_1: missing attr 'source'"),
    ("no num_samples", _del("@data/demo_1@num_samples"), "demo_1: missing attr 'num_samples'"),
    ("no total", _del("@data@total"), "/data: missing attr 'total'"),
    ("no plane", _del("@data@plane_axes"), "/data: missing attr 'plane_axes'"),
    ("format", _set_attr("format", "robomimic", "data"),
     "format is 'robomimic'; expected 'bt-demos'"),
    ("version", _set_attr("format_version", 2, "data"),
     "format_version 2 is not supported; this bt reads format_version 1"),
    ("version type", _set_attr("format_version", "1", "data"),
     "'format_version' must be an integer"),
    ("task", _set_attr("task", "mop ping", "data"),
     "attr task: invalid task name 'mop ping'; a task name is 1-64 characters"),
    ("source", _set_attr("source", "dream"),
     "demo_1: unknown source 'dream'; valid sources are teleop, synthetic, import"),
    ("theta type", _set_attr("theta_deg", "ten"), "demo_1: attr theta_deg must be a number"),
    ("theta inf", _set_attr("theta_deg", np.inf), "demo_1: attr theta_deg must be a finite number"),
    ("created", _set_attr("created", "last tuesday"), "demo_1: attr created must be an ISO 8601"),
    ("shape", _set_data("data/demo_1/obs/ee_pos", lambda a: a[:, :2]),
     r"demo_1: obs/ee_pos has shape \(50, 2\); expected \(T, 3\)"),
    ("rows", _set_data("data/demo_1/actions", lambda a: a[:-1]),
     r"demo_1: actions has shape \(49, 3\); expected \(50, 3\)"),
    ("states rows", _set_data("data/demo_1/states", lambda a: a[:-3]),
     r"demo_1: states has shape \(47, 23\); expected \(50, S\)"),
    ("quat width", _set_data("data/demo_1/obs/ee_quat", lambda a: a[:, :3]),
     r"demo_1: obs/ee_quat has shape \(50, 3\); expected \(50, 4\)"),
    ("dtype", _set_data("data/demo_1/timestamps", lambda a: (a * 1000).astype(np.int64)),
     "demo_1: timestamps has dtype int64; expected float64"),
    ("string data", _set_data("data/demo_1/obs/ee_pos", lambda a: a.astype("S8")),
     "demo_1: obs/ee_pos has dtype |S8; expected float64"),
    ("nan", _set_data("data/demo_1/obs/ee_pos", lambda a: _with(a, (7, 1), np.nan)),
     r"demo_1: obs/ee_pos has NaN or infinite values \(first at index \(7, 1\)\)"),
    ("inf", _set_data("data/demo_1/actions", lambda a: _with(a, (3, 0), np.inf)),
     r"demo_1: actions has NaN or infinite values \(first at index \(3, 0\)\)"),
    ("timestamps", _set_data("data/demo_1/timestamps", lambda a: _with(a, 10, a[9])),
     r"demo_1: timestamps must be strictly increasing; timestamps\[10\] = .* is not after "
     r"timestamps\[9\]"),
    ("last action", _set_data("data/demo_1/actions", lambda a: _with(a, -1, 1.0)),
     "demo_1: the last row of actions must be 0"),
    ("few samples", _shorten_demo_2, "demo_2 has 2 samples; at least 16 are needed"),
    ("num_samples", _set_attr("num_samples", 48),
     "demo_1: attr num_samples is 48 but obs/ee_pos has 50 rows"),
    ("total", _set_attr("total", 10, "data"), "/data: attr total is 10 but the demos hold 150"),
    ("axes", _set_attr("plane_axes", np.array([[1.0, 0, 0], [1.0, 1.0, 0]]), "data"),
     "plane_axes must hold two orthonormal rows"),
    ("origin", _set_attr("plane_origin", np.zeros(2), "data"),
     r"plane_origin has shape \(2,\) and dtype float64; expected shape \(3,\)"),
    ("env_args json", _set_attr("env_args", "{env_name: x", "data"),
     "/data: attr env_args is not valid JSON"),
    ("env_args keys", _set_attr("env_args", '{"env_name": "x"}', "data"),
     "env_args lacks type, env_kwargs"),
    ("ep_meta json", _set_attr("ep_meta", "{'a': 1}"), "demo_1: attr ep_meta is not valid JSON"),
    ("ep_meta list", _set_attr("ep_meta", "[1, 2]"), "demo_1: attr ep_meta must be a JSON object"),
    ("demo name", _rename("data/demo_1", "data/episode_1"), "'episode_1' is not a valid demo name"),
    ("same index", _rename("data/demo_1", "data/demo_00"),
     "demo_0 and demo_00 have the same index 0"),
    ("no demos", _no_demos, "no demos under /data; at least one demo_<k> is needed"),
    ("mask member", lambda f: f.create_dataset("mask/x", data=np.array([b"demo_7"])),
     "mask 'x' names 'demo_7', which is not a demo of this file"),
    ("mask dtype", lambda f: f.create_dataset("mask/x", data=np.arange(3)),
     "/mask/x must be a 1-D dataset of demo names as byte strings"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("edit", "message"), [(e, m) for _, e, m in MALFORMED], ids=[i for i, _, _ in MALFORMED]
)
def test_malformed_file_gives_one_clear_error(
    make_recording: MakeRecording, tmp_path: Path, edit: Editor, message: str
):
    path = write_recording(tmp_path / "bad.hdf5", make_recording(optional=True))
    with h5py.File(path, "r+") as file:
        edit(file)
    with pytest.raises(RecordingError, match=message) as info:
        read_recording(path)
    assert str(info.value).startswith(f"{path}: ")


def test_missing_file(tmp_path: Path):
    with pytest.raises(RecordingError, match=r"nope\.hdf5: no such file"):
        read_recording(tmp_path / "nope.hdf5")


def test_directory_is_not_a_file(tmp_path: Path):
    with pytest.raises(RecordingError, match="is a directory"):
        read_recording(tmp_path)


def test_not_hdf5(tmp_path: Path):
    path = tmp_path / "notes.hdf5"
    path.write_bytes(b"these are not the demos you are looking for\n" * 20)
    with pytest.raises(RecordingError, match=r"notes\.hdf5: not an HDF5 file"):
        read_recording(path)


@pytest.mark.parametrize("keep", [0.3, 0.6, 0.95])
def test_truncated_file(write_example_file: WriteExample, tmp_path: Path, keep: float):
    path = write_example_file(tmp_path, optional=True)
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(RecordingError, match=r"example\.hdf5: .*truncated or corrupt"):
        read_recording(path)


def test_corrupt_bytes_inside_a_dataset(write_example_file: WriteExample, tmp_path: Path):
    path = write_example_file(tmp_path)
    with h5py.File(path, "r") as file:
        header = file["data/demo_1/obs/ee_pos"].id.get_offset()
    assert header is not None
    raw = bytearray(path.read_bytes())
    raw[header - 400 : header] = b"\xff" * 400  # object headers just before the data
    path.write_bytes(bytes(raw))
    with pytest.raises(RecordingError, match=r"example\.hdf5: "):
        read_recording(path)


# --- several files ----------------------------------------------------------------------------


def test_expand_paths_file_dir_glob(write_example_file: WriteExample, tmp_path: Path):
    a = write_example_file(tmp_path / "runs", "b.hdf5")
    b = write_example_file(tmp_path / "runs" / "day2", "a.h5")
    c = write_example_file(tmp_path / "other", "c.hdf5")
    (tmp_path / "runs" / "notes.txt").write_text("not a recording")
    (tmp_path / "runs" / ".hidden").mkdir()
    write_example_file(tmp_path / "runs" / ".hidden", "x.hdf5")

    assert expand_paths([a]) == [a]
    assert expand_paths([tmp_path / "runs"]) == [a, b]  # sorted by path parts: b.hdf5 < day2/
    assert expand_paths([str(tmp_path / "**" / "*.hdf5")]) == [c, a]
    assert expand_paths([str(tmp_path / "**" / "*.h*")]) == [c, a, b]
    assert expand_paths([c, tmp_path / "runs", a, str(tmp_path / "other" / "*")]) == [c, a, b]


def test_expand_paths_without_match(tmp_path: Path):
    for item in (tmp_path / "missing.hdf5", str(tmp_path / "*.hdf5"), tmp_path):
        with pytest.raises(RecordingError, match=re.escape(f"no recordings found at '{item}'")):
            expand_paths([item])


def test_read_recordings_strict_and_lenient(
    write_example_file: WriteExample, tmp_path: Path, caplog: pytest.LogCaptureFixture
):
    good = write_example_file(tmp_path, "good.hdf5", task="pick_and_place")
    bad = tmp_path / "bad.hdf5"
    bad.write_bytes(b"\x00" * 100)
    with pytest.raises(RecordingError, match=r"bad\.hdf5: not an HDF5 file"):
        read_recordings([good, bad])
    with caplog.at_level(logging.WARNING, logger="bt"):
        recordings = read_recordings([bad, good], strict=False)
    assert [r.path for r in recordings] == [good]
    assert recordings[0].task == "pick_and_place"
    [record] = caplog.records
    assert record.name == "bt" and record.levelno == logging.WARNING
    assert f"skipping {bad}: not an HDF5 file" in record.getMessage()
