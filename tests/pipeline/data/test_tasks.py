"""Task names: any safe name is a task; three tasks have a built-in guide, plane and scene."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.recording import read_recording, write_recording
from bt_pipeline.data.shapes import SHAPE_SIZE, canonical_loop, canonical_shape
from bt_pipeline.data.tasks import (
    MAX_TASK_CHARS,
    TASKS,
    default_plane,
    has_guide,
    is_task_name,
    parse_guided_task,
    parse_task,
)
from bt_pipeline.data.validate import check_recording
from bt_pipeline.exceptions import ConfigError, RecordingError, UnknownTaskError
from tests.conftest import build_recording
from tests.pipeline.conftest import STIRRING_PLANE, write_stirring_file

VALID = ["stirring", "scrubbing", "buffing", "pick_and_place", "D-shape", "9", "x" * MAX_TASK_CHARS]
HOSTILE = [
    "../x",
    "a/b",
    "",
    "x" * (MAX_TASK_CHARS + 1),
    "a b",
    "a\x00b",
    "\x00",
    ".",
    "..",
    ".hidden",
    "stirring.cleaned",
    "-rf",
    "_x",
    "a\\b",
    "stirring\n",
    "Zoë",
]


@pytest.mark.parametrize("name", VALID)
def test_any_safe_name_is_a_task(name: str) -> None:
    assert parse_task(name) == name
    assert is_task_name(name)


@pytest.mark.parametrize("name", HOSTILE)
def test_hostile_names_are_refused_with_the_rule(name: str) -> None:
    assert not is_task_name(name)
    with pytest.raises(UnknownTaskError) as info:
        parse_task(name)
    message = str(info.value)
    assert message.startswith("invalid task name ")
    assert "a task name is 1-64 characters of letters, digits, '_' and '-'" in message
    assert "\n" not in message and "\x00" not in message  # one printable line
    assert len(message) < 300


def test_non_strings_are_refused() -> None:
    for value in (None, 3, b"wiping", ["wiping"]):
        assert not is_task_name(value)
        with pytest.raises(UnknownTaskError, match="not a string"):
            parse_task(value)


def test_a_very_long_name_is_not_echoed_whole() -> None:
    with pytest.raises(UnknownTaskError, match=r"\(100000 characters\)") as info:
        parse_task("a" * 100_000)
    assert len(str(info.value)) < 300


def test_the_three_guided_tasks_and_nothing_else() -> None:
    assert TASKS == ("wiping", "weaving", "pick_and_place")
    for task in TASKS:
        assert has_guide(task) and parse_guided_task(task) == task
    for name in ("stirring", "Wiping", "wiping_", "../wiping", ""):
        assert not has_guide(name)
        with pytest.raises(UnknownTaskError, match="valid tasks are wiping, weaving, pick_and"):
            parse_guided_task(name)
    with pytest.raises(UnknownTaskError, match="has no built-in guide and scene"):
        parse_guided_task("stirring")


def test_default_planes_exist_for_the_three_only() -> None:
    for task in TASKS:
        plane = default_plane(task)
        np.testing.assert_allclose(plane.axes @ plane.axes.T, np.eye(2), atol=1e-12)
    with pytest.raises(UnknownTaskError, match=r"no default task plane.*--plane auto"):
        default_plane("stirring")


def test_guide_shapes_exist_for_the_three_only() -> None:
    phase = np.linspace(0.0, 2.0 * np.pi, 7)
    # The three shapes at a few phases, as defined (module doc of shapes.py).
    np.testing.assert_allclose(
        canonical_shape("weaving", [0.0, np.pi / 2]), [[0, 0], [0.15, 0]], atol=1e-15
    )
    np.testing.assert_allclose(
        canonical_shape("wiping", [0.0])[0], [SHAPE_SIZE["wiping"][0] / 2, 0], atol=1e-15
    )
    np.testing.assert_allclose(canonical_shape("pick_and_place", [0.0])[0, 0], -0.15, atol=1e-15)
    for task in TASKS:
        assert canonical_shape(task, phase).shape == (7, 2)
    with pytest.raises(UnknownTaskError, match="task 'stirring' has no built-in guide shape"):
        canonical_shape("stirring", phase)
    with pytest.raises(UnknownTaskError, match="has no built-in guide shape"):
        canonical_loop("stirring", 12)
    with pytest.raises(UnknownTaskError, match="invalid task name"):
        canonical_shape("a/b", phase)


def test_unknown_task_error_is_a_config_error() -> None:
    assert issubclass(UnknownTaskError, ConfigError)


def test_a_stirring_file_is_written_read_and_validated(tmp_path: Path) -> None:
    path = write_stirring_file(tmp_path, n_demos=3, n_samples=50)
    back = read_recording(path)
    assert back.task == "stirring"
    np.testing.assert_allclose(back.plane.origin, STIRRING_PLANE.origin)
    np.testing.assert_allclose(back.plane.axes, STIRRING_PLANE.axes)
    assert list(back.demos) == ["demo_0", "demo_1", "demo_2"]
    check_recording(back, str(path))
    with h5py.File(path, "r") as f:
        assert f["data"].attrs["task"] == "stirring"
    demos = demos_from_recording(back, 64)
    assert [d.task for d in demos] == ["stirring"] * 3
    # Circles of radius 0.08 m ρ_k in the file's own plane.
    radii = [float(np.median(np.linalg.norm(d.positions, axis=1))) for d in demos]
    np.testing.assert_allclose(radii, [0.08, 0.088, 0.096], rtol=0.05)


@pytest.mark.parametrize("name", ["../x", "a/b", "", "x" * 65, "a b", "a\x00b"])
def test_the_writer_refuses_hostile_task_names(tmp_path: Path, name: str) -> None:
    recording = build_recording(name, plane=STIRRING_PLANE)
    with pytest.raises(RecordingError, match="invalid task name"):
        write_recording(tmp_path / "bad.hdf5", recording)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["../x", "a/b", "", "x" * 65, "a b", "a\x00b"])
def test_the_reader_refuses_hostile_task_names(tmp_path: Path, name: str) -> None:
    path = write_stirring_file(tmp_path, n_demos=1, n_samples=20)
    with h5py.File(path, "r+") as f:
        # Fixed-length bytes: h5py's variable-length strings refuse NUL.
        f["data"].attrs["task"] = np.bytes_(name.encode()) if "\x00" in name else name
    with pytest.raises(RecordingError) as info:
        read_recording(path)
    message = str(info.value)
    assert message.startswith(f"{path}: /data: attr")
    assert "\n" not in message
