"""The demo recorder: samples to a format-v1 demo, saved one file per demo."""

# mujoco ships compiled bindings without type stubs, so pyright cannot see MjModel, mj_step,
# mjtObj, ...: attribute checks on the mujoco module are off in this file.
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import math
from datetime import UTC, datetime
from pathlib import Path

import mujoco
import numpy as np
import pytest

from bt_pipeline.data.recording import read_recording
from bt_pipeline.data.records import MIN_SAMPLES
from bt_pipeline.exceptions import ConfigError, RecordingError
from bt_teleop.sim.scene import SceneModel, load_scene
from bt_teleop.takes.recorder import STATE_SIGNATURE, DemoInfo, DemoRecorder, env_args, save_demo

WHEN = datetime(2025, 6, 1, 12, 0, 0, tzinfo=UTC)


@pytest.fixture(scope="module")
def scene() -> SceneModel:
    return load_scene("pick_and_place")


def _filled(n: int, *, gripper: bool = True, seed: int = 0) -> DemoRecorder:
    rng = np.random.default_rng(seed)
    recorder = DemoRecorder(DemoInfo(" Ann\tB ", 10.0, 0.9, WHEN), t0_s=3.0, has_gripper=gripper)
    for k in range(n):
        recorder.add(
            3.0 + 0.02 * k,
            rng.normal(size=3),
            np.array([1.0, 0.0, 0.0, 0.0]),
            rng.normal(size=7),
            0.05,
            rng.normal(size=40),
            clamped=k % 4 == 0,
        )
    return recorder


def test_demo_has_forward_difference_actions_and_all_observations() -> None:
    recorder = _filled(20)
    demo = recorder.to_demo({"incomplete": False})
    assert demo.num_samples == 20 and demo.demonstrator == "Ann B"
    np.testing.assert_allclose(demo.timestamps, 0.02 * np.arange(20), atol=1e-12)
    assert demo.actions is not None
    np.testing.assert_allclose(demo.actions[:-1], np.diff(demo.ee_pos, axis=0) / 0.02)
    np.testing.assert_array_equal(demo.actions[-1], 0.0)
    assert demo.gripper is not None and demo.gripper.shape == (20, 1)
    assert demo.states is not None and demo.states.shape == (20, 40)
    assert recorder.clamped_samples == 5
    assert recorder.duration_s == pytest.approx(0.38)
    assert _filled(20, gripper=False).to_demo({}).gripper is None


def test_added_arrays_are_copied() -> None:
    recorder = DemoRecorder(DemoInfo("a", 0.0, 1.0, WHEN), 0.0, has_gripper=False)
    pos = np.zeros(3)
    recorder.add(0.0, pos, np.array([1.0, 0, 0, 0]), np.zeros(7), 0.0, np.zeros(4))
    pos[:] = 5.0
    np.testing.assert_array_equal(recorder.ee_positions(), np.zeros((1, 3)))


def test_short_demo_is_refused() -> None:
    with pytest.raises(RecordingError, match=f"at least {MIN_SAMPLES}"):
        _filled(MIN_SAMPLES - 1).to_demo({})


@pytest.mark.parametrize(
    ("theta", "rho", "match"),
    [(math.inf, 1.0, "theta_deg"), (0.0, -1.0, "rho must be positive"), (True, 1.0, "theta_deg")],
)
def test_demo_info_is_checked(theta: float, rho: float, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        DemoInfo("a", theta, rho, WHEN)


def test_demo_info_accepts_unknown_preferences_and_needs_aware_time() -> None:
    info = DemoInfo("a", math.nan, math.nan, WHEN)
    assert math.isnan(info.theta_deg) and math.isnan(info.rho)
    with pytest.raises(ConfigError, match="timezone"):
        DemoInfo("a", 0.0, 1.0, datetime(2025, 1, 1))


def test_saved_demos_get_their_own_files(scene: SceneModel, tmp_path: Path) -> None:
    env = env_args(scene, control_hz=100.0, record_hz=50.0)
    paths = [
        save_demo(_filled(20, seed=s).to_demo({"incomplete": False}), scene, tmp_path, env)
        for s in range(3)
    ]
    assert len(set(paths)) == 3
    for path in paths:
        assert path.parent == tmp_path / "pick_and_place"
        assert path.name.startswith("Ann-B_20250601T120000Z_")
        recording = read_recording(path)
        assert recording.task == "pick_and_place"
        assert recording.demos["demo_0"].created == "2025-06-01T12:00:00+00:00"
    assert not [p for p in tmp_path.rglob(".*")]  # no temporary files left


def test_env_args_carry_a_compilable_model(scene: SceneModel) -> None:
    env = env_args(scene, control_hz=100.0, record_hz=50.0)
    assert env["env_name"] == "bt_pick_and_place" and env["type"] == 0
    kwargs = env["env_kwargs"]
    assert kwargs["scene_file"] == "scenes/pick_and_place.xml"
    model = mujoco.MjModel.from_xml_string(kwargs["model_xml"])
    assert mujoco.mj_stateSize(model, STATE_SIGNATURE) == kwargs["state_size"]
