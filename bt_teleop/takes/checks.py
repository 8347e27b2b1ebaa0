"""Take checks on Stop & save: is a take a demonstration of the task, or junk?

A crowdsourced collection gets takes stopped a moment after Record, takes where nothing moved
and takes cut short (a closed tab, three drags and a save). They are kept as files, never lost,
but marked with the demo attr ``flags`` (docs/recording-format.md), so they are never the best
demo and scoring and cleaning skip them. The checks, in task-plane coordinates::

    too_short        duration < min_duration_s
    no_motion        largest distance of any sample from the first < min_motion_m
    incomplete       the take does not close one loop of its own
    closed_mid_take  the tab closed while recording

and one remark, written to ``flags`` too but informational: the take is kept, scored and
cleaned (:data:`bt_pipeline.data.records.INFO_FLAGS`)::

    off_guide        the take's own loop is more than max_guide_misfit off the guide's shape

**Own loop** (:func:`bt_pipeline.clean.recurrence.own_loop`): where the take's path returns to
itself, running the same way, with no template; one loop of it, 256 points uniform in arc
length. An approach, a retreat, pauses, uneven sample times and the loop's size, turn and shape
do not matter; a part of a loop, a stroke that stops and a straight drag (back and forth runs
the opposite way) close none. Labs draw loops of other shapes than bt's guide, which is only a
hint: a closed loop of any shape is a demonstration.

**Off the guide**: the take's own loop against the guide (the task's drawn loop,
:meth:`~bt_pipeline.data.loop_shape.LoopShape.guide`, resampled by arc length to the same 256
points) by the closed-form similarity alignment :func:`bt_pipeline.clean.loop_learn.align`,
over start point and direction: the RMS residual as a share of the loop's RMS radius. So θ, ρ
and where on the plane the loop is drawn do not count, only its shape. The threshold is
:data:`~bt_pipeline.clean.loop_learn.GUIDE_MISFIT` (12 %), the misfit up to which the cleaner
takes a set's loop for the guide.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from bt_pipeline.clean.loop_align import align, loop_signature
from bt_pipeline.clean.loop_learn import GUIDE_MISFIT
from bt_pipeline.clean.recurrence import own_loop
from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.records import INFO_FLAGS, FloatArray, TakeFlag
from bt_pipeline.data.tasks import TASKS, Task
from bt_pipeline.exceptions import ConfigError, DemoError

__all__ = ["TakeCheck", "TakeCheckConfig", "check_take", "guide_misfit"]


@dataclass(frozen=True)
class TakeCheckConfig:
    """Thresholds of the take checks (``AppOptions.take_checks``; docs/teleop.md)."""

    min_duration_s: float = 2.0
    """Shortest take [s] that is not ``too_short``."""
    min_motion_m: float = 0.02
    """A take whose samples all stay within this distance [m] of its first is ``no_motion``."""
    max_guide_misfit: float = GUIDE_MISFIT
    """A take whose own loop lies farther than this share (0..1) of its RMS radius from every
    similarity of the guide is ``off_guide`` (12 %: careful browser loops along the guide are
    3-10 % off, an ellipse of aspect 1.5 is 12 %, a circle inside the wiping guide 27 %)."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.min_duration_s) and self.min_duration_s >= 0.0):
            raise ConfigError(f"min_duration_s must be ≥ 0 [s]; got {self.min_duration_s}")
        if not (math.isfinite(self.min_motion_m) and self.min_motion_m >= 0.0):
            raise ConfigError(f"min_motion_m must be ≥ 0 [m]; got {self.min_motion_m}")
        if not (math.isfinite(self.max_guide_misfit) and self.max_guide_misfit > 0.0):
            raise ConfigError(f"max_guide_misfit must be > 0; got {self.max_guide_misfit}")


