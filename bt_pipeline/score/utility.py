"""Demo utility score: rank the raw demos of one task and pick the best (paper Sec. III-A).

Data flow, per task::

    demos ──► raw_metrics (per demo) ──► Normaliser (min, max per metric over the M raw demos)
          ──► Ĩ, L̃1..L̃3 (Eq. 7) ──► Ũ = (1 - β) Ĩ + β Σ_j w_j (1 - L̃_j) (Eq. 8) ──► ranks, best

Raw metrics are I(S; A) by KSG-1 (Eq. 1, :mod:`bt_pipeline.score.mi`) and the losses L1-L3 (Eqs.
4-6, :mod:`bt_pipeline.score.losses`). Min-max normalisation runs across the M raw demos of the
task, separately per metric (docs/algorithms.md §7 row 7); the refinement stage reuses the frozen
:class:`Normaliser` so its map stays fixed and affine. Eq. (3), U = (1 - β) I - β L, only explains
the intent: the normalised form Eq. (8) is used everywhere (§7 row 10).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bt_pipeline.data.demo import Demo
from bt_pipeline.data.tasks import Task
from bt_pipeline.exceptions import ConfigError, DemoError
from bt_pipeline.score.losses import (
    DEFAULT_ALPHAS,
    closure_loss,
    smoothness_loss,
    symmetry_loss,
    validate_alphas,
)
from bt_pipeline.score.mi import mutual_information

FloatArray = NDArray[np.float64]

METRIC_NAMES: tuple[str, ...] = ("mutual_information", "symmetry", "closure", "smoothness")
"""Raw metrics in the column order of :meth:`RawMetrics.as_array` and the default normaliser."""


@dataclass(frozen=True)
class ScoreConfig:
    """Settings of the demo utility score (defaults: docs/algorithms.md §7 rows 2, 8, 9)."""

    k: int = 3
    """Neighbours of the KSG estimator."""
    weights: tuple[float, float, float] = (1 / 3, 1 / 3, 1 / 3)
    """(w1, w2, w3) of L1 symmetry, L2 closure and L3 smoothness; each in [0, 1], sum 1."""
    beta: float = 0.5
    """Demonstrator ability β ∈ [0, 1], the same for every demo at selection time."""
    delta: float = 1e-12
    """δ of Eq. (7): a metric whose range over the demos is ≤ δ normalises to 0."""
    alphas: tuple[float, float, float] = DEFAULT_ALPHAS
    """(α1, α2, α3) of the smoothness loss, Eq. (6)."""
    derotate: bool = True
    """Evaluate L1 on each demo de-rotated by -θ (when its θ is known)."""

    def __post_init__(self) -> None:
        if isinstance(self.k, bool) or not isinstance(self.k, int) or self.k < 1:
            raise ConfigError(f"k must be an integer ≥ 1; got {self.k!r}")
        weights = validate_weights(self.weights)
        if len(weights) != 3:
            raise ConfigError(
                f"weights must hold 3 values (symmetry, closure, smoothness); got {self.weights!r}"
            )
        if not (math.isfinite(self.beta) and 0.0 <= self.beta <= 1.0):
            raise ConfigError(f"beta must lie in [0, 1]; got {self.beta!r}")
        if not (math.isfinite(self.delta) and self.delta >= 0.0):
            raise ConfigError(f"delta must be finite and ≥ 0; got {self.delta!r}")
        object.__setattr__(self, "weights", (weights[0], weights[1], weights[2]))
        object.__setattr__(self, "alphas", validate_alphas(self.alphas))
        object.__setattr__(self, "beta", float(self.beta))
        object.__setattr__(self, "delta", float(self.delta))


def validate_weights(weights: Sequence[float]) -> tuple[float, ...]:
    """`weights` as floats, each in [0, 1] and summing to 1 (paper Sec. III-A), or ConfigError."""
    values = tuple(float(w) for w in weights)
    if not values or not all(math.isfinite(w) and 0.0 <= w <= 1.0 for w in values):
        raise ConfigError(f"weights must each lie in [0, 1]; got {weights!r}")
    if abs(sum(values) - 1.0) > 1e-9:
        raise ConfigError(f"weights must sum to 1; got {weights!r} (sum {sum(values):.6g})")
    return values


def minmax_normalise(values: ArrayLike, delta: float = 1e-12) -> FloatArray:
    """Min-max normalisation with a δ guard (Eq. 7).

    Args:
        values: One metric of M demos, shape (M,).
        delta: Ranges max - min ≤ δ give all zeros.

    Returns:
        (v - min) / (max - min) in [0, 1], shape (M,); zeros when the range is ≤ δ.
    """
    v = _metric_values(values, "values")
    if v.ndim != 1:
        raise ConfigError(f"minmax_normalise takes one metric of shape (M,); got {v.shape}")
    return _normalise(v, np.min(v), np.max(v), delta)  # Eq. (7)


def normalised_utility(
    mi_norm: ArrayLike, loss_norms: ArrayLike, weights: Sequence[float], beta: ArrayLike
) -> FloatArray:
    """Normalised demo utility Ũ = (1 - β) Ĩ + β Σ_j w_j (1 - L̃_j) (Eq. 8).

    Args:
        mi_norm: Normalised mutual information Ĩ, shape (M,).
        loss_norms: Normalised losses L̃_j, shape (M, J).
        weights: w_j, J values in [0, 1] summing to 1.
        beta: β, a scalar or one value per demo, shape (M,), in [0, 1].

    Returns:
        Ũ, shape (M,); in [0, 1] when the normalised inputs are.
    """
    i_norm = _metric_values(mi_norm, "mi_norm")
    l_norm = _metric_values(loss_norms, "loss_norms")
    w = np.asarray(validate_weights(weights))
    b = np.asarray(beta, dtype=np.float64)
    m = i_norm.shape[0]
    if i_norm.ndim != 1 or l_norm.shape != (m, w.shape[0]):
        raise ConfigError(
            f"mi_norm must have shape (M,) and loss_norms (M, J) with J = {w.shape[0]} weights; "
            f"got {i_norm.shape} and {l_norm.shape}"
        )
    if b.shape not in ((), (m,)):
        raise ConfigError(f"beta must be a scalar or have shape ({m},); got {b.shape}")
    if not np.all(np.isfinite(b) & (b >= 0.0) & (b <= 1.0)):
        raise ConfigError(f"beta must lie in [0, 1]; got {b.tolist()}")
    return (1.0 - b) * i_norm + b * ((1.0 - l_norm) @ w)  # Eq. (8)


@dataclass(frozen=True, slots=True)  # one per take in the app's library: no __dict__
class RawMetrics:
    """Unnormalised metrics of one demo."""

    mutual_information: float
    """I(S; A) by KSG-1 [nats] (Eq. 1); higher is better."""
    symmetry: float
    """L1 [m] (Eq. 4); lower is better."""
    closure: float
    """L2 [m] (Eq. 5); lower is better."""
    smoothness: float
    """L3 [m²] (Eq. 6); lower is better."""

    def as_array(self) -> FloatArray:
        """The metrics in :data:`METRIC_NAMES` order, shape (4,)."""
        return np.array([self.mutual_information, self.symmetry, self.closure, self.smoothness])


def raw_metrics(
    positions: ArrayLike,
    actions: ArrayLike,
    theta_deg: float | None,
    config: ScoreConfig | None = None,
) -> RawMetrics:
    """I(S; A) and L1-L3 of one demo.

    Args:
        positions: States S = x(t_k), shape (N, 2), in [m].
        actions: Actions A = a(t_k), shape (N, 2), in [m/s] of normalised time.
        theta_deg: Demonstrator rotation θ [deg] for the L1 de-rotation; None for none.
        config: Score settings (k, α, whether to de-rotate); defaults when None.
    """
    config = ScoreConfig() if config is None else config
    theta = theta_deg if config.derotate else None
    return RawMetrics(
        mutual_information=mutual_information(positions, actions, k=config.k),
        symmetry=symmetry_loss(positions, theta),
        closure=closure_loss(positions),
        smoothness=smoothness_loss(positions, config.alphas),
    )


@dataclass(frozen=True)
class Normaliser:
    """Frozen per-metric min-max maps (Eq. 7), fitted on a set of raw demos.

    The refinement stage keeps the (min, max) of the raw set, so the map is fixed and affine:
    ``normalised = (value - min) * scale`` with ``scale = 1 / (max - min)``, or 0 where
    max - min ≤ δ (docs/algorithms.md §7 row 7).
    """

    names: tuple[str, ...]
    """Metric names, one per column."""
    min: FloatArray
    """Minimum of each metric over the fitting set, shape (K,)."""
    max: FloatArray
    """Maximum of each metric over the fitting set, shape (K,)."""
    delta: float = 1e-12
    """δ of Eq. (7)."""

    def __post_init__(self) -> None:
        lo = np.array(self.min, dtype=np.float64)
        hi = np.array(self.max, dtype=np.float64)
        names = tuple(self.names)
        if lo.shape != (len(names),) or hi.shape != (len(names),):
            raise ConfigError(
                f"normaliser needs min and max of shape ({len(names)},) for metrics {names}; got "
                f"{lo.shape} and {hi.shape}"
            )
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi >= lo)):
            raise ConfigError(f"normaliser needs finite min ≤ max; got {lo} and {hi}")
        if not (math.isfinite(self.delta) and self.delta >= 0.0):
            raise ConfigError(f"delta must be finite and ≥ 0; got {self.delta!r}")
        lo.setflags(write=False)
        hi.setflags(write=False)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "min", lo)
        object.__setattr__(self, "max", hi)

    @classmethod
    def from_values(
        cls, values: ArrayLike, names: Sequence[str] = METRIC_NAMES, delta: float = 1e-12
    ) -> Normaliser:
        """Fit on raw metric values, shape (M, K), one row per demo, columns named `names`."""
        v = _metric_values(values, "values")
        if v.ndim != 2 or v.shape[0] == 0 or v.shape[1] != len(names):
            raise ConfigError(
                f"values must have shape (M, {len(names)}) with M ≥ 1 for metrics "
                f"{tuple(names)}; got {v.shape}"
            )
        return cls(names=tuple(names), min=np.min(v, axis=0), max=np.max(v, axis=0), delta=delta)

    @classmethod
    def from_raw_metrics(cls, metrics: Sequence[RawMetrics], delta: float = 1e-12) -> Normaliser:
        """Fit on the raw metrics of M ≥ 1 demos (columns :data:`METRIC_NAMES`)."""
        if not metrics:
            raise DemoError("a normaliser needs the metrics of at least one demo")
        return cls.from_values(np.stack([m.as_array() for m in metrics]), METRIC_NAMES, delta)

    @property
    def scale(self) -> FloatArray:
        """1 / (max - min) per metric, 0 where max - min ≤ δ, shape (K,)."""
        span = self.max - self.min
        ok = span > self.delta
        return np.where(ok, 1.0 / np.where(ok, span, 1.0), 0.0)

    def index(self, name: str) -> int:
        """Column of metric `name`."""
        if name not in self.names:
            raise ConfigError(f"unknown metric {name!r}; this normaliser has {self.names}")
        return self.names.index(name)

    def affine(self, name: str) -> tuple[float, float]:
        """(offset, scale) of metric `name`: normalised = (value - offset) * scale.

        Plain floats, so the map also applies to torch tensors.
        """
        j = self.index(name)
        return float(self.min[j]), float(self.scale[j])

    def normalise(self, values: ArrayLike, clip: bool = False) -> FloatArray:
        """Normalise raw values of all metrics, shape (..., K), by the frozen (min, max).

        Args:
            values: Raw metrics, last axis in :attr:`names` order.
            clip: Clip to [0, 1] (new values may fall outside the fitting range).

        Returns:
            Normalised values, same shape; 0 in columns whose range is ≤ δ.
        """
        v = _metric_values(values, "values")
        if v.ndim == 0 or v.shape[-1] != len(self.names):
            raise ConfigError(
                f"values must have shape (..., {len(self.names)}) for metrics {self.names}; "
                f"got {v.shape}"
            )
        out = _normalise(v, self.min, self.max, self.delta)
        return np.clip(out, 0.0, 1.0) if clip else out

    def normalise_metric(self, name: str, values: ArrayLike, clip: bool = False) -> FloatArray:
        """Normalise raw values of the one metric `name`, any shape."""
        j = self.index(name)
        out = _normalise(_metric_values(values, "values"), self.min[j], self.max[j], self.delta)
        return np.clip(out, 0.0, 1.0) if clip else out


@dataclass(frozen=True)
class DemoScore:
    """Raw metrics, utility and rank of one demo."""

    demo: Demo
    """The demo scored."""
    mutual_information: float
    """I(S; A) [nats]."""
    symmetry: float
    """L1 [m]."""
    closure: float
    """L2 [m]."""
    smoothness: float
    """L3 [m²]."""
    utility: float
    """Normalised demo utility Ũ ∈ [0, 1] (Eq. 8)."""
    rank: int
    """1 for the best demo of the task; ties go to the earlier demo."""

    @property
    def raw(self) -> RawMetrics:
        """The raw metrics as a record."""
        return RawMetrics(self.mutual_information, self.symmetry, self.closure, self.smoothness)


@dataclass(frozen=True)
class TaskScores:
    """Scores of every demo of one task."""

    task: Task
    """The task."""
    scores: tuple[DemoScore, ...]
    """One score per demo, in input order."""
    best_index: int
    """Index into :attr:`scores` of the best demo (highest Ũ, earliest on ties)."""
    normaliser: Normaliser
    """The per-metric (min, max) over these raw demos, frozen for the refinement stage."""

    @property
    def best(self) -> DemoScore:
        """The score of the best demo."""
        return self.scores[self.best_index]

    def normalised_metrics(self) -> FloatArray:
        """Ĩ, L̃1, L̃2, L̃3 of every demo, shape (M, 4)."""
        return self.normaliser.normalise(np.stack([s.raw.as_array() for s in self.scores]))


def score_demos(
    demos: Sequence[Demo],
    config: ScoreConfig | None = None,
    *,
    metrics: Sequence[RawMetrics] | None = None,
) -> TaskScores:
    """Score the raw demos of one task with the normalised demo utility (Eqs. 7-8).

    Actions are the demos' forward differences (t ∈ [0, 1], a_N = 0); L1 is de-rotated by each
    demo's θ when known and `config.derotate` is set. A single demo gets Ũ = β (every metric's
    range is 0 ≤ δ) and is the best.

    Args:
        demos: M ≥ 1 demos, all of the same task.
        config: Score settings; defaults when None.
        metrics: Each demo's raw metrics to rank by, in place of :func:`raw_metrics` on its N
            samples (the cleaner reads L1-L3 per loop, along the path and at ρ = 1:
            :func:`bt_pipeline.clean.periodic.ranking_metrics`).

    Raises:
        DemoError: No demos.
        ConfigError: Demos of more than one task.
    """
    config = ScoreConfig() if config is None else config
    demos = list(demos)
    if not demos:
        raise DemoError("no demos to score; at least one is needed")
    tasks: list[Task] = []
    for demo in demos:
        if demo.task not in tasks:
            tasks.append(demo.task)
    if len(tasks) > 1:
        raise ConfigError(
            f"score_demos scores one task at a time; got demos of tasks {', '.join(tasks)} "
            "(split them with bt_pipeline.data.demo.group_by_task)"
        )
    if metrics is None:
        metrics = [raw_metrics(d.positions, d.actions, d.theta_deg, config) for d in demos]
    elif len(metrics) != len(demos):
        raise ConfigError(f"{len(metrics)} sets of metrics for {len(demos)} demos")
    utility, normaliser = set_utilities(metrics, config)
    order = np.argsort(-utility, kind="stable")  # stable: ties go to the lower index
    ranks = np.empty(len(demos), dtype=np.int64)
    ranks[order] = np.arange(1, len(demos) + 1)
    scores = tuple(
        DemoScore(
            demo=demo,
            mutual_information=m.mutual_information,
            symmetry=m.symmetry,
            closure=m.closure,
            smoothness=m.smoothness,
            utility=float(u),
            rank=int(r),
        )
        for demo, m, u, r in zip(demos, metrics, utility, ranks, strict=True)
    )
    return TaskScores(task=tasks[0], scores=scores, best_index=int(order[0]), normaliser=normaliser)


def set_utilities(
    metrics: Sequence[RawMetrics], config: ScoreConfig
) -> tuple[FloatArray, Normaliser]:
    """Ũ of each demo of a set from its raw metrics (Eqs. 7-8, normalised over the set), and
    the normaliser."""
    normaliser = Normaliser.from_raw_metrics(metrics, config.delta)
    normalised = normaliser.normalise(np.stack([m.as_array() for m in metrics]))
    utility = normalised_utility(normalised[:, 0], normalised[:, 1:], config.weights, config.beta)
    return utility, normaliser


def select_best(demos: Sequence[Demo], config: ScoreConfig | None = None) -> int:
    """Index of the demo with the highest normalised utility (x_best of paper Step 1)."""
    return score_demos(demos, config).best_index


def _normalise(values: FloatArray, lo: ArrayLike, hi: ArrayLike, delta: float) -> FloatArray:
    """(values - lo) / (hi - lo) where hi - lo > δ, else 0 (Eq. 7); broadcasts on the last axis."""
    lo = np.asarray(lo, dtype=np.float64)
    span = np.asarray(hi, dtype=np.float64) - lo
    ok = span > delta
    return np.where(ok, (values - lo) / np.where(ok, span, 1.0), 0.0)


def _metric_values(values: ArrayLike, name: str) -> FloatArray:
    """`values` as a float array; DemoError when any is NaN or infinite."""
    v = np.asarray(values, dtype=np.float64)
    if not np.all(np.isfinite(v)):
        raise DemoError(f"{name} contain NaN or infinite metric values")
    return v
