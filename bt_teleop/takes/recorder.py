"""The demo recorder: samples of one demo at a fixed rate on simulation time, saved as format v1.

A session adds one sample every ``1 / record_hz`` seconds of simulation time while recording.
Stop & save turns the samples into a :class:`~bt_pipeline.data.records.DemoRecord` (actions by
forward difference), wraps it in a one-demo :class:`~bt_pipeline.data.records.Recording` with the
scene's task plane and model, and writes it atomically with
:func:`bt_pipeline.data.recording.write_recording` to a fresh file per demo, so concurrent sessions
never share a file.
"""

# mujoco ships compiled bindings without type stubs, so pyright cannot see MjModel, mj_step,
# mjtObj, ...: attribute checks on the mujoco module are off in this file.
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from datetime import datetime
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from bt_pipeline.data.recording import DEFAULT_ENV_TYPE, write_recording
from bt_pipeline.data.records import (
    MIN_SAMPLES,
    DemoRecord,
    FloatArray,
    Recording,
    forward_difference_actions,
)
from bt_pipeline.exceptions import ConfigError, RecordingError
from bt_teleop.sim.scene import SCENES_DIR, SceneModel
from bt_teleop.takes.naming import clean_demonstrator, demo_path

THETA_RANGE_DEG = (-30.0, 30.0)
"""θ a demonstrator may declare [deg]: the θ slider's range, enforced on the server too."""
RHO_RANGE = (0.5, 1.5)
"""ρ a demonstrator may declare: the ρ slider's range, enforced on the server too."""
STATE_SIGNATURE = int(mujoco.mjtState.mjSTATE_FULLPHYSICS | mujoco.mjtState.mjSTATE_CTRL)
"""What ``states`` holds per sample: ``mj_getState`` with the full physics state and ctrl."""


@dataclass(frozen=True)
class DemoInfo:
    """Who records a demo and with which preference."""

    demonstrator: str
    """Demonstrator name (free text, cleaned with
    :func:`~bt_teleop.takes.naming.clean_demonstrator`)."""
    theta_deg: float
    """Demonstrator rotation θ [deg]; NaN when unknown."""
    rho: float
    """Demonstrator scale ρ; NaN when unknown."""
    created: datetime
    """When the recording started (timezone-aware, UTC)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "demonstrator", clean_demonstrator(self.demonstrator))
        for name in ("theta_deg", "rho"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ConfigError(f"{name} must be a number (NaN = unknown); got {value!r}")
            if math.isinf(value):
                raise ConfigError(f"{name} must be finite or NaN; got {value}")
            object.__setattr__(self, name, float(value))
        if not math.isnan(self.rho) and self.rho <= 0.0:
            raise ConfigError(f"rho must be positive (1 = canonical size); got {self.rho}")
        # A browser can send any number; hold it to the sliders' ranges (NaN = unknown).
        for name, (lo, hi) in (("theta_deg", THETA_RANGE_DEG), ("rho", RHO_RANGE)):
            value = getattr(self, name)
            if not math.isnan(value) and not lo <= value <= hi:
                raise ConfigError(
                    f"{name} must lie in [{lo:g}, {hi:g}] (the slider's range) or be unknown; "
                    f"got {value:g}"
                )
        if self.created.tzinfo is None:
            raise ConfigError("created must be a timezone-aware time (UTC)")


class DemoRecorder:
    """Samples of one demo in progress (not thread-safe: its session serialises access)."""

    def __init__(self, info: DemoInfo, t0_s: float, *, has_gripper: bool) -> None:
        """Start an empty demo whose timestamps count from simulation time `t0_s` [s]."""
        self.info = info
        self.t0_s = float(t0_s)
        self.has_gripper = has_gripper
        self._t: list[float] = []
        self._ee_pos: list[FloatArray] = []
        self._ee_quat: list[FloatArray] = []
        self._joint_pos: list[FloatArray] = []
        self._gripper: list[float] = []
        self._states: list[FloatArray] = []
        self.clamped_samples = 0
        """Samples taken while the target was clamped to the workspace."""
        self.ik_failures = 0
        """IK ticks that failed during the demo."""

    @property
    def n_samples(self) -> int:
        """Samples so far."""
        return len(self._t)

    @property
    def duration_s(self) -> float:
        """Simulation time from the first to the last sample [s]."""
        return self._t[-1] - self._t[0] if self._t else 0.0

    def add(
        self,
        t_s: float,
        ee_pos: FloatArray,
        ee_quat: FloatArray,
        joint_pos: FloatArray,
        gripper_opening_m: float,
        state: FloatArray,
        *,
        clamped: bool = False,
    ) -> None:
        """Append one sample (arrays are copied) taken at simulation time `t_s` [s]."""
        self._t.append(float(t_s) - self.t0_s)
        self._ee_pos.append(np.array(ee_pos, dtype=np.float64))
        self._ee_quat.append(np.array(ee_quat, dtype=np.float64))
        self._joint_pos.append(np.array(joint_pos, dtype=np.float64))
        self._gripper.append(float(gripper_opening_m))
        self._states.append(np.array(state, dtype=np.float64))
        self.clamped_samples += int(clamped)

    def times(self) -> FloatArray:
        """Sample times from the first sample, shape (T,) [s] (a copy)."""
        return np.array(self._t, dtype=np.float64)

    def ee_positions(self) -> FloatArray:
        """End-effector positions so far, shape (T, 3) [m] (a copy, e.g. for a trail)."""
        return np.array(self._ee_pos).reshape(-1, 3)

    def to_demo(self, ep_meta: dict[str, Any]) -> DemoRecord:
        """The finished demo.

        Args:
            ep_meta: Episode metadata to store (a copy is stored).

        Raises:
            RecordingError: Fewer than :data:`~bt_pipeline.data.records.MIN_SAMPLES` samples.
        """
        if self.n_samples < MIN_SAMPLES:
            raise RecordingError(
                f"the recording has {self.n_samples} samples ({self.duration_s:.2f} s); at least "
                f"{MIN_SAMPLES} are needed; nothing was saved"
            )
        ee_pos = np.array(self._ee_pos)
        timestamps = np.array(self._t)
        return DemoRecord(
            ee_pos=ee_pos,
            timestamps=timestamps,
            demonstrator=self.info.demonstrator,
            theta_deg=self.info.theta_deg,
            rho=self.info.rho,
            source="teleop",
            actions=forward_difference_actions(ee_pos, timestamps),
            created=self.info.created.isoformat(timespec="seconds"),
            ep_meta=dict(ep_meta),
            ee_quat=np.array(self._ee_quat),
            joint_pos=np.array(self._joint_pos),
            gripper=np.array(self._gripper)[:, None] if self.has_gripper else None,
            states=np.array(self._states),
        )


def env_args(scene: SceneModel, *, control_hz: float, record_hz: float) -> dict[str, Any]:
    """robomimic's ``env_args`` for a demo recorded in `scene`, with the composed model XML."""
    try:
        scene_file = str(scene.scene_file.resolve().relative_to(SCENES_DIR.parent))
    except ValueError:  # a scene outside the repository
        scene_file = str(scene.scene_file)
    return {
        "env_name": f"bt_{scene.task}",
        "type": DEFAULT_ENV_TYPE,
        "env_kwargs": {
            "task": scene.task,
            "robot": scene.robot,
            "robot_source": scene.robot_source,
            "scene_file": scene_file,
            "timestep_s": float(scene.model.opt.timestep),
            "control_hz": float(control_hz),
            "record_hz": float(record_hz),
            "state_signature": STATE_SIGNATURE,
            "state_size": int(mujoco.mj_stateSize(scene.model, STATE_SIGNATURE)),
            "model_xml": scene.xml,
        },
    }


