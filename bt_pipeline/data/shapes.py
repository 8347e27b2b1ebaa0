"""Canonical task shapes in task-plane coordinates and the demonstrator similarity transform.

Each task with a built-in guide (:data:`~bt_pipeline.data.tasks.TASKS`) has one closed, smooth
(C^∞: a trigonometric polynomial), periodic shape x(φ) with phase φ ∈ [0, 2π), centred at the
origin of task coordinates (the centre of its bounding box) and symmetric about the y axis (paper
Sec. III, L1). Increasing φ is the canonical direction. Other tasks have no built-in shape.

* ``wiping``: a rounded rectangle, 0.24 m × 0.12 m, traced counter-clockwise.
* ``weaving``: a figure-eight (lemniscate of Gerono) with its two loops left and right of the
  y axis, 0.30 m × 0.15 m.
* ``pick_and_place``: a closed arch, 0.30 m × 0.15 m: from the left place over high to the right
  place (outbound), then back low and nearly flat (return).

A demonstrator's preference (paper Sec. III-A, Fig. 4) is a similarity transform: rotation by
θ [deg] counter-clockwise and isotropic scale ρ about the origin, then a translation to the task
centre (:func:`similarity_transform`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.tasks import TASKS, GuidedTask, Task, has_guide, parse_task
from bt_pipeline.exceptions import ConfigError, UnknownTaskError

SHAPE_SIZE: dict[GuidedTask, tuple[float, float]] = {
    "wiping": (0.24, 0.12),
    "weaving": (0.30, 0.15),
    "pick_and_place": (0.30, 0.15),
}
"""Bounding-box width × height [m] of each canonical shape (θ = 0, ρ = 1)."""

_SQUARENESS = 0.1
"""Weight of the third harmonic that squares the wiping oval off (0 is an ellipse)."""
_RETURN_DEPTH = 1.0 / 3.0
"""Depth of the pick-and-place return path relative to the height of the outbound arch."""


def canonical_shape(task: Task, phase: ArrayLike) -> FloatArray:
    """The canonical shape of `task` at the given phases.

    Args:
        task: The task.
        phase: Phases φ [rad], shape (n,) (any shape works); periodic with period 2π.

    Returns:
        Task-plane positions x(φ), shape (n, 2) (the phase's shape plus a last axis of 2), in [m].

    Raises:
        UnknownTaskError: `task` is not a valid task name, or a task without a built-in guide
            (not one of :data:`bt_pipeline.data.tasks.TASKS`).
    """
    task = parse_task(task)
    if not has_guide(task):
        raise UnknownTaskError(
            f"task {task!r} has no built-in guide shape; built-in shapes exist for "
            f"{', '.join(TASKS)} only"
        )
    phi = np.asarray(phase, dtype=np.float64)
    half_w, half_h = (s / 2.0 for s in SHAPE_SIZE[task])
    if task == "wiping":
        # x(π - φ) = -x(φ), y(π - φ) = y(φ): mirror symmetric; extremes ±half_w at φ = 0, π and
        # ±half_h at φ = ±π/2.
        c = _SQUARENESS
        x = half_w * (np.cos(phi) - c * np.cos(3.0 * phi)) / (1.0 - c)
        y = half_h * (np.sin(phi) + c * np.sin(3.0 * phi)) / (1.0 - c)
    elif task == "weaving":
        # Lemniscate of Gerono: x(φ + π) = -x(φ), y(φ + π) = y(φ).
        x = half_w * np.sin(phi)
        y = half_h * np.sin(2.0 * phi)
    else:
        # x runs from the left place (φ = 0) to the right one (φ = π) and back. y = s + k s² with
        # s = sin φ is an arch of height 1 + k above the places on the way out and a shallow
        # dip of depth 1 - k below them on the way back; shifted to centre the bounding box.
        s = np.sin(phi)
        k = (1.0 - _RETURN_DEPTH) / (1.0 + _RETURN_DEPTH)
        top, bottom = 1.0 + k, -(1.0 - k)
        x = -half_w * np.cos(phi)
        y = half_h * (2.0 * (s + k * s * s) - (top + bottom)) / (top - bottom)
    return np.stack([x, y], axis=-1)


def canonical_loop(task: Task, n: int = 300) -> FloatArray:
    """`n` points of the canonical shape at uniform phase, endpoint excluded.

    The phases are φ_k = 2πk/n for k = 0..n-1, so the loop is closed implicitly: the point after
    the last one is the first one (φ = 2π ≡ 0).

    Args:
        task: The task.
        n: Number of points, at least 3.

    Returns:
        Positions, shape (n, 2), in [m].

    Raises:
        ConfigError: `n` < 3.
        UnknownTaskError: `task` has no built-in guide (see :func:`canonical_shape`).
    """
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 3:
        raise ConfigError(f"canonical_loop needs an integer n >= 3; got {n!r}")
    phase = 2.0 * np.pi * np.arange(int(n)) / int(n)
    return canonical_shape(task, phase)


def rotation_matrix(theta_deg: float) -> FloatArray:
    """Counter-clockwise rotation R(θ), shape (2, 2), for θ in [deg]."""
    t = math.radians(theta_deg)
    return np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])


def similarity_transform(
    points: ArrayLike,
    theta_deg: float,
    rho: float,
    centre: Sequence[float] | FloatArray = (0.0, 0.0),
) -> FloatArray:
    """Apply a demonstrator's preference: ``rho · R(θ) · p + centre``.

    Rotates counter-clockwise by θ and scales by ρ about the origin, then translates to `centre`.
    The inverse of ``(θ, ρ, c)`` is ``similarity_transform(q - c, -θ, 1/ρ)``.

    Args:
        points: Positions, shape (n, 2) (any shape with a last axis of 2), in [m].
        theta_deg: Rotation θ [deg], counter-clockwise.
        rho: Scale ρ, > 0.
        centre: Translation applied last, shape (2,), in [m].

    Returns:
        Transformed positions, a new array of the shape of `points`, in [m].

    Raises:
        ConfigError: `points` has no last axis of 2, θ is not finite, ρ is not a finite number
            > 0, or `centre` is not 2 finite numbers.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim < 1 or p.shape[-1] != 2:
        raise ConfigError(f"points must have a last axis of size 2; got shape {p.shape}")
    if not math.isfinite(theta_deg):
        raise ConfigError(f"theta_deg must be finite; got {theta_deg}")
    if not (math.isfinite(rho) and rho > 0.0):
        raise ConfigError(f"rho must be a finite number > 0; got {rho}")
    c = np.asarray(centre, dtype=np.float64)
    if c.shape != (2,) or not np.all(np.isfinite(c)):
        raise ConfigError(f"centre must be 2 finite numbers; got {np.asarray(centre).tolist()}")
    return rho * p @ rotation_matrix(theta_deg).T + c


__all__ = [
    "SHAPE_SIZE",
    "canonical_loop",
    "canonical_shape",
    "rotation_matrix",
    "similarity_transform",
]
