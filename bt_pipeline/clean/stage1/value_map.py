"""The state-visitation value map V_E from DMP rollouts (paper Sec. III-B step 3, Eq. 11).

V_E is a kernel density estimate of the states the canonical DMP visits, normalised by its
maximum over a grid, frozen after Stage 1 (docs/algorithms.md §3, §7 row 12):

* R = 50 rollouts start at x^d(0) + N(0, (0.05 · size)² I) at the phase of x^d(0), each run for
  2 periods; the first half period is dropped as transient and exactly one whole period is kept,
  so every phase of the loop weighs the same (keeping 1.5 periods would double the density on
  half of the loop).
* The density uses an isotropic Gaussian kernel of bandwidth h = factor · σ, with σ the RMS of
  the per-axis standard deviations of the states: the isotropic analogue of
  ``scipy.stats.gaussian_kde`` with a scalar factor (which scales the data covariance). The
  default factor 0.15 sits in the 0.1–0.2 range docs/algorithms.md §3 recommends.
* It is evaluated on a 120 × 120 grid over the states' bounding box, padded on every side by
  max(0.25 · size, 4h). The states are linearly binned onto the grid nodes (each state shares its
  weight among the four nodes around it) and the counts are convolved with the sampled Gaussian
  (scipy.ndimage.gaussian_filter): the KDE at the nodes up to a binning error of order
  (cell / h)², at a small fraction of the cost of evaluating every state at every node.
* V_E(s) = p̂(s) / max_grid p̂, bilinear between nodes, 0 outside the grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.ndimage import gaussian_filter

from bt_pipeline.clean.stage1.dmp import PeriodicDmp
from bt_pipeline.clean.stage1.period import loop_size
from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError


@dataclass(frozen=True)
class ValueMapConfig:
    """Settings of the value map V_E."""

    n_rollouts: int = 50
    """R, DMP rollouts."""
    n_periods: int = 2
    """Periods per rollout."""
    transient_periods: float = 0.5
    """Leading part of each rollout dropped as transient, in periods."""
    init_noise: float = 0.05
    """Std of the initial position perturbation, as a fraction of the reference's size."""
    samples_per_period: int = 300
    """Rollout samples per period."""
    bandwidth_factor: float = 0.15
    """h = bandwidth_factor · σ_states (ignored when bandwidth_m is set)."""
    bandwidth_m: float | None = None
    """Fixed bandwidth h [m], or None for bandwidth_factor."""
    grid_size: int = 120
    """Grid nodes per axis."""
    padding: float = 0.25
    """Padding of the grid beyond the states, as a fraction of their size (at least 4h)."""

    def __post_init__(self) -> None:
        if self.n_rollouts < 1 or self.samples_per_period < 4 or self.grid_size < 4:
            raise ConfigError(
                "n_rollouts must be at least 1, samples_per_period and grid_size at least 4; got "
                f"{self.n_rollouts}, {self.samples_per_period} and {self.grid_size}"
            )
        if not (self.transient_periods >= 0 and self.n_periods - self.transient_periods >= 1):
            raise ConfigError(
                f"a rollout of {self.n_periods} periods must keep at least one whole period after "
                f"its transient of {self.transient_periods} periods"
            )
        if not (self.init_noise >= 0 and self.bandwidth_factor > 0 and self.padding >= 0):
            raise ConfigError(
                "init_noise and padding must be non-negative and bandwidth_factor positive"
            )
        if self.bandwidth_m is not None and not self.bandwidth_m > 0:
            raise ConfigError(f"bandwidth_m must be positive or None; got {self.bandwidth_m}")


@dataclass(frozen=True, eq=False)
class ValueMap:
    """V_E on a regular grid: V(s) ∈ [0, 1], bilinear between nodes, 0 outside the grid."""

    x_centres: FloatArray
    """Node coordinates along the first task axis, increasing and uniform, shape (nx,), in [m]."""
    y_centres: FloatArray
    """Node coordinates along the second task axis, increasing and uniform, shape (ny,), [m]."""
    values: FloatArray
    """V at the nodes, shape (ny, nx), in [0, 1] (read-only)."""
    bandwidth: float
    """Kernel bandwidth h [m]."""

    def __post_init__(self) -> None:
        x = np.array(self.x_centres, dtype=np.float64)
        y = np.array(self.y_centres, dtype=np.float64)
        values = np.array(self.values, dtype=np.float64)
        if x.ndim != 1 or y.ndim != 1 or x.size < 2 or y.size < 2:
            raise ConfigError("x_centres and y_centres must be 1-D with at least 2 nodes each")
        if values.shape != (y.size, x.size):
            raise ConfigError(
                f"values must have shape (ny, nx) = ({y.size}, {x.size}); got {values.shape}"
            )
        for name, c in (("x_centres", x), ("y_centres", y)):
            step = np.diff(c)
            if not (np.all(step > 0) and np.allclose(step, step[0], rtol=1e-6)):
                raise ConfigError(f"{name} must be increasing and uniformly spaced")
        if not (np.all(np.isfinite(values)) and values.min() >= 0 and values.max() <= 1):
            raise ConfigError("values must be finite and in [0, 1]")
        for name, array in (("x_centres", x), ("y_centres", y), ("values", values)):
            array.setflags(write=False)
            object.__setattr__(self, name, array)

    def __call__(self, points: ArrayLike) -> FloatArray:
        """V_E at `points`, shape (..., 2) [m] -> (...)."""
        p = np.asarray(points, dtype=np.float64)
        if p.shape[-1:] != (2,):
            raise ConfigError(f"points must have shape (..., 2); got {p.shape}")
        nx, ny = self.x_centres.size, self.y_centres.size
        fx = (p[..., 0] - self.x_centres[0]) / (self.x_centres[1] - self.x_centres[0])
        fy = (p[..., 1] - self.y_centres[0]) / (self.y_centres[1] - self.y_centres[0])
        inside = (fx >= 0) & (fx <= nx - 1) & (fy >= 0) & (fy <= ny - 1)
        fx, fy = np.where(inside, fx, 0.0), np.where(inside, fy, 0.0)
        i = np.minimum(fx.astype(np.intp), nx - 2)
        j = np.minimum(fy.astype(np.intp), ny - 2)
        wx, wy = fx - i, fy - j
        v = self.values
        bottom = (1 - wx) * v[j, i] + wx * v[j, i + 1]
        top = (1 - wx) * v[j + 1, i] + wx * v[j + 1, i + 1]
        return np.where(inside, (1 - wy) * bottom + wy * top, 0.0)

    def mean_reward(self, positions: ArrayLike) -> float:
        """R̄ = (1/N) Σ_k V_E(x_k) ∈ [0, 1] of one path, shape (N, 2) (Eq. 11 divided by N)."""
        p = np.asarray(positions, dtype=np.float64)
        if p.ndim != 2:
            raise ConfigError(f"positions must have shape (N, 2); got {p.shape}")
        return float(np.mean(self(p)))

    def mean_rewards(self, positions: ArrayLike) -> FloatArray:
        """R̄ per path for paths of shape (M, N, 2) -> (M,) (Eq. 11 divided by N)."""
        p = np.asarray(positions, dtype=np.float64)
        if p.ndim != 3:
            raise ConfigError(f"positions must have shape (M, N, 2); got {p.shape}")
        return np.mean(self(p), axis=1)


