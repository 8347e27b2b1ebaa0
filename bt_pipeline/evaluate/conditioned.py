"""The preference-conditioned protocol: each demonstrator's own loop, drawn by one policy.

The paper trains one unconditioned policy on four demonstrators with different θ/ρ and reads its
rollouts against the best demonstrator's value map; such a policy draws their mean loop, so the
yardstick, not the data, decides (docs/evaluation.md). Here every learner takes each demo's
demonstrator preference (θ, ρ) as an input (:func:`~bt_pipeline.evaluate.learners.train_learner`
with ``preferences=``) and is rolled out once per demonstrator, with that demonstrator's
preference, from starts on that demonstrator's true loop, and scored against that loop::

    dataset (M, N, 2) + each demo's (θ, ρ) ──train (conditioned)──▶ policy
    per demonstrator d: starts on its true loop + N(0, (2 % of its size)²)   (or 1-3 cm off)
        ──rollout with (θ_d, ρ_d), two periods──▶ the second period is scored against d's loop:
        shape distance (Chamfer, mm), coverage within τ, progress (loops per period),
        success(τ) = coverage(τ) ≥ 0.9 and it returns within τ of its start and progress ≥ 0.95

The rollouts of one trained model describe that model; comparisons between datasets are made
over seeds (:mod:`bt_pipeline.evaluate.stats`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import KDTree

from bt_pipeline.data.records import FloatArray
from bt_pipeline.evaluate.distance import chamfer_distance
from bt_pipeline.evaluate.learners import LearnerName, learner_config, train_learner
from bt_pipeline.exceptions import ConfigError

TAUS_MM: tuple[float, ...] = (2.0, 3.0, 5.0, 7.5, 10.0, 15.0, 20.0)
"""Thresholds τ [mm] of the success curve."""
COVER = 0.9
"""A successful rollout passes within τ of this share of its demonstrator's true loop,"""
PROGRESS = 0.95
"""and goes around it at least this many times per period."""
_RETURN = 0.2  # It returns within τ of its start in the last 20 % of the period.


@dataclass(frozen=True)
class DemonstratorLoop:
    """One demonstrator: its preference and its true loop (from the generator's truth)."""

    name: str
    theta_deg: float
    """θ [deg]."""
    rho: float
    """ρ."""
    loop: FloatArray
    """The loop it meant, shape (K, 2), in task coordinates [m], in its direction of travel."""

    @property
    def size_m(self) -> float:
        """The larger side of the loop's bounding box [m]."""
        return float(np.ptp(self.loop, axis=0).max())


@dataclass(frozen=True, eq=False)
class RolloutScores:
    """Per-rollout scores of one policy, rolled out for every demonstrator."""

    who: np.ndarray
    """Index of the demonstrator each rollout draws, shape (R,)."""
    shape_mm: FloatArray
    """Chamfer distance of the scored period to the demonstrator's true loop [mm], (R,)."""
    coverage: FloatArray
    """Share of the true loop within τ of the scored period, shape (R, len(TAUS_MM))."""
    returns: np.ndarray
    """Whether the period returns within τ of its start, shape (R, len(TAUS_MM)) (bool)."""
    progress: FloatArray
    """Loops travelled along the true loop in the period (either direction), shape (R,)."""

    @property
    def success(self) -> np.ndarray:
        """success(τ) of each rollout, shape (R, len(TAUS_MM)) (bool; module doc)."""
        return (self.coverage >= COVER) & self.returns & (self.progress[:, None] >= PROGRESS)

    def success_rate(self, tau_mm: float) -> float:
        """Share of rollouts that succeed at τ (one of :data:`TAUS_MM`)."""
        return float(np.mean(self.success[:, _tau_index(tau_mm)]))

    def by_demonstrator(self, values: ArrayLike) -> FloatArray:
        """The mean of per-rollout `values` (R,) over each demonstrator's rollouts, (D,)."""
        v = np.asarray(values, dtype=np.float64)
        return np.array([v[self.who == d].mean() for d in range(int(self.who.max()) + 1)])


def starts_on_loops(
    loops: Sequence[DemonstratorLoop],
    per_demonstrator: int,
    seed: int,
    noise: float = 0.02,
    off_m: tuple[float, float] | None = None,
) -> tuple[FloatArray, np.ndarray]:
    """Rollout starts, shape (R, 2) [m], and the demonstrator of each (R,), R = D x per.

    On each demonstrator's true loop at random points plus N(0, (noise x its size)²) per axis;
    with `off_m` = (lo, hi), instead lo-hi [m] off the loop along its normal, either side (the
    robustness row).
    """
    if per_demonstrator < 1:
        raise ConfigError(f"rollouts per demonstrator must be ≥ 1; got {per_demonstrator}")
    rng = np.random.default_rng(seed)
    starts, who = [], []
    for d, demonstrator in enumerate(loops):
        loop = demonstrator.loop
        k = rng.integers(0, loop.shape[0], size=per_demonstrator)
        if off_m is None:
            offset = rng.normal(0.0, noise * demonstrator.size_m, (per_demonstrator, 2))
        else:
            tangent = loop[(k + 1) % loop.shape[0]] - loop[k - 1]
            normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
            normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
            side = rng.choice([-1.0, 1.0], size=(per_demonstrator, 1))
            offset = normal * side * rng.uniform(*off_m, size=(per_demonstrator, 1))
        starts.append(loop[k] + offset)
        who.append(np.full(per_demonstrator, d))
    return np.concatenate(starts), np.concatenate(who)


