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
        shape distance (Chamfer, mm), L4 (Eq. 9, mm), coverage within τ, progress (loops per
        period), success(τ) = coverage(τ) ≥ 0.9, it returns within τ of its start and
        progress ≥ 0.95

Two other ways to train, on the same data and starts: ``held_out`` trains without one
demonstrator's demos and rolls out for that demonstrator only (does the policy generalise to a
preference it never saw?), and ``per_demonstrator`` trains one unconditioned policy per
demonstrator on its demos alone.

The rollouts of one trained model describe that model; comparisons between datasets are made
over seeds (:mod:`bt_pipeline.evaluate.stats`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import KDTree

from bt_pipeline.clean.stage1.alignment import shape_loss
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
Approach = Literal["conditioned", "held_out", "per_demonstrator"]
"""How a learner is trained and rolled out (module doc)."""
APPROACHES: tuple[Approach, ...] = ("conditioned", "held_out", "per_demonstrator")
OFFSETS: tuple[tuple[float, float] | None, ...] = (None, (0.01, 0.03))
"""Starts on the true loops (plus noise), and the robustness row's 1-3 cm off them [m]."""


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
    l4_mm: FloatArray
    """L4 (Eq. 9: best circular shift and direction) of the scored period against the
    demonstrator's true loop [mm], (R,): unlike the shape distance, it reads the timing too."""
    coverage: FloatArray
    """Share of the true loop within τ of the scored period, shape (R, len(TAUS_MM))."""
    returns: np.ndarray
    """Whether the period returns within τ of its start, shape (R, len(TAUS_MM)) (bool)."""
    progress: FloatArray
    """Loops travelled along the true loop in the period (either direction), shape (R,)."""
    demonstrators: int
    """D, the number of demonstrators' loops scored against (some may have no rollout)."""

    @property
    def success(self) -> np.ndarray:
        """success(τ) of each rollout, shape (R, len(TAUS_MM)) (bool; module doc)."""
        return (self.coverage >= COVER) & self.returns & (self.progress[:, None] >= PROGRESS)

    def success_rate(self, tau_mm: float) -> float:
        """Share of rollouts that succeed at τ (one of :data:`TAUS_MM`)."""
        return float(np.mean(self.success[:, _tau_index(tau_mm)]))

    def by_demonstrator(self, values: ArrayLike) -> FloatArray:
        """The mean of per-rollout `values` (R,) over each demonstrator's rollouts, (D,); NaN for
        a demonstrator without rollouts."""
        v = np.asarray(values, dtype=np.float64)
        return np.array(
            [
                v[self.who == d].mean() if np.any(self.who == d) else np.nan
                for d in range(self.demonstrators)
            ]
        )


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
    shape, l4, coverage, returns, progress = [], [], [], [], []
    trees = [KDTree(d.loop) for d in loops]
    for path, d in zip(x, w, strict=True):
        loop = loops[int(d)].loop
        shape.append(1000.0 * chamfer_distance(path, loop))
        l4.append(1000.0 * shape_loss(path, _resampled(loop, len(path))))  # Eq. (9)
        gaps, _ = KDTree(path).query(loop)
        coverage.append(np.mean(gaps[:, None] <= taus[None, :], axis=0))
        tail = path[int((1.0 - _RETURN) * len(path)) :]
        back = float(np.min(np.linalg.norm(tail - path[0], axis=1)))
        returns.append(back <= taus)
        progress.append(_progress(path, loop, trees[int(d)]))
    return RolloutScores(
        who=w,
        shape_mm=np.array(shape),
        l4_mm=np.array(l4),
        coverage=np.array(coverage),
        returns=np.array(returns),
        progress=np.array(progress),
        demonstrators=len(loops),
    )


@dataclass(frozen=True, eq=False)
class ConditionedEval:
    """One learner trained on one dataset, rolled out for every demonstrator (or, held out, for
    one)."""

    learner: LearnerName
    dataset: str
    scores: RolloutScores
    """From starts on the true loops."""
    robust: RolloutScores
    """From starts 1-3 cm off the true loops."""
    train_seconds: float
    examples: FloatArray
    """The first on-loop rollout's scored period of each demonstrator, (D, n, 2) [m]; NaN for
    a demonstrator not rolled out (held out: all but one)."""


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
    approach: Approach = "conditioned",
    held_out: int = 0,
) -> ConditionedEval:
    """Train `learner` on `positions` (M, N, 2) [m] with each demo's (θ [deg], ρ) (M, 2) and
    score it for every demonstrator of `loops` (module doc).

    `conditioned=False` trains the paper's unconditioned learner on the same data and rolls it
    out from the same starts (it cannot be told whose loop to draw). `demonstrators` (M names,
    matching the loops' names) group ILEED's expertise; the ``held_out`` (``loops[held_out]``'s
    demos left out) and ``per_demonstrator`` approaches need them. Every approach rolls a
    demonstrator out from the same starts.
    """
    x = np.asarray(positions, dtype=np.float64)
    prefs = np.asarray(preferences, dtype=np.float64)
    names = np.array(demonstrators if demonstrators is not None else [""] * x.shape[0])
    if approach != "conditioned" and demonstrators is None:
        raise ConfigError(f"the {approach} approach needs each demo's demonstrator")
    everyone = np.ones(x.shape[0], dtype=bool)
    units: list[tuple[np.ndarray, list[int], bool]]  # (demos trained on, rolled out for, cond)
    if approach == "conditioned":
        units = [(everyone, list(range(len(loops))), conditioned)]
    elif approach == "held_out":
        units = [(names != loops[held_out].name, [held_out], True)]
    else:
        units = [(names == d.name, [i], False) for i, d in enumerate(loops)]
    overrides: dict[str, object] = {"seed": seed}
    if steps is not None:
        overrides["steps"] = steps
    config = learner_config(learner, quick=quick, **overrides)
    n = x.shape[1]
    wanted = np.array([[d.theta_deg, d.rho] for d in loops])
    starts = [starts_on_loops(loops, per_demonstrator, seed + 1, off_m=off) for off in OFFSETS]
    periods: list[list[FloatArray]] = [[] for _ in OFFSETS]
    whos: list[list[np.ndarray]] = [[] for _ in OFFSETS]
    seconds = 0.0
    for mask, targets, cond in units:
        if not mask.any():
            raise ConfigError(f"no demos to train the {approach} learner on")
        trained = train_learner(
            learner,
            x[mask],
            list(names[mask]) if demonstrators is not None else None,
            config,
            prefs[mask] if cond else None,
        )
        seconds += trained.seconds
        for k, (x0, who) in enumerate(starts):
            pick = np.isin(who, targets)
            states = trained.policy.rollout(
                x0[pick], 2 * n - 1, preferences=wanted[who[pick]] if cond else None
            )
            periods[k].append(states[:, n - 1 :])
            whos[k].append(who[pick])
    scored = [
        score_rollouts(np.concatenate(p), np.concatenate(w), loops)
        for p, w in zip(periods, whos, strict=True)
    ]
    examples = np.full((len(loops), n, 2), np.nan)
    on_loop, who = np.concatenate(periods[0]), np.concatenate(whos[0])
    for d in range(len(loops)):
        if np.any(who == d):
            examples[d] = on_loop[int(np.flatnonzero(who == d)[0])]
    return ConditionedEval(learner, dataset, scored[0], scored[1], seconds, examples)


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


def _resampled(loop: FloatArray, n: int) -> FloatArray:
    """The open loop (K, 2) at n − 1 even steps of its own parameter, closed: shape (n, 2), the
    last sample the first (Eq. 9's reference: one period of a rollout of n samples)."""
    k = loop.shape[0]
    closed = np.concatenate([loop, loop[:1]])
    s = np.linspace(0.0, k, n)
    return np.stack([np.interp(s, np.arange(k + 1), closed[:, j]) for j in range(2)], axis=1)