@dataclass(frozen=True)
class TakeCheck:
    """What the checks found in one take."""

    flags: tuple[TakeFlag, ...]
    """Failed checks, in the order too_short, no_motion, incomplete, closed_mid_take, then the
    remark off_guide (the demo attr ``flags``)."""
    duration_s: float
    """Length of the take [s]."""
    motion_m: float
    """Largest distance of a sample from the first [m]."""
    loops: float
    """About how many of its own loops the take draws (0: it closes none)."""
    guide_misfit: float
    """Its own loop's distance from the guide's shape, a share of the loop's RMS radius (NaN
    when it closes no loop or the task has no guide)."""
    config: TakeCheckConfig
    """The thresholds used."""

    @property
    def ok(self) -> bool:
        """Whether the take passed every check (a remark such as ``off_guide`` is no failure)."""
        return all(flag in INFO_FLAGS for flag in self.flags)

    @property
    def attr(self) -> str:
        """The demo attr ``flags``: comma-separated, empty when the take passed with no remark."""
        return ",".join(self.flags)

    def reasons(self) -> list[str]:
        """One sentence per failed check, for the person who recorded the take."""
        c = self.config
        text: dict[TakeFlag, str] = {
            "too_short": f"too short: {self.duration_s:.1f} s (at least {c.min_duration_s:g} s)",
            "no_motion": (
                f"no motion: the end effector moved {1e3 * self.motion_m:.0f} mm "
                f"(at least {1e3 * c.min_motion_m:.0f} mm)"
            ),
            "incomplete": (
                "incomplete: it never comes back round to where it was (draw a whole loop)"
            ),
            "closed_mid_take": "the tab closed during the take",
        }
        return [text[flag] for flag in self.flags if flag not in INFO_FLAGS]

    def remarks(self) -> list[str]:
        """One sentence per remark (``off_guide``): worth knowing, but the take is used."""
        return [
            f"off the guide: its loop's shape is {100 * self.guide_misfit:.0f} % of its size "
            f"from the blue loop's ({100 * self.config.max_guide_misfit:.0f} % at most counts "
            "as along it); kept and cleaned"
            for flag in self.flags
            if flag == "off_guide"
        ]


def guide_misfit(loop_uv: FloatArray, task: str) -> float:
    """Distance of a closed loop from the nearest similarity of `task`'s guide (module doc).

    Args:
        loop_uv: One closed loop, endpoint excluded, shape (P, 2) [m] (e.g. an
            :class:`~bt_pipeline.clean.recurrence.OwnLoop`'s ``loop``); resampled to 256 points
            uniform in arc length, as the guide is, so that points correspond.
        task: A task with a guide (one of ``TASKS``).

    Returns:
        The RMS residual as a share (0..1) of the loop's RMS radius (inf for a degenerate loop).
    """
    return align(loop_signature(np.asarray(loop_uv, dtype=np.float64)), _guide_points(task))[3]


@functools.cache
def _guide_points(task: str) -> np.ndarray:
    """`task`'s guide as 256 centred complex points uniform in arc length (read-only)."""
    z = loop_signature(LoopShape.guide(task).points(1024))
    z.setflags(write=False)
    return z


def check_take(
    ee_pos: FloatArray,
    timestamps: FloatArray,
    *,
    task: Task,
    plane: TaskPlane,
    theta_deg: float = math.nan,
    rho: float = math.nan,
    closed_mid_take: bool = False,
    config: TakeCheckConfig | None = None,
) -> TakeCheck:
    """Check one take against the thresholds.

    Args:
        ee_pos: End-effector positions in the world frame, shape (T, 3) [m].
        timestamps: Sample times, shape (T,) [s].
        task: The task recorded (``off_guide`` is checked for a task with a guide only).
        plane: Its task plane.
        theta_deg: The take's θ [deg]; unused: the checks compare shapes up to a similarity.
        rho: The take's ρ; unused, as θ.
        closed_mid_take: The tab closed while recording (adds ``closed_mid_take``).
        config: Thresholds; the defaults when None.
    """
    config = config or TakeCheckConfig()
    pos = np.asarray(ee_pos, dtype=np.float64).reshape(-1, 3)
    times = np.asarray(timestamps, dtype=np.float64).reshape(-1)
    duration = float(times[-1] - times[0]) if len(times) > 1 else 0.0
    motion = float(np.max(np.linalg.norm(pos - pos[0], axis=1))) if len(pos) else 0.0
    try:
        found = own_loop(plane.to_plane(pos), times, "the take")
    except DemoError:  # fewer than 4 samples, times not increasing, NaN: no loop to find
        found = None
    loop = found.loop if found is not None and found.closes else None
    misfit = guide_misfit(loop, task) if loop is not None and task in TASKS else math.nan
    flags: list[TakeFlag] = []
    if duration < config.min_duration_s:
        flags.append("too_short")
    if motion < config.min_motion_m:
        flags.append("no_motion")
    if loop is None:
        flags.append("incomplete")
    if closed_mid_take:
        flags.append("closed_mid_take")
    if misfit > config.max_guide_misfit:
        flags.append("off_guide")
    loops = found.loops if loop is not None and found is not None else 0.0
    return TakeCheck(tuple(flags), duration, motion, loops, misfit, config)