def save_demo(
    demo: DemoRecord, scene: SceneModel, recordings_dir: str | Path, env: dict[str, Any]
) -> Path:
    """Write `demo` as a one-demo recording to a fresh file under ``<recordings_dir>/<task>/``.

    Returns:
        The file written.

    Raises:
        RecordingError: The demo breaks format v1 (nothing is written).
    """
    recording = Recording(task=scene.task, plane=scene.plane, demos={"demo_0": demo}, env_args=env)
    created = datetime.fromisoformat(demo.created) if demo.created else datetime.now().astimezone()
    path = demo_path(recordings_dir, scene.task, demo.demonstrator, created)
    return write_recording(path, recording)


def site_quat(data: mujoco.MjData, site_id: int) -> FloatArray:
    """Orientation wxyz (4,) of site `site_id` in `data` (kinematics must be up to date)."""
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, data.site_xmat[site_id])
    return quat


def take_sample(
    recorder: DemoRecorder, scene: SceneModel, data: mujoco.MjData, *, clamped: bool = False
) -> None:
    """Add the state of `data` (kinematics up to date) to `recorder` as its next sample."""
    state = np.empty(mujoco.mj_stateSize(scene.model, STATE_SIGNATURE))
    mujoco.mj_getState(scene.model, data, state, STATE_SIGNATURE)
    fingers = list(scene.gripper_qpos_adr)
    recorder.add(
        data.time,
        data.site_xpos[scene.site_id],
        site_quat(data, scene.site_id),
        data.qpos[list(scene.arm_qpos_adr)],
        float(data.qpos[fingers].sum()) if fingers else 0.0,
        state,
        clamped=clamped,
    )


def finish_demo(
    recorder: DemoRecorder,
    scene: SceneModel,
    recordings_dir: str | Path,
    *,
    incomplete: bool,
    session_id: str,
    flags: str = "",
    control_hz: float,
    record_hz: float,
) -> Path:
    """Turn a recorder's samples into a demo file; returns the file written.

    `flags` is the demo attr ``flags`` (the failed take checks, comma-separated; none when
    empty).

    Raises:
        RecordingError: Too few samples, or the demo cannot be written (nothing is written).
    """
    ep_meta: dict[str, Any] = {
        "incomplete": incomplete,
        "session": session_id,
        "robot": scene.robot,
        "clamped_samples": recorder.clamped_samples,
        "ik_failures": recorder.ik_failures,
    }
    demo = recorder.to_demo(ep_meta)
    if flags:
        demo = replace(demo, attrs={**demo.attrs, "flags": flags})
    env = env_args(scene, control_hz=control_hz, record_hz=record_hz)
    return save_demo(demo, scene, recordings_dir, env)
