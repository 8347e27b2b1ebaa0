"""Session logic: tracking, recording, discarding, independence, robustness, the gripper."""

# mujoco ships compiled bindings without type stubs, so pyright cannot see MjModel, mj_step,
# mjtObj, ...: attribute checks on the mujoco module are off in this file.
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import math
import time
from pathlib import Path

import mink
import mujoco
import numpy as np
import pytest

from bt_pipeline.data.recording import read_recording
from bt_pipeline.data.records import MIN_SAMPLES
from bt_pipeline.data.tasks import TASKS
from bt_pipeline.exceptions import ConfigError, RecordingError
from bt_teleop.session.control_loop import Session, SessionConfig
from bt_teleop.sim import ik as ik_module
from bt_teleop.sim.scene import SceneModel
from bt_teleop.takes.recorder import STATE_SIGNATURE
from bt_teleop.testing.harness import circle_uv

RADIUS_M = 0.06
PERIOD_S = 4.0


def _files(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if p.is_file()]


@pytest.mark.parametrize("task", TASKS)
def test_tracks_a_reachable_circle_in_the_task_plane(
    scenes: dict[str, SceneModel], task: str, tmp_path: Path
) -> None:
    session = Session(scenes[task], tmp_path)
    errors, positions = [], []
    for k in range(round(6.0 / session.dt_s)):
        t_s = k * session.dt_s
        session.set_target_uv(circle_uv(t_s, RADIUS_M, PERIOD_S))
        session.step(1)
        if t_s >= 1.5:  # after settling
            status = session.status()
            errors.append(np.linalg.norm(status.ee_pos - status.target_pos))
            positions.append(status.ee_pos)
    rms = float(np.sqrt(np.mean(np.square(errors))))
    assert rms < 0.005, f"{task}: RMS tracking error {rms * 1e3:.2f} mm"
    uv = scenes[task].plane.to_plane(np.array(positions))
    assert np.ptp(uv[:, 0]) > 1.8 * RADIUS_M and np.ptp(uv[:, 1]) > 1.8 * RADIUS_M
    assert session.status().ik_failures == 0


def test_recorded_file_validates_and_its_states_replay(
    scenes: dict[str, SceneModel], tmp_path: Path
) -> None:
    scene = scenes["wiping"]
    session = Session(scene, tmp_path)
    session.start_recording("Zoë / ../x", theta_deg=12.5, rho=1.2)
    for k in range(round(1.0 / session.dt_s)):
        session.set_target_uv(circle_uv(k * session.dt_s, RADIUS_M, PERIOD_S))
        session.step(1)
    assert session.status().n_samples == 51
    path = session.stop_and_save()
    assert path.parent == tmp_path / "wiping" and path.suffix == ".hdf5"
    assert not session.recording

    recording = read_recording(path)
    assert recording.task == "wiping" and list(recording.demos) == ["demo_0"]
    np.testing.assert_allclose(recording.plane.origin, scene.plane.origin)
    demo = recording.demos["demo_0"]
    assert demo.source == "teleop" and demo.demonstrator == "Zoë / ../x"
    assert (demo.theta_deg, demo.rho) == (12.5, 1.2)
    assert demo.ep_meta["incomplete"] is False and demo.created is not None
    np.testing.assert_allclose(np.diff(demo.timestamps), 0.02, atol=1e-9)
    assert demo.ee_quat is not None and demo.joint_pos is not None and demo.states is not None
    assert demo.gripper is None  # no gripper in the wiping scene
    velocity = np.diff(demo.ee_pos, axis=0) / np.diff(demo.timestamps)[:, None]
    np.testing.assert_allclose(demo.resolved_actions()[:-1], velocity)

    kwargs = recording.env_args["env_kwargs"]
    assert (kwargs["task"], kwargs["robot"], kwargs["state_signature"]) == (
        "wiping",
        "light",
        STATE_SIGNATURE,
    )
    model = mujoco.MjModel.from_xml_string(kwargs["model_xml"])
    data = mujoco.MjData(model)
    site = model.site("attachment_site").id
    for k in (0, 17, demo.num_samples - 1):
        mujoco.mj_setState(model, data, demo.states[k], STATE_SIGNATURE)
        mujoco.mj_kinematics(model, data)
        np.testing.assert_allclose(data.site_xpos[site], demo.ee_pos[k], atol=1e-12)


def test_discard_writes_nothing(scenes: dict[str, SceneModel], tmp_path: Path) -> None:
    session = Session(scenes["weaving"], tmp_path)
    session.start_recording("ann", 0.0, 1.0)
    session.step_for(1.0)
    assert session.discard()
    assert not session.discard()
    with pytest.raises(ConfigError, match="no recording"):
        session.stop_and_save()
    session.close()
    assert _files(tmp_path) == []


