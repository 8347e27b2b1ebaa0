"""bt import: robomimic files (written the way robomimic writes them) and LeRobot datasets."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.recording import read_recording, write_recording
from bt_pipeline.exceptions import ConfigError, RecordingError
from bt_pipeline.interop.export_lerobot import export_lerobot
from bt_pipeline.interop.import_lerobot import read_lerobot
from bt_pipeline.interop.import_robomimic import read_robomimic
from bt_pipeline.interop.plane_fit import fit_plane, parse_plane
from tests.pipeline.interop.conftest import full_recording

REPO = Path(__file__).resolve().parents[3]
# A tilted plane (30° about world x), as another lab's table or easel might be.
TILT = math.radians(30.0)
TRUE_AXES = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(TILT), math.sin(TILT)]])
TRUE_ORIGIN = np.array([0.45, -0.05, 0.30])


def write_robomimic_file(path: Path, n_demos: int = 4, seed: int = 0) -> Path:
    """A robomimic low-dim file as robosuite + robomimic write it (no bt attrs at all).

    Demos: an approach, two wobbly loops on the tilted plane, a retreat; 20 Hz; robosuite obs
    (robot0_eef_pos, robot0_eef_quat x,y,z,w, robot0_joint_pos, robot0_gripper_qpos, object),
    7-D normalised OSC actions, rewards, dones, states; mask/train and mask/valid.
    """
    rng = np.random.default_rng(seed)
    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        data.attrs["env_args"] = json.dumps(
            {"env_name": "Wipe", "type": 1, "env_kwargs": {"control_freq": 20, "robots": ["Panda"]}}
        )
        total = 0
        for k in range(n_demos):
            n = 180 + 20 * k
            s = np.linspace(0.0, 1.0, n)
            phase = 2 * np.pi * 2 * np.clip((s - 0.15) / 0.7, 0.0, 1.0)
            radius = 0.07 * (1 + 0.1 * k) * np.clip(np.minimum(s / 0.15, (1 - s) / 0.15), 0, 1)
            uv = radius[:, None] * np.stack([np.cos(phase), np.sin(phase)], axis=1)
            uv += 0.002 * rng.standard_normal(uv.shape)
            eef = TRUE_ORIGIN + uv @ TRUE_AXES
            demo = data.create_group(f"demo_{k}")
            demo.attrs["num_samples"] = n
            demo.create_dataset("actions", data=np.clip(rng.normal(0, 0.4, (n, 7)), -1, 1))
            demo.create_dataset("rewards", data=np.zeros(n))
            demo.create_dataset("dones", data=np.r_[np.zeros(n - 1), 1].astype(np.int64))
            demo.create_dataset("states", data=rng.standard_normal((n, 32)))
            quat_xyzw = np.tile([0.0, 1.0, 0.0, 0.0], (n, 1))
            for group in ("obs", "next_obs"):
                shift = 0 if group == "obs" else 1
                idx = np.minimum(np.arange(n) + shift, n - 1)
                demo.create_dataset(f"{group}/robot0_eef_pos", data=eef[idx])
                demo.create_dataset(f"{group}/robot0_eef_quat", data=quat_xyzw[idx])
                demo.create_dataset(f"{group}/robot0_joint_pos", data=np.zeros((n, 7)))
                demo.create_dataset(f"{group}/robot0_gripper_qpos", data=np.full((n, 2), 0.02))
                demo.create_dataset(f"{group}/object", data=np.arange(n * 10.0).reshape(n, 10))
            total += n
        data.attrs["total"] = total
        names = [f"demo_{k}" for k in range(n_demos)]
        f.create_dataset("mask/train", data=np.array(names[:-1], dtype="S"))
        f.create_dataset("mask/valid", data=np.array(names[-1:], dtype="S"))
    return path


def test_import_robomimic_maps_robosuite_conventions(tmp_path) -> None:
    src = write_robomimic_file(tmp_path / "other_lab.hdf5")
    recording = read_robomimic(src, "wiping", None)
    demo = recording.demos["demo_1"]
    assert math.isnan(demo.theta_deg) and math.isnan(demo.rho) and demo.source == "import"
    np.testing.assert_allclose(np.diff(demo.timestamps), 1 / 20)
    np.testing.assert_allclose(demo.ee_quat[0], [0.0, 0.0, 1.0, 0.0])  # type: ignore[index]
    assert set(demo.extra_obs) == {"robot0_gripper_qpos", "object"}
    assert recording.masks == {"train": ["demo_0", "demo_1", "demo_2"], "valid": ["demo_3"]}
    # PCA recovers the tilted plane: same normal (up to sign), origin on the plane.
    true_normal = np.cross(TRUE_AXES[0], TRUE_AXES[1])
    assert abs(float(recording.plane.normal @ true_normal)) > 0.999
    assert abs(float((recording.plane.origin - TRUE_ORIGIN) @ true_normal)) < 1e-3
    written = write_recording(tmp_path / "imported.hdf5", recording)
    back = read_recording(written).demos["demo_1"]
    np.testing.assert_array_equal(back.extra_obs["object"], demo.extra_obs["object"])


@pytest.mark.slow
def test_imported_robomimic_file_cleans_keeping_masks_and_extra_obs(tmp_path) -> None:
    src = write_robomimic_file(tmp_path / "other_lab.hdf5")
    imported = tmp_path / "imported.hdf5"
    cmd = [sys.executable, "-m", "bt_pipeline"]
    env = {"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"}
    subprocess.run(
        [
            *cmd,
            "import",
            str(src),
            "--from",
            "robomimic",
            "--task",
            "wiping",
            "--out",
            str(imported),
        ],
        check=True,
        env=env,
        capture_output=True,
    )
    run = subprocess.run(
        [*cmd, "clean", str(imported), "--out", str(tmp_path / "out"), "--epochs", "2", "--no-rrd"],
        check=True,
        env=env,
        capture_output=True,
        text=True,
    )
    assert "\r" not in run.stderr  # no progress-bar redraws in a log (stderr is no terminal)
    cleaned = read_recording(tmp_path / "out/wiping.cleaned.hdf5")
    assert cleaned.masks == {"train": ["demo_0", "demo_1", "demo_2"], "valid": ["demo_3"]}
    demo = cleaned.demos["demo_0"]
    assert set(demo.extra_obs) == {"robot0_gripper_qpos", "object"}
    # Carried on the cleaned timeline: the object's counter is linear in time, so it stays so.
    obj = demo.extra_obs["object"][:, 0]
    t = demo.timestamps
    np.testing.assert_allclose(obj, 10.0 * 20.0 * t, atol=1e-6)
    assert demo.ee_quat is not None and demo.joint_pos is None


def test_lerobot_round_trip(tmp_path) -> None:
    src = write_recording(tmp_path / "w.hdf5", full_recording())
    root = export_lerobot([src], tmp_path / "ds", fps=25).root
    back = read_lerobot(root, "wiping", None)
    original = read_recording(src).demos
    for (name, record), demo in zip(original.items(), back.demos.values(), strict=True):
        t = record.timestamps - record.timestamps[0]
        truth = np.stack([np.interp(demo.timestamps, t, record.ee_pos[:, j]) for j in range(3)], 1)
        np.testing.assert_allclose(demo.ee_pos, truth, atol=1e-6)
        assert demo.joint_pos is not None and demo.ee_quat is not None
        assert demo.demonstrator == record.demonstrator
        assert (math.isnan(demo.theta_deg) and math.isnan(record.theta_deg)) or (
            demo.theta_deg == record.theta_deg
        ), name
    with pytest.raises(RecordingError, match="no episode of task weaving"):
        read_lerobot(root, "weaving", None)


def test_plane_fit_and_parse() -> None:
    rng = np.random.default_rng(0)
    uv = rng.uniform(-0.1, 0.1, (200, 2))
    plane = fit_plane([TRUE_ORIGIN + uv @ TRUE_AXES])
    assert abs(float(plane.normal @ np.cross(*TRUE_AXES))) > 0.9999
    assert plane.normal[2] > 0
    with pytest.raises(ConfigError, match="span no plane"):
        fit_plane([np.outer(np.linspace(0, 1, 50), [1.0, 0.0, 0.0])])
    given = parse_plane("0.5,0,0.05, 0,-1,0, 1,0,0")
    assert isinstance(given, TaskPlane) and given.origin[0] == 0.5
    assert parse_plane("auto") is None
    with pytest.raises(ConfigError, match="9 comma-separated"):
        parse_plane("1,2,3")


def test_bad_inputs_are_one_clear_error(tmp_path) -> None:
    text = tmp_path / "notes.hdf5"
    text.write_text("not an HDF5 file")
    with pytest.raises(RecordingError, match=r"notes\.hdf5: cannot read the file as HDF5"):
        read_robomimic(text, "wiping", None)
    with pytest.raises(RecordingError, match=r"no meta/info\.json"):
        read_lerobot(tmp_path, "wiping", None)
    src = write_recording(tmp_path / "w.hdf5", full_recording())
    root = export_lerobot([src], tmp_path / "ds").root
    next((root / "data").glob("*/*.parquet")).write_bytes(b"truncated")
    with pytest.raises(RecordingError, match="cannot read the dataset's parquet files"):
        read_lerobot(root, "wiping", None)


def test_missing_end_effector_is_named(tmp_path) -> None:
    path = tmp_path / "bad.hdf5"
    with h5py.File(path, "w") as f:
        f.create_dataset("data/demo_0/obs/agentview_image", data=np.zeros((20, 4, 4, 3)))
    with pytest.raises(RecordingError, match=r"demo_0: no end-effector position.*--ee-key"):
        read_robomimic(path, "wiping", None)


def test_import_robomimic_as_a_task_without_a_guide_fits_its_plane(capsys, tmp_path) -> None:
    from tests.conftest import run

    src = write_robomimic_file(tmp_path / "other_lab.hdf5")
    out = tmp_path / "stirring.hdf5"
    code, printed, err = run(
        capsys, "import", str(src), "--from", "robomimic", "--task", "stirring", "--out", str(out)
    )
    assert code == 0, err
    assert printed.strip() == str(out)
    recording = read_recording(out)
    assert recording.task == "stirring" and len(recording.demos) == 4
    # No built-in plane for stirring: --plane auto (the default) fits the tilted one.
    assert abs(float(recording.plane.normal @ np.cross(*TRUE_AXES))) > 0.999
    assert recording.masks == {"train": ["demo_0", "demo_1", "demo_2"], "valid": ["demo_3"]}


def test_import_lerobot_as_a_task_without_a_guide(capsys, tmp_path) -> None:
    from tests.conftest import run
    from tests.pipeline.conftest import STIRRING_PLANE

    src = write_recording(tmp_path / "s.hdf5", full_recording("stirring", STIRRING_PLANE))
    root = export_lerobot([src], tmp_path / "ds", fps=25).root
    out = tmp_path / "back.hdf5"
    code, _, err = run(
        capsys, "import", str(root), "--from", "lerobot", "--task", "stirring", "--out", str(out)
    )
    assert code == 0, err
    recording = read_recording(out)
    assert recording.task == "stirring" and len(recording.demos) == 3
    assert abs(float(recording.plane.normal @ STIRRING_PLANE.normal)) > 0.999
    code, _, err = run(
        capsys, "import", str(root), "--from", "lerobot", "--task", "buffing", "--out", str(out),
        "--overwrite",
    )  # fmt: skip
    assert code == 2 and "no episode of task buffing" in err


@pytest.mark.parametrize("name", ["../x", "a/b", "", "x" * 65, "a b", "a\x00b", ".hidden"])
def test_import_refuses_hostile_task_names_in_one_line(capsys, tmp_path, name: str) -> None:
    from tests.conftest import run

    src = write_robomimic_file(tmp_path / "other_lab.hdf5", n_demos=1)
    out = tmp_path / "out.hdf5"
    code, printed, err = run(
        capsys, "import", str(src), "--from", "robomimic", "--task", name, "--out", str(out)
    )
    assert code == 2 and printed == ""
    assert err.count("\n") == 1
    assert err.startswith("bt: error: invalid task name ")
    assert "a task name is 1-64 characters of letters, digits, '_' and '-'" in err
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other_lab.hdf5"]
