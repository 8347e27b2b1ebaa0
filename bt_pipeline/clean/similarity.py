"""The closed-form step of the guide fit: θ, ρ, t of p ≈ ρ R(θ) q + t, point-to-tangent.

:func:`~bt_pipeline.clean.guide_fit.fit_guide` pairs each demo point p with its nearest loop
point q and solves this weighted least squares for the similarity (its ICP step), clipped to
the allowed θ/ρ range or with θ and/or ρ held fixed.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from bt_pipeline.data.records import FloatArray

if TYPE_CHECKING:
    from bt_pipeline.clean.guide_fit import PreferenceRange

_POINT_WEIGHT = 0.05  # Weight of the point-to-point term beside the point-to-tangent one.


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


__all__ = ["solve_similarity", "transform"]
