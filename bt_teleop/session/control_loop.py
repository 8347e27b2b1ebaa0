"""The control loop: one teleoperation session's simulated FR3, target, IK and recorder.

Callbacks only store the latest command; one fixed-rate loop per session consumes it. The data
flow of one tick (:meth:`Session._tick`, every ``1 / control_hz`` [s] of simulation time)::

  browser tab / script / replay (any thread)
    set_target(p, q) · set_gripper(open) · set_stay_on_plane(on)   validated; the latest kept
        │                                                            under _input_lock
  ┌─────▼ tick ───────────────────────────────────────────────────── control thread ──
  │ read     p, q, gripper open?, stay on plane?                  (_input_lock, briefly)
  │ target   p ─project onto the task plane (if asked)─▶ Workspace.clamp ─▶ p, clamped?
  │ ┄┄ under _state_lock ┄┄
  │ slew     command ─one bounded step towards (p, q): ≤ max_speed · dt, ≤ max_turn · dt
  │ IK       IkController.solve(command) ─▶ q_arm (7,), v_arm (7,), ok   (mink QP, daqp)
  │ actuate  ctrl[arm] = q_arm + (kv/kp) · v_arm;  ctrl[gripper] = open or closed
  │ physics  mj_step × substeps (unstable ─▶ reset to the ready pose); mj_kinematics
  │ record   every 1 / record_hz: RecordingSlot.sample_due ─▶ one DemoRecorder sample
  │          (ee pose, joints, gripper, clamped?, mj_getState)
  └──┬──────────────────────────────────────────────────────────────────────────────
     ▼
  status() · trail()   snapshots under the locks (any thread): the tab's 3-D view, Rerun
  stop_and_check()     the samples leave the slot under _state_lock; the take checks and the
                       file write run after it (session/recording.py, takes/recorder.py)

The loop runs in a thread of its own at real time (:meth:`Session.start`; a late tick is caught
up, a lag beyond ``max_lag_s`` dropped) or synchronously as fast as possible
(:meth:`Session.step_for`), with the same tick. In the app each session runs in a child process
of its own (:mod:`bt_teleop.session.process`), its ticks timed
(:mod:`bt_teleop.session.tick_stats`).
"""

# mujoco ships compiled bindings without type stubs, so pyright cannot see MjModel, mj_step,
# mjtObj, ...: attribute checks on the mujoco module are off in this file.
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import logging
import math
import secrets
import threading
import time
from datetime import UTC, datetime
from pathlib import Path

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError
from bt_teleop.session.config import SessionConfig, SessionStatus, whole_steps
from bt_teleop.session.recording import RecordingSlot, SavedTake
from bt_teleop.sim.ik import IkController
from bt_teleop.sim.scene import HOME_KEY, SceneModel, load_scene
from bt_teleop.sim.workspace import (
    project_onto_plane,
    slew_toward,
    validate_position,
    validate_quat,
)
from bt_teleop.takes.recorder import DemoInfo, site_quat

__all__ = ["Session", "SessionConfig", "SessionStatus"]

LOGGER = logging.getLogger("bt.teleop")
MIN_SAMPLES_WAIT_S = 10.0
"""Longest wall time Stop & save lets a too-short take record on to a file's minimum [s]."""
_UNSTABLE = (
    mujoco.mjtWarning.mjWARN_BADQACC,
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
)