def test_too_short_demo_is_refused_and_nothing_is_written(
    scenes: dict[str, SceneModel], tmp_path: Path
) -> None:
    session = Session(scenes["wiping"], tmp_path)
    session.start_recording("ann", 0.0, 1.0)
    session.step_for(0.1)
    with pytest.raises(RecordingError, match="at least 16"):
        session.stop_and_save()
    assert _files(tmp_path) == [] and not session.recording


def test_a_stop_a_moment_after_record_saves_a_flagged_take_in_real_time(
    scenes: dict[str, SceneModel], tmp_path: Path
) -> None:
    # The app's loop runs in real time: a Stop pressed before the take has the 16 samples a
    # file needs records on to them and saves the take flagged, as the take checks promise
    # ("kept as files, never lost"), instead of refusing it (a take lost under CPU load).
    session = Session(scenes["wiping"], tmp_path)
    session.start()
    try:
        session.start_recording("quick", 0.0, 1.0)
        take = session.stop_and_check()
    finally:
        session.close()
    demo = read_recording(take.path).demos["demo_0"]
    assert len(demo.timestamps) >= MIN_SAMPLES
    assert "too_short" in demo.flags and "too_short" in take.check.attr
    assert not session.recording


def test_two_sessions_stay_independent(scenes: dict[str, SceneModel], tmp_path: Path) -> None:
    a = Session(scenes["wiping"], tmp_path)
    b = Session(scenes["wiping"], tmp_path)
    b_start = b.status()
    a.set_target_uv([0.1, 0.05])
    a.set_stay_on_plane(True)
    a.start_recording("a", 0.0, 1.0)
    for _ in range(100):
        a.step(1)
        b.step(1)
    a_now, b_now = a.status(), b.status()
    assert np.linalg.norm(a_now.ee_pos - b_start.ee_pos) > 0.1
    np.testing.assert_allclose(b_now.ee_pos, b_start.ee_pos, atol=1e-3)
    np.testing.assert_allclose(b_now.target_pos, b_start.target_pos)
    assert a_now.recording and not b_now.recording
    assert a_now.sim_time_s == pytest.approx(b_now.sim_time_s)

    # The same in real time, each session in its own thread.
    a.start()
    b.start()
    try:
        a.set_target_uv([-0.1, -0.05])
        deadline = time.monotonic() + 30.0
        while np.linalg.norm(a.status().ee_pos - a_now.ee_pos) < 0.1:
            assert time.monotonic() < deadline, "session a did not move"
            time.sleep(0.01)
    finally:
        a.stop()
        b.stop()
    np.testing.assert_allclose(b.status().ee_pos, b_start.ee_pos, atol=1e-3)


def test_far_target_is_clamped_and_the_loop_keeps_running(
    scenes: dict[str, SceneModel], tmp_path: Path
) -> None:
    scene = scenes["pick_and_place"]
    session = Session(scene, tmp_path)
    with pytest.raises(ConfigError, match="within 10 m"):  # a browser's absurd pose is refused
        session.set_target([10.0, -10.0, 50.0])
    session.set_target([3.0, -3.0, 5.0], [0.3, 0.1, 0.9, 0.2])  # far, but a pose: clamped
    session.step_for(1.0)
    status = session.status()
    assert status.target_clamped
    np.testing.assert_allclose(
        status.target_pos, [scene.workspace.hi[0], scene.workspace.lo[1], scene.workspace.hi[2]]
    )
    assert np.all(np.isfinite(status.qpos)) and np.all(np.isfinite(status.ee_pos))
    with pytest.raises(ConfigError, match="finite"):
        session.set_target([math.nan, 0.0, 0.0])
    session.set_target(scene.ready_pos, scene.ee_quat)
    session.step_for(1.5)
    status = session.status()
    assert not status.target_clamped
    np.testing.assert_allclose(status.ee_pos, scene.ready_pos, atol=2e-3)


