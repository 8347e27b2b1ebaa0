"""Take checks on Stop & save: is a take a demonstration of the task, or junk?

A crowdsourced collection gets takes stopped a moment after Record, takes where nothing moved
and takes cut short (a closed tab, three drags and a save). They are kept as files, never lost,
but marked with the demo attr ``flags`` (docs/recording-format.md), so they are never the best
demo and scoring and cleaning skip them. The checks, in task-plane coordinates::

    too_short   duration < min_duration_s
    no_motion   largest distance of any sample from the first < min_motion_m
    incomplete  share of the guide's angular sectors the take reaches < min_loop_share

Loop share, measured against the guide (the task's canonical loop under the take's θ and ρ,
centred on the plane origin, at uniform phase): the share of the guide's points that have a
sample of the take within ``tolerance_share`` of the guide's RMS radius, in task-plane
coordinates. It ignores where the take starts, its speed, pauses, an approach and a retreat
(they cover little of the loop), and a loop drawn up to about 15 % larger or smaller than the
guide; a straight drag across the plane covers only the points near where it crosses the loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import KDTree

from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.records import FloatArray, TakeFlag
from bt_pipeline.data.shapes import canonical_loop, similarity_transform
from bt_pipeline.data.tasks import Task
from bt_pipeline.exceptions import ConfigError

__all__ = ["TakeCheck", "TakeCheckConfig", "check_take", "loop_share"]


@dataclass(frozen=True)
class TakeCheckConfig:
    """Thresholds of the take checks (``AppOptions.take_checks``; docs/teleop.md)."""

    min_duration_s: float = 2.0
    """Shortest take [s] that is not ``too_short``."""
    min_motion_m: float = 0.02
    """A take whose samples all stay within this distance [m] of its first is ``no_motion``."""
    min_loop_share: float = 0.6
    """Least share (0..1) of the guide's sectors a take must reach not to be ``incomplete``."""
    tolerance_share: float = 0.15
    """A guide point is reached when a sample is within this share of the guide's RMS radius."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.min_duration_s) and self.min_duration_s >= 0.0):
            raise ConfigError(f"min_duration_s must be ≥ 0 [s]; got {self.min_duration_s}")
        if not (math.isfinite(self.min_motion_m) and self.min_motion_m >= 0.0):
            raise ConfigError(f"min_motion_m must be ≥ 0 [m]; got {self.min_motion_m}")
        if not 0.0 <= self.min_loop_share <= 1.0:
            raise ConfigError(f"min_loop_share must be in [0, 1]; got {self.min_loop_share}")
        if not (math.isfinite(self.tolerance_share) and 0.0 < self.tolerance_share <= 1.0):
            raise ConfigError(f"tolerance_share must be in (0, 1]; got {self.tolerance_share}")


@dataclass(frozen=True)
class TakeCheck:
    """What the checks found in one take."""

    flags: tuple[TakeFlag, ...]
    """Failed checks, in the order too_short, no_motion, incomplete, closed_mid_take."""
    duration_s: float
    """Length of the take [s]."""
    motion_m: float
    """Largest distance of a sample from the first [m]."""
    loop_share: float
    """Share (0..1) of the guide's points reached."""
    config: TakeCheckConfig
    """The thresholds used."""

    @property
    def ok(self) -> bool:
        """Whether the take passed every check."""
        return not self.flags

    @property
    def attr(self) -> str:
        """The demo attr ``flags``: comma-separated, empty when the take passed."""
        return ",".join(self.flags)

    def reasons(self) -> list[str]:
        """One sentence per flag, for the person who recorded the take."""
        c = self.config
        text: dict[TakeFlag, str] = {
            "too_short": f"too short: {self.duration_s:.1f} s (at least {c.min_duration_s:g} s)",
            "no_motion": (
                f"no motion: the end effector moved {1e3 * self.motion_m:.0f} mm "
                f"(at least {1e3 * c.min_motion_m:.0f} mm)"
            ),
            "incomplete": (
                f"incomplete: it follows {100 * self.loop_share:.0f} % of the blue loop "
                f"(at least {100 * c.min_loop_share:.0f} %)"
            ),
            "closed_mid_take": "the tab closed during the take",
        }
        return [text[flag] for flag in self.flags]


def loop_share(uv: FloatArray, guide_uv: FloatArray, tolerance_share: float = 0.15) -> float:
    """Share (0..1) of the guide's points that the take `uv` comes close to.

    Args:
        uv: The take in task coordinates, shape (T, 2) [m].
        guide_uv: The guide loop at uniform phase, centred on the origin, shape (N, 2) [m].
        tolerance_share: A guide point is reached when a sample is within this share of the
            guide's RMS radius.
    """
    guide = np.asarray(guide_uv, dtype=np.float64).reshape(-1, 2)
    take = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    if len(guide) == 0 or len(take) == 0:
        return 0.0
    tolerance = tolerance_share * float(np.sqrt(np.mean(np.sum(guide**2, axis=1))))
    distance, _ = KDTree(take).query(guide, k=1, distance_upper_bound=tolerance)
    return float(np.mean(np.isfinite(distance)))


def check_take(
    ee_pos: FloatArray,
    timestamps: FloatArray,
    *,
    task: Task,
    plane: TaskPlane,
    theta_deg: float,
    rho: float,
    closed_mid_take: bool = False,
    config: TakeCheckConfig | None = None,
) -> TakeCheck:
    """Check one take against the thresholds.

    Args:
        ee_pos: End-effector positions in the world frame, shape (T, 3) [m].
        timestamps: Sample times, shape (T,) [s].
        task: The task recorded.
        plane: Its task plane.
        theta_deg: The take's θ [deg] (the guide's rotation; 0 when NaN).
        rho: The take's ρ (the guide's scale; 1 when NaN).
        closed_mid_take: The tab closed while recording (adds ``closed_mid_take``).
        config: Thresholds; the defaults when None.
    """
    config = config or TakeCheckConfig()
    pos = np.asarray(ee_pos, dtype=np.float64).reshape(-1, 3)
    times = np.asarray(timestamps, dtype=np.float64).reshape(-1)
    duration = float(times[-1] - times[0]) if len(times) > 1 else 0.0
    motion = float(np.max(np.linalg.norm(pos - pos[0], axis=1))) if len(pos) else 0.0
    theta = 0.0 if not math.isfinite(theta_deg) else float(theta_deg)
    scale = 1.0 if not (math.isfinite(rho) and rho > 0.0) else float(rho)
    guide = similarity_transform(canonical_loop(task, 240), theta, scale)
    share = loop_share(plane.to_plane(pos), guide, config.tolerance_share)
    flags: list[TakeFlag] = []
    if duration < config.min_duration_s:
        flags.append("too_short")
    if motion < config.min_motion_m:
        flags.append("no_motion")
    if share < config.min_loop_share:
        flags.append("incomplete")
    if closed_mid_take:
        flags.append("closed_mid_take")
    return TakeCheck(tuple(flags), duration, motion, share, config)
