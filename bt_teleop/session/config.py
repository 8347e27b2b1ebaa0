"""A session's settings (:class:`SessionConfig`) and snapshot (:class:`SessionStatus`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError
from bt_teleop.sim.ik import IkSettings
from bt_teleop.takes.checks import TakeCheckConfig


@dataclass(frozen=True)
class SessionConfig:
    """Rates and policies of a session."""

    control_hz: float = 100.0
    """IK and actuator command rate [Hz]; a whole number of physics steps per tick."""
    record_hz: float = 50.0
    """Sampling rate of recordings on simulation time [Hz]; divides control_hz."""
    max_speed_m_s: float = 1.0
    """Fastest the commanded target follows the user's target [m/s]."""
    max_turn_rad_s: float = 3.0
    """Fastest the commanded orientation follows the user's [rad/s]."""
    max_lag_s: float = 0.25
    """Real-time loop: when it falls further behind than this [s] it skips ahead."""
    save_incomplete: bool = True
    """What :meth:`Session.close` does with a recording in progress: save it flagged
    incomplete (True) or discard it (False)."""
    priority_boost: int = 5
    """The app's real-time loops (:class:`bt_teleop.session.tick_stats.TimedSession`) lower their
    thread's nice value by this much (0..20): the CPU serves them before the app's web server
    and library loads. Needs CAP_SYS_NICE or a ``ulimit -e`` that allows it (Linux); without,
    the loop keeps its priority (logged)."""
    realtime_priority: int = 10
    """When > 0 (1..99), the control loop runs under the real-time policy ``SCHED_RR`` at this
    priority, its process's command thread one step below
    (:func:`bt_teleop.proc.priority.use_realtime`,
    :func:`bt_teleop.proc.priority.command_priority`): the machine's other work then cannot
    keep them waiting for a CPU. Tried by default, as ros2_control's controller manager does: it
    needs root, CAP_SYS_NICE or ``ulimit -r``, and where not permitted the loop keeps the normal
    policy (logged). 0: never (docs/security.md, "Real-time by default")."""
    late_tick_s: float = 0.05
    """A control tick later than this beyond the period [s] is attributed (what the loop's
    thread and process did meanwhile: :mod:`bt_teleop.session.late_ticks`); ``inf``: never (the
    probe then reads nothing)."""
    release_memory_after_take: bool = True
    """A session in a child process (:mod:`bt_teleop.session.child`), after each take it saved
    or dropped, empties HDF5's free lists and gives its C heap's free pages back
    (:func:`bt_teleop.proc.native_memory.release_free_memory`), so what one take needed is not kept
    resident for the next (docs/security.md, the session children's memory)."""
    ik: IkSettings = field(default_factory=IkSettings)
    """IK weights and limits."""
    take_checks: TakeCheckConfig = field(default_factory=TakeCheckConfig)
    """Thresholds of the checks on Stop & save (:mod:`bt_teleop.takes.checks`)."""

    def __post_init__(self) -> None:
        for name in ("control_hz", "record_hz", "max_speed_m_s", "max_turn_rad_s", "max_lag_s"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (
                isinstance(value, int | float) and math.isfinite(value) and value > 0.0
            ):
                raise ConfigError(f"{name} must be a positive number; got {value!r}")
        rt = self.realtime_priority
        if isinstance(rt, bool) or not isinstance(rt, int) or not 0 <= rt <= 99:
            raise ConfigError(f"realtime_priority must be a whole number in 0..99; got {rt!r}")
        late = self.late_tick_s
        if isinstance(late, bool) or not (isinstance(late, int | float) and late > 0.0):
            raise ConfigError(f"late_tick_s must be a positive number or inf; got {late!r}")
        boost = self.priority_boost
        if isinstance(boost, bool) or not isinstance(boost, int) or not 0 <= boost <= 20:
            raise ConfigError(f"priority_boost must be a whole number in 0..20; got {boost!r}")


@dataclass(frozen=True, eq=False)  # holds arrays: compare fields explicitly
class SessionStatus:
    """A snapshot of a session for a UI (all arrays are copies)."""

    sim_time_s: float
    """Simulation time [s]."""
    qpos: FloatArray
    """Full MuJoCo qpos, shape (nq,) (to draw the scene)."""
    ee_pos: FloatArray
    """End-effector (attachment_site) position, shape (3,), in [m]."""
    ee_quat: FloatArray
    """End-effector orientation wxyz, shape (4,)."""
    joint_pos: FloatArray
    """Arm joint positions, shape (7,), in [rad]."""
    target_pos: FloatArray
    """The user's target after projection and clamping, shape (3,), in [m]."""
    target_quat: FloatArray
    """The user's target orientation wxyz, shape (4,)."""
    command_pos: FloatArray
    """The target the IK tracks this tick (the user's, approached at bounded speed), (3,) [m]."""
    command_quat: FloatArray
    """Orientation the IK tracks this tick, wxyz, shape (4,)."""
    target_clamped: bool
    """Whether the latest target was moved into the workspace box."""
    gripper_open: bool | None
    """Gripper command (None without a gripper)."""
    ik_ok: bool
    """Whether the latest IK tick succeeded."""
    warning: str | None
    """The latest IK or simulation warning, None when all is well."""
    ik_failures: int
    """IK ticks that failed since the session started."""
    recording: bool
    """Whether a demo is being recorded."""
    n_samples: int
    """Samples of the demo in progress (0 when not recording)."""
    duration_s: float
    """Duration of the demo in progress [s]."""
    running: bool
    """Whether the real-time background loop runs."""


def whole_steps(ratio: float, what: str) -> int:
    """`ratio` as a positive integer (steps per tick, ticks per sample), or an error naming the
    rate to fix."""
    n = round(ratio)
    if n < 1 or abs(ratio - n) > 1e-6:
        hint = (
            "control_hz must be timestep⁻¹ divided by a whole number"
            if what == "physics"
            else "record_hz must divide control_hz"
        )
        raise ConfigError(f"rates do not fit: {ratio:.6g} {what} steps per tick; {hint}")
    return n
