"""Phase-free distances between curves: the quality measure against a known true shape.

Both measures compare point sets, not samples matched in time: they ignore the start phase,
direction and speed profile of a demo, and see only where it went. That is what "distance of a
demo to its ground-truth shape" should mean for the synthetic demonstrators, whose start phase
and timing are random.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import KDTree  # cKDTree underneath (scipy >= 1.6), typed

from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError


def _as_points(points: ArrayLike, what: str) -> FloatArray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[0] < 1 or p.shape[1] < 1:
        raise ConfigError(f"{what} must have shape (n, d) with n >= 1; got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ConfigError(f"{what} has NaN or infinite values")
    return p


def chamfer_distance(a: ArrayLike, b: ArrayLike) -> float:
    """Symmetric mean Chamfer distance between two curves given as point sets.

    ``(mean_{p∈a} min_{q∈b} ‖p - q‖ + mean_{q∈b} min_{p∈a} ‖p - q‖) / 2``. Zero for identical sets,
    symmetric in its arguments, independent of the order of the points (so phase-free).

    Args:
        a: Points of the first curve, shape (n, d), usually d = 2, in [m].
        b: Points of the second curve, shape (m, d), same d, in [m].

    Returns:
        The distance [m].

    Raises:
        ConfigError: An input is not a non-empty finite (n, d) array, or the d differ.
    """
    return PointSet.of(a, "a").chamfer(PointSet.of(b, "b"))


@dataclass(frozen=True, eq=False)
class PointSet:
    """A curve as a point set with its k-d tree, built once: for many distances to one curve
    (:func:`chamfer_distance` builds both trees on every call)."""

    points: FloatArray
    """Points, shape (n, d) [m]."""
    tree: KDTree
    """k-d tree of `points`."""

    @classmethod
    def of(cls, points: ArrayLike, what: str = "points") -> PointSet:
        """Validate `points` (n, d) and build the tree.

        Raises:
            ConfigError: Not a non-empty finite (n, d) array (the message names `what`).
        """
        p = _as_points(points, what)
        return cls(p, KDTree(p))

    def chamfer(self, other: PointSet) -> float:
        """:func:`chamfer_distance` from this set (a) to `other` (b) [m]; the same value.

        Raises:
            ConfigError: The dimensions differ.
        """
        pa, pb = self.points, other.points
        if pa.shape[1] != pb.shape[1]:
            raise ConfigError(
                f"a and b must have the same dimension; got {pa.shape} and {pb.shape}"
            )
        d_ab, _ = other.tree.query(pa)
        d_ba, _ = self.tree.query(pb)
        return 0.5 * (float(np.mean(d_ab)) + float(np.mean(d_ba)))

    def gaps(self, points: FloatArray) -> FloatArray:
        """Distance of each of `points` (m, d) to its nearest point of this set [m], shape (m,)."""
        d, _ = self.tree.query(points)
        return np.asarray(d, dtype=np.float64)


def distance_to_truth(positions: ArrayLike, truth: ArrayLike) -> float:
    """Distance of a demo to its ground-truth shape: :func:`chamfer_distance` to the dense truth.

    Phase-free: the demo's start phase, direction and speed do not matter, only the set of places
    it visits. Missing parts of the loop (an incomplete demo) count through the truth-to-demo
    half, excursions (drift, spikes, a lopsided side) through the demo-to-truth half. Pass a
    dense truth (e.g. 600 points over one period) so its own sampling adds little.

    Args:
        positions: The demo's task-plane positions, shape (N, 2), in [m].
        truth: The noise-free shape, dense, shape (M, 2), in [m].

    Returns:
        The distance [m].

    Raises:
        ConfigError: An input is not a non-empty finite (n, 2)-like array.
    """
    return chamfer_distance(positions, truth)


__all__ = ["PointSet", "chamfer_distance", "distance_to_truth"]
