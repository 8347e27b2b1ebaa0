"""The centre c the demonstrators' rotations and scalings share, moved to where the demos agree.

Paper Sec. III-B steps 4-5: x^g = R(−θ_best)(x^d − c)/ρ_best and x_i^aligned = ρ_i R(θ_i) x^g + c,
one c for every reference (docs/algorithms.md §7 row 13). bt takes c at the centre of the best
loop's bounding box in the best demonstrator's unrotated frame. That is right when the frame is
the drawing's own (θ/ρ stated against the task's guide), but where c lies on the loop is a
convention of whoever drew the demos: with θ/ρ hidden a learned loop's frame is the set's (its
mean θ, not the drawing's θ = 0), and the box of a turned D shape has another centre, 17 mm off
on one random-loop set; another generator turns a D shape about a point 3-7 mm from its box
centre. A c in the wrong place puts every reference but the best demo's off by
(I − A_i)(c − c_true), with A_i = (ρ_i/ρ_b) R(θ_i − θ_b) demo i's similarity relative to the best:
that set's naive demos came out at 1.9-2.1 x their raw error with θ/ρ estimated right.

The demos say where c is. With the references built about the box centre, each demo's offset
from its reference loop, o_i (the translation that lays the loop onto the demo's samples: a
trimmed point-to-tangent fit, so approach, spikes and a missing part do not pull it, and the
loop slides along itself instead of pairing samples by time), is what a better c would remove:
moving c by Δc moves reference i by (I − A_i) Δc. A drifting or lopsided demo's offset is not
its placement, and in a set of four one such demo with a large (I − A_i) would carry a least-
squares fit with it, so Δc is found by consensus: each demo that constrains Δc on its own
proposes the Δc that explains its offset, Δc = 0 proposes keeping the box centre, and the
proposal that explains the most offsets within 2.5 mm wins (ties keep the box centre); Δc is
then fitted to the offsets it explains. A move needs two demos that agree.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import KDTree

from bt_pipeline.data.records import FloatArray

INLIER_M = 0.0025
"""An offset is explained by a Δc when it lies within this of (I − A_i) Δc [m]."""
_CONDITION = 0.1  # A demo proposes a Δc on its own when (I − A_i)'s smaller singular value ≥ this.
_KEEP = 0.8  # Share of a demo's samples the placement fit keeps (the nearest to the loop).
_STEPS = 30  # Most steps of the placement fit.


def similarity_matrix(theta_deg: float, rho: float) -> FloatArray:
    """ρ R(θ), shape (2, 2)."""
    t = math.radians(theta_deg)
    return rho * np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])


def placement_offset(points: ArrayLike, loop: ArrayLike) -> FloatArray:
    """The translation that lays a closed `loop` (P, 2) onto a demo's `points` (N, 2) [m]: a
    trimmed point-to-tangent fit (the 80 % of points nearest the loop), at most 30 steps."""
    x = np.asarray(points, dtype=np.float64)
    g = np.asarray(loop, dtype=np.float64)
    tangent = np.roll(g, -1, axis=0) - np.roll(g, 1, axis=0)
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True) + 1e-15
    tree = KDTree(g)
    keep = max(3, int(_KEEP * x.shape[0]))
    t = np.zeros(2)
    for _ in range(_STEPS):
        dist, index = tree.query(x - t)
        order = np.argpartition(np.asarray(dist), keep - 1)[:keep]
        nearest = np.asarray(index)[order]
        n = normal[nearest]
        gap = x[order] - t - g[nearest]
        step = np.linalg.solve(
            np.einsum("ij,ik->jk", n, n) + 1e-12 * np.eye(2), np.einsum("ij,ik,ik->j", n, n, gap)
        )
        t = t + step
        if float(np.linalg.norm(step)) < 1e-6:
            break
    return t


def pivot_shift(
    thetas_deg: ArrayLike, rhos: ArrayLike, offsets: ArrayLike, best_index: int
) -> FloatArray:
    """Δc: how far the shared centre c moves so the references sit on their demos (module doc).

    Args:
        thetas_deg: Each demo's θ [deg], shape (M,).
        rhos: Each demo's ρ, shape (M,).
        offsets: Each demo's offset from its reference loop built about the current c, shape
            (M, 2) [m].
        best_index: The best demo's index.

    Returns:
        Δc, shape (2,), in [m]: zeros unless two demos agree on a move.
    """
    th, r = np.asarray(thetas_deg, dtype=np.float64), np.asarray(rhos, dtype=np.float64)
    o = np.asarray(offsets, dtype=np.float64)
    inverse_best = np.linalg.inv(similarity_matrix(th[best_index], r[best_index]))
    keep = [
        i
        for i in range(th.size)
        if i != best_index and math.isfinite(th[i]) and r[i] > 0 and np.all(np.isfinite(o[i]))
    ]
    if len(keep) < 2:
        return np.zeros(2)
    m = np.stack([np.eye(2) - similarity_matrix(th[i], r[i]) @ inverse_best for i in keep])
    y = o[keep]
    proposals = [np.zeros(2)] + [
        np.linalg.solve(m[k], y[k])
        for k in range(len(keep))
        if np.linalg.svd(m[k], compute_uv=False)[-1] >= _CONDITION
    ]

    def explained(shift: FloatArray) -> np.ndarray:
        residual = np.linalg.norm(np.einsum("ijk,k->ij", m, shift) - y, axis=1)
        return residual <= INLIER_M

    best, inliers = proposals[0], explained(proposals[0])
    for shift in proposals[1:]:  # The first that explains the most offsets; ties keep c.
        found = explained(shift)
        if found.sum() > inliers.sum():
            best, inliers = shift, found
    if not best.any() or inliers.sum() < 2:
        return np.zeros(2)
    lhs = np.einsum("ijk,ijl->kl", m[inliers], m[inliers])
    return np.linalg.solve(lhs, np.einsum("ijk,ij->k", m[inliers], y[inliers]))


__all__ = ["INLIER_M", "pivot_shift", "placement_offset", "similarity_matrix"]