def test_ik_failure_keeps_the_last_good_command(
    scenes: dict[str, SceneModel], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    session = Session(scenes["wiping"], tmp_path)
    session.set_target_uv([0.05, 0.0])
    session.step_for(0.5)
    good_q = session.ik.q_arm

    def no_solution(*_args: object, **_kwargs: object) -> np.ndarray:
        raise mink.NoSolutionFound("daqp")

    with monkeypatch.context() as patch:
        patch.setattr(ik_module.mink, "solve_ik", no_solution)
        session.set_target_uv([-0.05, 0.05])
        session.step_for(0.3)
        status = session.status()
        assert not status.ik_ok and status.ik_failures == 30
        assert status.warning is not None and "IK failed" in status.warning
        np.testing.assert_array_equal(session.ik.q_arm, good_q)
        np.testing.assert_array_equal(session.data.ctrl[:7], good_q)
    session.step_for(0.5)
    status = session.status()
    assert status.ik_ok and status.warning is None
    assert np.linalg.norm(session.ik.q_arm - good_q) > 1e-3


def test_close_saves_incomplete_or_discards(scenes: dict[str, SceneModel], tmp_path: Path) -> None:
    saving = Session(scenes["weaving"], tmp_path / "keep")
    saving.start_recording("ann", 0.0, 1.0)
    saving.step_for(0.6)
    path = saving.close(save_incomplete=True)
    assert path is not None
    assert read_recording(path).demos["demo_0"].ep_meta["incomplete"] is True
    assert saving.close() is None  # idempotent
    with pytest.raises(ConfigError, match="closed"):
        saving.start_recording("ann")

    dropping = Session(scenes["weaving"], tmp_path / "drop")
    dropping.start_recording("ann", 0.0, 1.0)
    dropping.step_for(0.6)
    assert dropping.close(save_incomplete=False) is None
    assert _files(tmp_path / "drop") == []


def _lift_block(session: Session, grasp: bool) -> float:
    """Go down to the block on the left place, grasp (or not), lift; the block's height [m]."""
    block = session.scene.model.body("block").id
    start = session.scene.plane.to_plane(session.status().target_pos)
    for goal, seconds in (([-0.15, 0.0], 1.2), ([-0.15, -0.03], 0.8)):
        n = round(seconds / session.dt_s)
        for k in range(n):
            session.set_target_uv(start + (np.array(goal) - start) * (k + 1) / n)
            session.step(1)
        start = np.array(goal)
    session.step_for(0.3)
    session.set_gripper(not grasp)
    session.step_for(0.5)
    for k in range(100):
        session.set_target_uv([-0.15, -0.03 + 0.15 * (k + 1) / 100])
        session.step(1)
    session.step_for(0.3)
    return float(session.data.xpos[block][2])


def test_gripper_lifts_the_block_only_when_closed(
    scenes: dict[str, SceneModel], tmp_path: Path
) -> None:
    session = Session(scenes["pick_and_place"], tmp_path)
    z0 = float(session.data.xpos[session.scene.model.body("block").id][2])
    assert _lift_block(session, grasp=True) > z0 + 0.12
    assert session.status().gripper_open is False
    session.reset()
    assert session.status().gripper_open is True
    assert _lift_block(session, grasp=False) == pytest.approx(z0, abs=0.002)


def test_background_loop_runs_and_stops(scenes: dict[str, SceneModel], tmp_path: Path) -> None:
    session = Session(scenes["wiping"], tmp_path)
    session.start()
    try:
        deadline = time.monotonic() + 30.0
        while session.status().sim_time_s < 0.2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert session.status().running and session.status().sim_time_s >= 0.2
        with pytest.raises(ConfigError, match="real time"):
            session.step(1)
    finally:
        session.stop()
    assert not session.status().running
    t_s = session.status().sim_time_s
    session.step(1)
    assert session.status().sim_time_s == pytest.approx(t_s + session.dt_s)


def test_stay_on_plane_projects_the_target(scenes: dict[str, SceneModel], tmp_path: Path) -> None:
    scene = scenes["weaving"]
    session = Session(scene, tmp_path)
    off_plane = scene.plane.to_world(np.array([0.05, 0.02])) - 0.08 * scene.plane.normal
    session.set_target(off_plane)
    session.step(1)
    assert (
        abs(float(np.dot(session.status().target_pos - scene.plane.origin, scene.plane.normal)))
        > 0.05
    )
    session.set_stay_on_plane(True)
    session.step(1)
    target = session.status().target_pos
    np.testing.assert_allclose(scene.plane.to_plane(target), [0.05, 0.02], atol=1e-12)
    assert abs(float(np.dot(target - scene.plane.origin, scene.plane.normal))) < 1e-12


def test_rates_that_do_not_fit_are_refused(scenes: dict[str, SceneModel], tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="control_hz"):
        Session(scenes["wiping"], tmp_path, config=SessionConfig(control_hz=300.0))
    with pytest.raises(ConfigError, match="record_hz"):
        Session(scenes["wiping"], tmp_path, config=SessionConfig(record_hz=30.0))
