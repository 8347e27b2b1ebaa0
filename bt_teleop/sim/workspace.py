"""Where end-effector targets may go: the workspace box, the task-plane projection, the slew.

Targets arrive from a browser gizmo or a script and may be anywhere (or garbage), and may jump.
Before the IK sees one it is optionally projected onto the task plane, clamped into the scene's
workspace box, and approached at a bounded speed (:func:`slew_toward`), so the control loop only
ever tracks finite targets a small step away from the current command.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError


@dataclass(frozen=True, eq=False)  # holds arrays: compare fields explicitly
class Workspace:
    """An axis-aligned box in the world frame."""

    lo: FloatArray
    """Lower corner, shape (3,), in [m]."""
    hi: FloatArray
    """Upper corner, shape (3,), in [m]."""

    def __post_init__(self) -> None:
        lo = np.asarray(self.lo, dtype=np.float64)
        hi = np.asarray(self.hi, dtype=np.float64)
        if lo.shape != (3,) or hi.shape != (3,):
            raise ConfigError(f"workspace corners must have shape (3,); got {lo.shape}, {hi.shape}")
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo <= hi)):
            raise ConfigError(
                f"workspace needs finite corners with lo <= hi; got lo {lo.tolist()}, "
                f"hi {hi.tolist()}"
            )
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    def clamp(self, p_world: ArrayLike) -> tuple[FloatArray, bool]:
        """The nearest point of the box to `p_world` (3,) [m], and whether it moved."""
        p = np.asarray(p_world, dtype=np.float64)
        clamped = np.clip(p, self.lo, self.hi)
        return clamped, bool(np.any(clamped != p))

    def contains(self, p_world: ArrayLike, tol: float = 1e-9) -> bool:
        """Whether `p_world` (3,) [m] lies in the box (up to `tol` [m])."""
        p = np.asarray(p_world, dtype=np.float64)
        return bool(np.all(p >= self.lo - tol) and np.all(p <= self.hi + tol))


def project_onto_plane(plane: TaskPlane, p_world: ArrayLike) -> FloatArray:
    """The orthogonal projection of `p_world` (3,) [m] onto `plane`, shape (3,) [m]."""
    p = np.asarray(p_world, dtype=np.float64)
    return plane.to_world(plane.to_plane(p))


MAX_TARGET_M = 10.0
"""Largest |coordinate| of a target a client may send [m] (the workspace then clamps it)."""


def validate_position(p_world: ArrayLike, what: str = "target position") -> FloatArray:
    """`p_world` as a finite float array of shape (3,) [m] (a copy).

    Raises:
        ConfigError: Wrong shape or not finite.
    """
    try:
        p = np.array(p_world, dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError(f"{what} must be 3 numbers [m]; got {p_world!r}") from None
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise ConfigError(f"{what} must be 3 finite numbers [m]; got {p.tolist()}")
    if not float(np.max(np.abs(p))) <= MAX_TARGET_M:
        raise ConfigError(f"{what} must lie within {MAX_TARGET_M:g} m of the world origin")
    return p


def validate_quat(quat: ArrayLike, what: str = "target orientation") -> FloatArray:
    """`quat` (wxyz) as a unit quaternion, shape (4,) (a normalised copy).

    Raises:
        ConfigError: Wrong shape, not finite, or (near) zero norm.
    """
    try:
        q = np.array(quat, dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError(f"{what} must be a quaternion (w, x, y, z); got {quat!r}") from None
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise ConfigError(f"{what} must be 4 finite numbers (w, x, y, z); got {q.tolist()}")
    norm = float(np.linalg.norm(q))
    if norm < 1e-6:
        raise ConfigError(f"{what} has zero norm; a rotation quaternion has norm 1")
    return q / norm


def slew_toward(
    pos: FloatArray,
    quat: FloatArray,
    goal_pos: FloatArray,
    goal_quat: FloatArray,
    max_step_m: float,
    max_step_rad: float,
) -> tuple[FloatArray, FloatArray]:
    """Move a pose towards a goal by at most a given distance and angle (new arrays).

    A big jump of the target (a click far away, an orientation half a turn off) would make the
    differential IK take maximal steps and, near a half-turn, flip between two solutions tick
    after tick; stepping the command towards the goal keeps every IK step small.

    Args:
        pos: Current command position, shape (3,), in [m].
        quat: Current command orientation wxyz, shape (4,), unit norm.
        goal_pos: Goal position, shape (3,), in [m].
        goal_quat: Goal orientation wxyz, shape (4,), unit norm.
        max_step_m: Largest position step [m].
        max_step_rad: Largest rotation step [rad].

    Returns:
        The new position (3,) [m] and orientation wxyz (4,).
    """
    delta = np.asarray(goal_pos, dtype=np.float64) - pos
    distance = float(np.linalg.norm(delta))
    new_pos = pos + delta * min(1.0, max_step_m / distance) if distance > 0.0 else pos.copy()
    goal = np.asarray(goal_quat, dtype=np.float64)
    dot = float(np.dot(quat, goal))
    if dot < 0.0:  # q and -q are the same rotation: take the short way
        goal, dot = -goal, -dot
    angle = 2.0 * math.acos(min(1.0, dot))
    if angle <= max_step_rad or angle < 1e-12:
        return new_pos, goal.copy()
    fraction = max_step_rad / angle
    half = angle / 2.0  # slerp on the unit quaternions
    new_quat = (
        math.sin((1.0 - fraction) * half) * np.asarray(quat) + math.sin(fraction * half) * goal
    ) / math.sin(half)
    return new_pos, new_quat / np.linalg.norm(new_quat)
