"""Task-intention losses L1-L3 of one demo (paper Sec. III-A, Eqs. 4-6).

All three take a trajectory Γ = {(p_k, q_k)}, shape (N, 2), in task coordinates [m] and return a
non-negative float; lower is better. Only their min-max-normalised values enter the utility
(Eq. 8), so their raw units do not matter there:

* L1 symmetry about the vertical axis through the centroid, in [m];
* L2 closure, the gap between the first and last sample, in [m];
* L3 smoothness, weighted squared norms of raw sample differences, in [m²] (no Δt, as written in
  the paper; docs/algorithms.md §7 row 6).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

# scipy ships no type stub for its compiled _ckdtree module, so pyright cannot see cKDTree.
from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]

from bt_pipeline.exceptions import ConfigError, DemoError

FloatArray = NDArray[np.float64]

DEFAULT_ALPHAS: tuple[float, float, float] = (0.2, 0.3, 0.5)
"""(α1, α2, α3) of Eq. (6): weights of velocity, acceleration and jerk."""


def symmetry_loss(positions: ArrayLike, theta_deg: float | None = None) -> float:
    """L1: mean distance of the mirrored trajectory to the trajectory (Eq. 4).

    Each sample (p_k, q_k) is mirrored about the vertical line p = C_x through the centroid, and
    L1 = (1/N) Σ_k min_j ‖(2 C_x - p_k, q_k) - (p_j, q_j)‖₂. With `theta_deg`, the demo is first
    de-rotated by -θ about its centroid so the demonstrator's preferred rotation is not counted as
    asymmetry (docs/algorithms.md §7 row 4).

    Args:
        positions: Trajectory Γ, shape (N, 2), in [m].
        theta_deg: Demonstrator rotation θ [deg] (counter-clockwise); None for no de-rotation.

    Returns:
        L1 in [m]; 0 for a trajectory whose samples are mirror images of each other.
    """
    gamma = _trajectory(positions, "symmetry loss", min_samples=1, planar=True)
    if theta_deg is not None:
        if not math.isfinite(theta_deg):
            raise ConfigError(f"theta_deg must be finite or None; got {theta_deg!r}")
        gamma = _rotate_about_centroid(gamma, -theta_deg)
    c_x = float(np.mean(gamma[:, 0]))
    mirrored = np.column_stack([2.0 * c_x - gamma[:, 0], gamma[:, 1]])
    dist, _ = cKDTree(gamma).query(mirrored, k=1)
    return float(np.mean(dist))  # Eq. (4)


def closure_loss(positions: ArrayLike) -> float:
    """L2: distance between the first and last sample, ‖x_1 - x_N‖₂ (Eq. 5).

    Args:
        positions: Trajectory Γ, shape (N, d), in [m].

    Returns:
        L2 in [m]; exactly 0 for a closed loop whose last sample repeats the first.
    """
    gamma = _trajectory(positions, "closure loss", min_samples=1, planar=False)
    return float(np.linalg.norm(gamma[0] - gamma[-1]))  # Eq. (5)


def smoothness_loss(positions: ArrayLike, alphas: Sequence[float] = DEFAULT_ALPHAS) -> float:
    """L3: α1‖DΓ‖² + α2‖D²Γ‖² + α3‖D³Γ‖² with raw sample differences (Eq. 6).

    ‖·‖ is the Frobenius norm of the (N - n, d) difference array; no division by Δt.

    Args:
        positions: Trajectory Γ, shape (N, d) with N ≥ 4, in [m].
        alphas: (α1, α2, α3), finite and ≥ 0.

    Returns:
        L3 in [m²].
    """
    a1, a2, a3 = validate_alphas(alphas)
    gamma = _trajectory(positions, "smoothness loss", min_samples=4, planar=False)
    d1 = np.diff(gamma, n=1, axis=0)
    d2 = np.diff(d1, n=1, axis=0)
    d3 = np.diff(d2, n=1, axis=0)
    return float(a1 * np.sum(d1**2) + a2 * np.sum(d2**2) + a3 * np.sum(d3**2))  # Eq. (6)


def validate_alphas(alphas: Sequence[float]) -> tuple[float, float, float]:
    """`alphas` as three finite non-negative floats, or ConfigError."""
    values = tuple(float(a) for a in alphas)
    if len(values) != 3 or not all(math.isfinite(a) and a >= 0.0 for a in values):
        raise ConfigError(
            f"smoothness weights (α1, α2, α3) must be three finite numbers ≥ 0; got {alphas!r}"
        )
    return values[0], values[1], values[2]


def _rotate_about_centroid(gamma: FloatArray, angle_deg: float) -> FloatArray:
    """`gamma` (N, 2) rotated counter-clockwise by `angle_deg` [deg] about its centroid."""
    angle = math.radians(angle_deg)
    c, s = math.cos(angle), math.sin(angle)
    rotation = np.array([[c, -s], [s, c]])
    centroid = np.mean(gamma, axis=0)
    return (gamma - centroid) @ rotation.T + centroid


def _trajectory(positions: ArrayLike, what: str, *, min_samples: int, planar: bool) -> FloatArray:
    """`positions` as a float array of shape (N, d) (d = 2 when `planar`), validated."""
    gamma = np.asarray(positions, dtype=np.float64)
    if gamma.ndim != 2 or gamma.shape[1] == 0 or (planar and gamma.shape[1] != 2):
        expected = "(N, 2)" if planar else "(N, d)"
        raise DemoError(f"{what} needs positions of shape {expected}; got {gamma.shape}")
    if gamma.shape[0] < min_samples:
        raise DemoError(f"{what} needs at least {min_samples} samples; got {gamma.shape[0]}")
    if not np.all(np.isfinite(gamma)):
        raise DemoError(f"{what}: positions contain NaN or infinite values")
    return gamma
