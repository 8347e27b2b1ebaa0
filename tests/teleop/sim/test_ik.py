"""mink IK: reaches reachable targets, keeps the last good command, keeps off the table."""

# mujoco ships compiled bindings without type stubs, so pyright cannot see MjModel, mj_step,
# mjtObj, ...: attribute checks on the mujoco module are off in this file.
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import mink
import mujoco
import numpy as np
import pytest

from bt_pipeline.data.tasks import TASKS
from bt_pipeline.exceptions import ConfigError
from bt_teleop.sim import ik as ik_module
from bt_teleop.sim.ik import IkController, IkSettings
from bt_teleop.sim.scene import ARM_JOINTS, SceneModel, load_scene


def _arm_ranges(scene: SceneModel) -> np.ndarray:
    """Joint ranges of fr3_joint1..7, shape (7, 2) [rad]."""
    model = scene.ik_model
    return model.jnt_range[[model.joint(name).id for name in ARM_JOINTS]]


def _ready(scene: SceneModel) -> IkController:
    controller = IkController(scene, 0.01)
    controller.reset(scene.seed_q_arm)
    result = controller.converge(scene.ready_pos, scene.ee_quat)
    assert result.ok, result.warning
    controller.hold_posture()
    return controller


@pytest.mark.parametrize("task", TASKS)
def test_converges_on_reachable_targets_from_forward_kinematics(
    scenes: dict[str, SceneModel], task: str
) -> None:
    """Targets made by FK of perturbed postures are reachable; the IK must reach them."""
    scene = scenes[task]
    controller = _ready(scene)
    rng = np.random.default_rng(0)
    probe = IkController(scene, 0.01)
    ranges = _arm_ranges(scene)
    for _ in range(4):
        q = scene.seed_q_arm + rng.normal(scale=0.15, size=7)
        q = np.clip(q, ranges[:, 0] + 0.05, ranges[:, 1] - 0.05)
        probe.reset(q)
        pos, quat = probe.ee_pose()
        result = controller.converge(pos, quat)
        assert result.ok, result.warning
        reached, _ = controller.ee_pose()
        assert np.linalg.norm(reached - pos) < 1e-3


@pytest.mark.parametrize("task", TASKS)
def test_ready_pose_is_at_the_plane_origin_within_limits(
    scenes: dict[str, SceneModel], task: str
) -> None:
    scene = scenes[task]
    controller = _ready(scene)
    pos, quat = controller.ee_pose()
    np.testing.assert_allclose(pos, scene.ready_pos, atol=2e-4)
    assert abs(abs(float(np.dot(quat, scene.ee_quat))) - 1.0) < 1e-5
    ranges = _arm_ranges(scene)
    q = controller.q_arm
    assert np.all(q >= ranges[:, 0]) and np.all(q <= ranges[:, 1])


def test_solver_failure_keeps_the_last_good_command(
    scenes: dict[str, SceneModel], monkeypatch: pytest.MonkeyPatch
) -> None:
    scene = scenes["wiping"]
    controller = _ready(scene)
    good = controller.solve(scene.ready_pos + np.array([0.02, 0.0, 0.0]), scene.ee_quat)
    assert good.ok and good.warning is None

    def no_solution(*_args: object, **_kwargs: object) -> np.ndarray:
        raise mink.NoSolutionFound("daqp")

    monkeypatch.setattr(ik_module.mink, "solve_ik", no_solution)
    failed = controller.solve(scene.ready_pos + np.array([0.05, 0.0, 0.0]), scene.ee_quat)
    assert not failed.ok and failed.warning is not None and "IK failed" in failed.warning
    np.testing.assert_array_equal(failed.q_arm, good.q_arm)
    np.testing.assert_array_equal(failed.v_arm, np.zeros(7))

    monkeypatch.setattr(
        ik_module.mink, "solve_ik", lambda *a, **k: np.full(scene.ik_model.nv, np.nan)
    )
    nan = controller.solve(scene.ready_pos, scene.ee_quat)
    assert not nan.ok and "NaN" in (nan.warning or "")
    np.testing.assert_array_equal(nan.q_arm, good.q_arm)


def test_keeps_the_tool_off_the_table_when_asked_to_go_through_it(
    scenes: dict[str, SceneModel],
) -> None:
    scene = scenes["wiping"]
    controller = _ready(scene)
    below = scene.ready_pos + np.array([0.0, 0.0, -0.2])  # 15 cm under the table top
    for _ in range(300):
        controller.solve(below, scene.ee_quat)
    model, data = scene.ik_model, controller.configuration.data
    table = model.geom("table").id
    fromto = np.zeros(6)
    distances = [
        mujoco.mj_geomDistance(model, data, model.geom(name).id, table, 0.5, fromto)
        for name in scene.avoid_geoms
    ]
    # The guards keep the minimum distance up to the linearisation error of one tick.
    assert min(distances) > 0.003
    pos, _ = controller.ee_pose()
    assert pos[2] > scene.plane.origin[2] - 0.02  # stopped at the table, not 20 cm below


def test_settings_are_checked() -> None:
    with pytest.raises(ConfigError, match="velocity_scale"):
        IkSettings(velocity_scale=0.0)
    with pytest.raises(ConfigError, match="dt_s"):
        IkController(load_scene("wiping"), 0.0)