def score_rollouts(
    periods: ArrayLike, who: ArrayLike, loops: Sequence[DemonstratorLoop]
) -> RolloutScores:
    """Scores of each rollout's scored period (R, n, 2) [m] against its demonstrator's loop."""
    x = np.asarray(periods, dtype=np.float64)
    w = np.asarray(who, dtype=np.int64)
    if x.ndim != 3 or x.shape[2] != 2 or w.shape != (x.shape[0],):
        raise ConfigError(f"periods must be (R, n, 2) with one demonstrator each; got {x.shape}")
    taus = np.array(TAUS_MM) / 1000.0
    shape, coverage, returns, progress = [], [], [], []
    trees = [KDTree(d.loop) for d in loops]
    for path, d in zip(x, w, strict=True):
        loop = loops[int(d)].loop
        shape.append(1000.0 * chamfer_distance(path, loop))
        gaps, _ = KDTree(path).query(loop)
        coverage.append(np.mean(gaps[:, None] <= taus[None, :], axis=0))
        tail = path[int((1.0 - _RETURN) * len(path)) :]
        back = float(np.min(np.linalg.norm(tail - path[0], axis=1)))
        returns.append(back <= taus)
        progress.append(_progress(path, loop, trees[int(d)]))
    return RolloutScores(
        who=w,
        shape_mm=np.array(shape),
        coverage=np.array(coverage),
        returns=np.array(returns),
        progress=np.array(progress),
    )


@dataclass(frozen=True, eq=False)
class ConditionedEval:
    """One learner trained (conditioned) on one dataset, rolled out for every demonstrator."""

    learner: LearnerName
    dataset: str
    scores: RolloutScores
    """From starts on the true loops."""
    robust: RolloutScores
    """From starts 1-3 cm off the true loops."""
    train_seconds: float


def evaluate_conditioned(
    learner: LearnerName,
    dataset: str,
    positions: ArrayLike,
    preferences: ArrayLike,
    loops: Sequence[DemonstratorLoop],
    *,
    seed: int,
    per_demonstrator: int = 12,
    quick: bool = False,
    steps: int | None = None,
    demonstrators: Sequence[str] | None = None,
    conditioned: bool = True,
) -> ConditionedEval:
    """Train `learner` on `positions` (M, N, 2) [m] with each demo's (θ [deg], ρ) (M, 2) and
    score it for every demonstrator of `loops` (module doc).

    `conditioned=False` trains the paper's unconditioned learner on the same data and rolls it
    out from the same starts (it cannot be told whose loop to draw). `demonstrators` (M names)
    group ILEED's expertise.
    """
    x = np.asarray(positions, dtype=np.float64)
    prefs = np.asarray(preferences, dtype=np.float64)
    overrides: dict[str, object] = {"seed": seed}
    if steps is not None:
        overrides["steps"] = steps
    trained = train_learner(
        learner,
        x,
        demonstrators,
        learner_config(learner, quick=quick, **overrides),
        prefs if conditioned else None,
    )
    n = x.shape[1]
    wanted = np.array([[d.theta_deg, d.rho] for d in loops])
    results = []
    for off in (None, (0.01, 0.03)):
        x0, who = starts_on_loops(loops, per_demonstrator, seed + 1, off_m=off)
        states = trained.policy.rollout(
            x0, 2 * n - 1, preferences=wanted[who] if conditioned else None
        )
        results.append(score_rollouts(states[:, n - 1 :], who, loops))
    return ConditionedEval(learner, dataset, results[0], results[1], trained.seconds)


def loops_by_demonstrator(
    names: Sequence[str], preferences: ArrayLike, truths: Sequence[FloatArray]
) -> tuple[list[DemonstratorLoop], dict[str, int]]:
    """One :class:`DemonstratorLoop` per distinct demonstrator name (its first demo's preference
    and true loop), and each name's index."""
    prefs = np.asarray(preferences, dtype=np.float64)
    out: list[DemonstratorLoop] = []
    index: dict[str, int] = {}
    for name, (theta, rho), truth in zip(names, prefs, truths, strict=True):
        if name not in index:
            index[name] = len(out)
            out.append(DemonstratorLoop(name, float(theta), float(rho), np.asarray(truth)))
    return out, index


def mean_scores(evals: Mapping[str, ConditionedEval], tau_mm: float) -> dict[str, float]:
    """Per dataset: the success rate at τ and the mean shape distance [mm] (one seed's values,
    the inputs of :func:`~bt_pipeline.evaluate.stats.verdict` over seeds)."""
    out = {}
    for name, e in evals.items():
        out[f"{name}_success"] = e.scores.success_rate(tau_mm)
        out[f"{name}_shape_mm"] = float(np.mean(e.scores.shape_mm))
    return out


def _progress(path: FloatArray, loop: FloatArray, tree: KDTree) -> float:
    """Loops travelled along `loop` (K, 2) by `path` (n, 2), either direction.

    Each sample is placed on the loop near where the previous one was (within 1/8 of the loop
    each way, the nearest point there), so a path through a crossing (a figure-eight) keeps to
    its branch instead of jumping to the other one, as a global nearest point would.
    """
    k = loop.shape[0]
    reach = max(2, k // 8)
    window = np.arange(-reach, reach + 1)
    index = int(tree.query(path[0])[1])
    travelled = 0
    for point in path[1:]:
        near = (index + window) % k
        best = int(np.argmin(np.sum((loop[near] - point) ** 2, axis=1)))
        travelled += int(window[best])
        index = int(near[best])
    return abs(travelled) / k


def _tau_index(tau_mm: float) -> int:
    for i, tau in enumerate(TAUS_MM):
        if abs(tau - tau_mm) < 1e-9:
            return i
    raise ConfigError(f"τ must be one of {TAUS_MM} mm; got {tau_mm}")
