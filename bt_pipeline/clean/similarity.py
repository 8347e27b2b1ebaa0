"""The similarity fit's pieces: its result, its allowed range and its ICP steps.

A fit maps the task's loop q onto a demo's points p by p ≈ ρ R(θ) q + t (:class:`GuideFit`,
within a :class:`PreferenceRange`). :func:`icp` pairs each point with its nearest loop point and
solves :func:`solve_similarity`, a weighted least squares, clipped to the allowed θ/ρ range or
with θ and/or ρ held fixed; :func:`~bt_pipeline.clean.guide_fit.fit_guide` runs it from several
starts, and :mod:`~bt_pipeline.clean.guide_consensus` from each half of a lopsided loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import KDTree

from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError

_POINT_WEIGHT = 0.05  # Weight of the point-to-point term beside the point-to-tangent one.
GUIDE_POINTS = 1024  # Dense guide for nearest-point pairing (< 0.4 mm spacing).
FIT_POINTS = 240  # Arc-length resampled demo points used by the fit.


@dataclass(frozen=True)
class PreferenceRange:
    """Allowed demonstrator preferences for estimation (``bt clean`` flags)."""

    theta_max_deg: float = 45.0
    """|θ| ≤ this [deg]."""
    rho_min: float = 0.5
    """Smallest ρ."""
    rho_max: float = 2.0
    """Largest ρ."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.theta_max_deg) and 0.0 <= self.theta_max_deg <= 180.0):
            raise ConfigError(f"theta range must be in [0, 180] deg; got {self.theta_max_deg}")
        if not (0.0 < self.rho_min <= self.rho_max < math.inf):
            raise ConfigError(
                f"rho range must satisfy 0 < min <= max; got {self.rho_min}..{self.rho_max}"
            )


@dataclass(frozen=True)
class GuideFit:
    """A similarity fit of the guide to a demo."""

    theta_deg: float
    """θ [deg], counter-clockwise, within the allowed range."""
    rho: float
    """ρ, within the allowed range."""
    translation: FloatArray
    """t, shape (2,), in [m]: where the guide's centre sits."""
    residual_m: float
    """Mean distance of the kept (trimmed) points to the fitted guide [m]."""
    size_m: float
    """The fitted guide's size, the larger side of its bounding box [m]."""
    loop: LoopShape
    """The loop fitted: the task's guide or the loop learned from the task's demos."""

    def guide(self, n: int = GUIDE_POINTS) -> FloatArray:
        """The fitted loop, `n` points of one loop, shape (n, 2), in [m]."""
        return transform(self.loop.points(n), self.theta_deg, self.rho, self.translation)


def transform(points: FloatArray, theta_deg: float, rho: float, t: FloatArray) -> FloatArray:
    """ρ R(θ) p + t for points, shape (n, 2)."""
    c, s = math.cos(math.radians(theta_deg)), math.sin(math.radians(theta_deg))
    return rho * points @ np.array([[c, s], [-s, c]]) + t