def rollout_states(
    dmp: PeriodicDmp,
    reference: ArrayLike,
    config: ValueMapConfig | None = None,
    seed: int | np.random.Generator = 0,
) -> FloatArray:
    """States visited by R perturbed DMP rollouts from x^d(0), transients dropped.

    Args:
        dmp: The DMP fitted to the best demo.
        reference: x^d, shape (N, 2), in [m].
        config: Value-map settings; defaults to ValueMapConfig().
        seed: Seed or generator of the initial perturbations.

    Returns:
        States, shape (R · samples_per_period, 2), in [m]: one whole period per rollout.
    """
    config = config or ValueMapConfig()
    ref = np.asarray(reference, dtype=np.float64)
    rng = np.random.default_rng(seed)
    sigma = config.init_noise * loop_size(ref)
    y0 = ref[0] + rng.normal(0.0, sigma, size=(config.n_rollouts, 2))
    spp = config.samples_per_period
    paths = dmp.rollout(
        y0, n_periods=config.n_periods, samples_per_period=spp, phase0=dmp.phase_of(ref[0])
    )
    start = math.ceil(config.transient_periods * spp)
    return paths[:, start : start + spp].reshape(-1, 2)


def value_map_from_states(states: ArrayLike, config: ValueMapConfig | None = None) -> ValueMap:
    """KDE of `states`, shape (K, 2) [m], on a padded grid, normalised to max 1 (module doc)."""
    config = config or ValueMapConfig()
    s = np.asarray(states, dtype=np.float64)
    if s.ndim != 2 or s.shape[1] != 2 or s.shape[0] < 2 or not np.all(np.isfinite(s)):
        raise ConfigError(f"states must be finite with shape (K >= 2, 2); got {s.shape}")
    by_axis = np.ascontiguousarray(s.T)  # Reductions along rows of (2, K) are much faster.
    low, high = by_axis.min(axis=1), by_axis.max(axis=1)
    sigma = math.sqrt(float(np.mean(by_axis.var(axis=1))))
    h = config.bandwidth_m if config.bandwidth_m is not None else config.bandwidth_factor * sigma
    if not h > 0:
        raise ConfigError("the states do not spread; set bandwidth_m to a positive bandwidth")
    pad = max(config.padding * float(np.max(high - low)), 4.0 * h)
    n = config.grid_size
    lo, hi = low - pad, high + pad
    x_c, y_c = np.linspace(lo[0], hi[0], n), np.linspace(lo[1], hi[1], n)
    cell = (hi - lo) / (n - 1)
    f = (s - lo) / cell
    i = np.minimum(f.astype(np.intp), n - 2)
    w = f - i
    counts = np.zeros(n * n)
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        weight = (w[:, 0] if dx else 1 - w[:, 0]) * (w[:, 1] if dy else 1 - w[:, 1])
        counts += np.bincount((i[:, 1] + dy) * n + i[:, 0] + dx, weights=weight, minlength=n * n)
    density = gaussian_filter(
        counts.reshape(n, n), sigma=(h / cell[1], h / cell[0]), mode="constant", truncate=4.0
    )
    return ValueMap(x_c, y_c, np.clip(density / density.max(), 0.0, 1.0), h)


def build_value_map(
    dmp: PeriodicDmp,
    reference: ArrayLike,
    config: ValueMapConfig | None = None,
    seed: int | np.random.Generator = 0,
) -> ValueMap:
    """V_E from R perturbed rollouts of the DMP around x^d (paper Sec. III-B step 3)."""
    config = config or ValueMapConfig()
    return value_map_from_states(rollout_states(dmp, reference, config, seed), config)