class Session:
    """A simulated FR3 in one task scene, driven by the latest target, with a demo recorder."""

    def __init__(
        self,
        scene: SceneModel | str,
        recordings_dir: str | Path = "recordings",
        *,
        robot: str = "light",
        config: SessionConfig | None = None,
        session_id: str | None = None,
    ) -> None:
        """Create the session at the scene's ready pose (plane origin, default orientation).

        Args:
            scene: A loaded scene, or a task name to load with `robot`.
            recordings_dir: Root folder; demos go to ``<recordings_dir>/<task>/``.
            robot: ``light`` or ``menagerie`` (only when `scene` is a task name).
            config: Rates and policies; defaults when None.
            session_id: Stored in each demo's ep_meta; random when None.

        Raises:
            ConfigError: Rates that do not divide into physics steps and samples.
        """
        self.scene = scene if isinstance(scene, SceneModel) else load_scene(scene, robot)
        self.config = config or SessionConfig()
        self.recordings_dir = Path(recordings_dir)
        self.session_id = session_id or secrets.token_hex(4)
        model = self.scene.model
        self._substeps = whole_steps(1.0 / (self.config.control_hz * model.opt.timestep), "physics")
        self._demo = RecordingSlot(self.scene, self.recordings_dir, self.session_id, self.config)
        self.dt_s = self._substeps * float(model.opt.timestep)
        """Control period [s]."""
        self.data = mujoco.MjData(model)
        self._ik = IkController(self.scene, self.dt_s, self.config.ik)
        self._arm_act = np.array(self.scene.arm_actuator_ids)
        # Velocity feed-forward for the position servos: a position actuator with damping kv
        # pushes kp (ctrl - q) - kv q̇, which lags a moving command by kv/kp seconds. Commanding
        # ctrl = q_cmd + (kv/kp) v_cmd turns it into kp (q_cmd - q) + kv (v_cmd - q̇).
        kp = model.actuator_gainprm[self._arm_act, 0]
        self._lead_s = np.where(kp > 0.0, -model.actuator_biasprm[self._arm_act, 2] / kp, 0.0)
        self._arm_adr = np.array(self.scene.arm_qpos_adr)
        self._grip_adr = np.array(self.scene.gripper_qpos_adr, dtype=int)
        self._input_lock = threading.Lock()
        self._state_lock = threading.RLock()
        self._stop_event = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False
        self._ticks = 0
        self._ik_failures = 0
        self._warning: str | None = None
        self._ik_ok = True
        self._clamped = False
        self._stay_on_plane = False
        self._gripper_open = True
        self._target_pos = self.scene.ready_pos
        self._target_quat = self.scene.ee_quat.copy()
        self._effective_pos = self._target_pos.copy()
        self._command_pos = self._target_pos.copy()
        self._command_quat = self._target_quat.copy()
        self.reset()

    # -- commands (any thread) ----------------------------------------------------------------

    def set_target(self, pos: ArrayLike, quat: ArrayLike | None = None) -> None:
        """Set the end-effector target: position (3,) [m], orientation wxyz (4,) or None (keep).

        Raises:
            ConfigError: Not finite or of the wrong shape (the previous target stays).
        """
        p = validate_position(pos)
        q = None if quat is None else validate_quat(quat)
        with self._input_lock:
            self._target_pos = p
            if q is not None:
                self._target_quat = q

    def set_target_uv(self, uv: ArrayLike) -> None:
        """Set the target position in task-plane coordinates (2,) [m]; orientation kept."""
        uv_arr = np.array(uv, dtype=np.float64)
        if uv_arr.shape != (2,):
            raise ConfigError(f"task-plane target must be 2 numbers (u, v) [m]; got {uv!r}")
        self.set_target(self.scene.plane.to_world(uv_arr))

    def set_gripper(self, open: bool) -> None:
        """Open (True) or close (False) the gripper; ignored by scenes without one."""
        with self._input_lock:
            self._gripper_open = bool(open)

    def set_stay_on_plane(self, on: bool) -> None:
        """Project every target onto the task plane (True) or not (False)."""
        with self._input_lock:
            self._stay_on_plane = bool(on)

    def start_recording(
        self, demonstrator: str = "anonymous", theta_deg: float = math.nan, rho: float = math.nan
    ) -> None:
        """Start a demo now; the first sample is the current state (timestamp 0).

        Raises:
            ConfigError: A demo is already being recorded, the session is closed, or θ/ρ are
                not valid numbers.
        """
        info = DemoInfo(demonstrator, theta_deg, rho, created=datetime.now(UTC))
        with self._state_lock:
            self._check_open()
            self._demo.start(info, self.data, self._ticks)

    def stop_and_save(self) -> Path:
        """Stop the demo in progress and write it to a new file; returns its path.

        Raises:
            ConfigError: Nothing is being recorded.
            RecordingError: The demo is too short (it is discarded) or cannot be written.
        """
        return self.stop_and_check().path

    def stop_and_check(self) -> SavedTake:
        """:meth:`stop_and_save`, also returning what the take checks found (a take that fails
        them is saved with the demo attr ``flags``).

        A Stop pressed a moment after Record: while the loop runs in real time, a take with
        fewer samples than a file needs (``MIN_SAMPLES``) records on until it has them (0.3 s
        of simulation at 50 Hz) and is saved flagged ``too_short``, not refused and lost.
        """
        deadline = time.monotonic() + MIN_SAMPLES_WAIT_S
        while self._demo.short_of_minimum() and self.running and time.monotonic() < deadline:
            time.sleep(self.dt_s)
        with self._state_lock:
            recorder = self._demo.take()
            if recorder is None:
                raise ConfigError("nothing to save: no recording in progress")
        return self._demo.save(recorder)

    def discard(self) -> bool:
        """Drop the demo in progress without writing anything; whether there was one."""
        with self._state_lock:
            return self._demo.take() is not None

    # -- running the loop ---------------------------------------------------------------------

    def step(self, n_ticks: int = 1) -> None:
        """Run `n_ticks` control ticks synchronously, as fast as possible."""
        if self.running:
            raise ConfigError("the session runs in real time; stop() it before stepping by hand")
        self._check_open()
        for _ in range(int(n_ticks)):
            self._tick()

    def step_for(self, seconds: float) -> None:
        """Advance the simulation by `seconds` [s] of simulation time, synchronously."""
        if not (math.isfinite(seconds) and seconds >= 0.0):
            raise ConfigError(f"step_for needs a non-negative duration [s]; got {seconds}")
        self.step(round(seconds / self.dt_s))

    def start(self) -> None:
        """Run the loop in a background thread, paced to real time."""
        self._check_open()
        if self.running:
            return
        self._stop_event.clear()
        self._thread = threading.Thread(
            target=self._run, name=f"bt-session-{self.session_id}", daemon=True
        )
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the background loop (no-op when it is not running)."""
        self._stop_event.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            self._thread = None

    def close(self, save_incomplete: bool | None = None) -> Path | None:
        """End the session (e.g. its tab closed): stop the loop and settle a demo in progress.

        Args:
            save_incomplete: Save a demo in progress flagged ``incomplete`` in ep_meta (True)
                or discard it (False); ``config.save_incomplete`` when None. A demo shorter
                than the minimum is always discarded.

        Returns:
            The file saved, or None.
        """
        self.stop()
        with self._state_lock:
            if self._closed:
                return None
            self._closed = True
            recorder = self._demo.take()
        keep = self.config.save_incomplete if save_incomplete is None else save_incomplete
        return self._demo.save_incomplete(recorder, keep)

    def __enter__(self) -> Session:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def reset(self) -> None:
        """Put the robot at the ready pose with the gripper open and the target on it."""
        with self._state_lock:
            model, data = self.scene.model, self.data
            key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, HOME_KEY)
            mujoco.mj_resetDataKeyframe(model, data, key)
            self._ik.reset(self.scene.seed_q_arm)
            result = self._ik.converge(self.scene.ready_pos, self.scene.ee_quat)
            self._ik.hold_posture()
            self._warning = result.warning
            data.qpos[self._arm_adr] = result.q_arm
            data.ctrl[self._arm_act] = result.q_arm
            if self.scene.gripper_actuator_id is not None:
                opened = self.scene.gripper_ctrl_range[1]
                data.qpos[self._grip_adr] = opened
                data.ctrl[self.scene.gripper_actuator_id] = opened
            mujoco.mj_forward(model, data)
            self._command_pos = self.scene.ready_pos
            self._command_quat = self.scene.ee_quat.copy()
            self._effective_pos = self.scene.ready_pos
        with self._input_lock:
            self._target_pos = self.scene.ready_pos
            self._target_quat = self.scene.ee_quat.copy()
            self._gripper_open = True

    # -- reading ------------------------------------------------------------------------------

    @property
    def running(self) -> bool:
        """Whether the real-time background loop runs."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def recording(self) -> bool:
        """Whether a demo is being recorded."""
        return self._demo.recorder is not None

    @property
    def ik(self) -> IkController:
        """The session's IK controller."""
        return self._ik

    def status(self) -> SessionStatus:
        """A consistent snapshot of the session."""
        with self._input_lock:
            target_quat = self._target_quat.copy()
            gripper_open = self._gripper_open if self.scene.has_gripper else None
        with self._state_lock:
            data = self.data
            recorder = self._demo.recorder
            return SessionStatus(
                sim_time_s=float(data.time),
                qpos=data.qpos.copy(),
                ee_pos=data.site_xpos[self.scene.site_id].copy(),
                ee_quat=site_quat(data, self.scene.site_id),
                joint_pos=data.qpos[self._arm_adr].copy(),
                target_pos=self._effective_pos.copy(),
                target_quat=target_quat,
                command_pos=self._command_pos.copy(),
                command_quat=self._command_quat.copy(),
                target_clamped=self._clamped,
                gripper_open=gripper_open,
                ik_ok=self._ik_ok,
                warning=self._warning,
                ik_failures=self._ik_failures,
                recording=recorder is not None,
                n_samples=0 if recorder is None else recorder.n_samples,
                duration_s=0.0 if recorder is None else recorder.duration_s,
                running=self.running,
            )

    def trail(self) -> FloatArray:
        """End-effector positions of the demo in progress, shape (T, 3) [m] (empty if none)."""
        with self._state_lock:
            return self._demo.trail()

    # -- internals ----------------------------------------------------------------------------

    def _tick(self) -> None:
        with self._input_lock:
            pos, quat = self._target_pos, self._target_quat
            gripper_open, stay = self._gripper_open, self._stay_on_plane
        if stay:
            pos = project_onto_plane(self.scene.plane, pos)
        pos, clamped = self.scene.workspace.clamp(pos)
        model, data = self.scene.model, self.data
        with self._state_lock:
            self._command_pos, self._command_quat = slew_toward(
                self._command_pos,
                self._command_quat,
                pos,
                quat,
                self.config.max_speed_m_s * self.dt_s,
                self.config.max_turn_rad_s * self.dt_s,
            )
            result = self._ik.solve(self._command_pos, self._command_quat)
            self._ik_ok, self._clamped, self._effective_pos = result.ok, clamped, pos
            if not result.ok:
                self._ik_failures += 1
                self._warning = result.warning
                self._demo.count_ik_failure()
            elif self._warning is not None and self._warning.startswith("IK"):
                self._warning = None
            data.ctrl[self._arm_act] = result.q_arm + self._lead_s * result.v_arm
            if self.scene.gripper_actuator_id is not None:
                closed, opened = self.scene.gripper_ctrl_range
                data.ctrl[self.scene.gripper_actuator_id] = opened if gripper_open else closed
            unstable = sum(int(data.warning[w].number) for w in _UNSTABLE)
            for _ in range(self._substeps):
                mujoco.mj_step(model, data)
            if sum(int(data.warning[w].number) for w in _UNSTABLE) != unstable:
                self._recover()
            mujoco.mj_kinematics(model, data)  # poses of the state just integrated
            self._ticks += 1
            self._demo.sample_due(data, self._ticks, clamped=clamped)

    def _recover(self) -> None:
        """The simulation went unstable (MuJoCo reset it): start again from the ready pose."""
        time_s = self.data.time
        LOGGER.warning("session %s: simulation unstable; resetting the robot", self.session_id)
        self.reset()
        self.data.time = time_s
        self._warning = "simulation became unstable; the robot was reset"

    def _run(self) -> None:
        period = self.dt_s
        next_t = time.perf_counter()
        while not self._stop_event.is_set():
            try:
                self._tick()
            except Exception as exc:  # keep the server alive; the status shows what happened
                LOGGER.exception("session %s: control loop stopped", self.session_id)
                self._warning = f"control loop stopped: {type(exc).__name__}: {exc}"
                return
            next_t += period
            delay = next_t - time.perf_counter()
            if delay > 0.0:
                self._stop_event.wait(delay)
            elif -delay > self.config.max_lag_s:
                next_t = time.perf_counter()

    def _check_open(self) -> None:
        if self._closed:
            raise ConfigError(f"session {self.session_id} is closed")