def solve_similarity(
    p: FloatArray,
    q: FloatArray,
    normal: FloatArray,
    theta: float,
    rho: float,
    theta_fixed: float | None,
    rho_fixed: float | None,
    allowed: PreferenceRange,
    centred: bool = False,
) -> tuple[float, float, FloatArray]:
    """θ, ρ, t of p ≈ ρ R(θ) q + t, point-to-tangent least squares, clipped or held fixed.

    Each pair's residual is measured along the guide's normal at q (mapped by the current θ), so
    points may slide along the guide (fast convergence on smooth loops), plus a small
    point-to-point term (weight 0.05) that keeps the problem well posed. With `centred`, t = 0.
    """
    c, s = math.cos(math.radians(theta)), math.sin(math.radians(theta))
    n = normal @ np.array([[c, s], [-s, c]])  # Normals in the demo's frame.
    w = math.sqrt(_POINT_WEIGHT)
    if theta_fixed is None or rho_fixed is None:
        # Unknowns (a, b, tx, ty) with ρ R(θ) = [[a, −b], [b, a]].
        rows = np.concatenate(
            [
                np.stack(
                    [
                        n[:, 0] * q[:, 0] + n[:, 1] * q[:, 1],
                        n[:, 1] * q[:, 0] - n[:, 0] * q[:, 1],
                        n[:, 0],
                        n[:, 1],
                    ],
                    axis=1,
                ),
                w * np.stack([q[:, 0], -q[:, 1], np.ones(len(q)), np.zeros(len(q))], axis=1),
                w * np.stack([q[:, 1], q[:, 0], np.zeros(len(q)), np.ones(len(q))], axis=1),
            ]
        )
        rhs = np.concatenate([np.sum(n * p, axis=1), w * p[:, 0], w * p[:, 1]])
        # Normal equations (2-4 unknowns, well conditioned): the same solution as lstsq's SVD
        # (identical fits on benchmarks), without its cost on this hot path.
        design = rows[:, :2] if centred else rows
        try:
            a, b = np.linalg.solve(design.T @ design, design.T @ rhs)[:2]
        except np.linalg.LinAlgError:  # Degenerate pairs: the minimum-norm solution.
            a, b = np.linalg.lstsq(design, rhs, rcond=None)[0][:2]
        th = theta_fixed if theta_fixed is not None else math.degrees(math.atan2(b, a))
        th = float(np.clip(th, -allowed.theta_max_deg, allowed.theta_max_deg))
        if rho_fixed is None:
            r = float((complex(a, b) * np.exp(-1j * math.radians(th))).real)
            r = float(np.clip(r, allowed.rho_min, allowed.rho_max))
        else:
            r = float(rho_fixed)
    else:
        th, r = float(theta_fixed), float(rho_fixed)
    if centred:
        return th, r, np.zeros(2)
    # Translation for the (clipped) rotation and scale: the same weighted least squares in t.
    mapped = transform(q, th, r, np.zeros(2))
    d = p - mapped
    nn = np.einsum("ki,kj->ij", n, n) + _POINT_WEIGHT * len(q) * np.eye(2)
    rhs_t = np.einsum("ki,kj,kj->i", n, n, d) + _POINT_WEIGHT * d.sum(axis=0)
    return th, r, np.linalg.solve(nn, rhs_t)


def icp(
    points: FloatArray,
    guide: FloatArray,
    tree: KDTree,
    th: float,
    r: float,
    t: FloatArray,
    keep: int,
    iterations: int,
    theta_fixed: float | None,
    rho_fixed: float | None,
    allowed: PreferenceRange,
    centred: bool = False,
) -> tuple[float, float, FloatArray, float]:
    """At most `iterations` trimmed ICP steps from (θ, ρ, t); returns the fit and its residual.

    With `centred`, t is held at 0 (the guide's centre on the task plane's origin).
    """
    residual = math.inf
    for _ in range(iterations):
        local = transform(points - t, -th, 1.0, np.zeros(2)) / r  # R(−θ)(p − t)/ρ
        dist, found = tree.query(local)
        dist, index = np.asarray(dist, dtype=np.float64), np.asarray(found, dtype=np.intp)
        order = np.argpartition(dist, keep - 1)[:keep]
        residual = float(np.mean(dist[order]) * r)
        g = index[order]
        tangent = guide[(g + 1) % guide.shape[0]] - guide[(g - 1) % guide.shape[0]]
        normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
        normal /= np.linalg.norm(normal, axis=1, keepdims=True) + 1e-15
        th_new, r_new, t_new = solve_similarity(
            points[order], guide[g], normal, th, r, theta_fixed, rho_fixed, allowed, centred
        )
        moved = abs(th_new - th) / 90.0 + abs(r_new - r) + float(np.linalg.norm(t_new - t))
        th, r, t = th_new, r_new, t_new
        if moved < 1e-6 or not math.isfinite(residual):
            break
    return th, r, t, residual


__all__ = [
    "FIT_POINTS",
    "GUIDE_POINTS",
    "GuideFit",
    "PreferenceRange",
    "icp",
    "solve_similarity",
    "transform",
]
