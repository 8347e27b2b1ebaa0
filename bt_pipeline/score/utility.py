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
from bt_pipeline.score.normalise import (
    Normaliser,
    RawMetrics,
    metric_values,
)

FloatArray = NDArray[np.float64]


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
    i_norm = metric_values(mi_norm, "mi_norm")
    l_norm = metric_values(loss_norms, "loss_norms")
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
    the normaliser.

    This is the one Ũ every view shows: ``bt score``, ``bt clean`` (raw, and cleaned through
    :func:`utilities_against` with this normaliser), the app's table, the Rerun summaries and
    ``bt view`` all read a demo's Ũ from here, over the task's current set of demos, so a demo
    reads the same Ũ everywhere for the same set (docs/teleop.md, "Ũ is relative to the set").
    """
    normaliser = Normaliser.from_raw_metrics(metrics, config.delta)
    return utilities_against(normaliser, metrics, config), normaliser


def utilities_against(
    normaliser: Normaliser, metrics: Sequence[RawMetrics], config: ScoreConfig
) -> FloatArray:
    """Ũ (Eq. 8) of demos measured against a set's frozen normaliser (Eq. 7), shape (M,).

    The set's own demos (:func:`set_utilities`) lie inside its ranges; a demo cleaned from them
    may not, and each of its metrics is clipped to the set's range (a metric better than every
    raw demo's counts as the best raw demo's), so Ũ stays in [0, 1] and raw and cleaned demos
    are read on one scale.
    """
    normalised = normaliser.normalise(np.stack([m.as_array() for m in metrics]), clip=True)
    return normalised_utility(normalised[:, 0], normalised[:, 1:], config.weights, config.beta)


def utility_terms(
    normaliser: Normaliser, metrics: Sequence[RawMetrics], config: ScoreConfig
) -> FloatArray:
    """The four terms of Ũ (Eq. 8) that :func:`utilities_against` sums, shape (M, 4):
    (1 - β) Ĩ, then β w_j (1 - L̃_j) for L1-L3; what a change of Ũ is made of."""
    normalised = normaliser.normalise(np.stack([m.as_array() for m in metrics]), clip=True)
    beta = config.beta
    losses = beta * (1.0 - normalised[:, 1:]) * np.asarray(config.weights)
    return np.concatenate([(1.0 - beta) * normalised[:, :1], losses], axis=1)


def select_best(demos: Sequence[Demo], config: ScoreConfig | None = None) -> int:
    """Index of the demo with the highest normalised utility (x_best of paper Step 1)."""
    return score_demos(demos, config).best_index
