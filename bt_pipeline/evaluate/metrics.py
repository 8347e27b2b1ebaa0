"""Rollout metrics against a yardstick built from the noisy demos: R̄, coverage and shape."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.spatial import KDTree

from bt_pipeline.clean.stage1.alignment import shape_loss
from bt_pipeline.clean.stage1.extract import Stage1Result, run_stage1
from bt_pipeline.clean.stage2.refiner import refine_normaliser
from bt_pipeline.data.demo import Demo
from bt_pipeline.data.records import FloatArray
from bt_pipeline.evaluate.distance import chamfer_distance
from bt_pipeline.exceptions import DemoError
from bt_pipeline.score.losses import closure_loss, smoothness_loss, symmetry_loss
from bt_pipeline.score.mi import mutual_information
from bt_pipeline.score.utility import Normaliser, normalised_utility, score_demos

RewardFrame = Literal["nearest", "best"]
"""Where V_E reads a rollout: mapped from its nearest demonstrator's frame into the best one's
(bt's default), or as it is, in the best demonstrator's frame (the paper's literal protocol)."""
UTILITY_WEIGHTS = (0.2, 0.2, 0.2, 0.4)
"""w_1..w_4 of Ũ for rollouts (the refinement weights, docs/algorithms.md §7 row 8)."""
UTILITY_BETA = 0.5
"""β of Ũ for rollouts: the selection-time value, the same for every learner and dataset."""


def mean_of(values: FloatArray) -> float:
    return float(np.mean(values))


def std_of(values: FloatArray) -> float:
    return float(np.std(values))


def build_yardstick(noisy: Sequence[Demo], seed: int = 0) -> Yardstick:
    """V_E, aligned references and the frozen normaliser of the noisy set.

    Raises:
        DemoError: No demos.
    """
    if not noisy:
        raise DemoError("the yardstick needs at least one noisy demo")
    scores = score_demos(noisy)
    stage1 = run_stage1(noisy, scores.best_index, seed=seed)
    normaliser = refine_normaliser(scores.normaliser, stage1.shape_losses)
    best = noisy[scores.best_index].positions
    keys: dict[tuple[float, float], int] = {}
    for i in range(stage1.n_demos):  # demos sharing a preference share one reference loop
        keys.setdefault((round(float(stage1.thetas[i]), 6), round(float(stage1.rhos[i]), 6)), i)
    return Yardstick(
        stage1=stage1,
        normaliser=normaliser,
        size=float(np.max(np.ptp(best, axis=0))),
        representatives=tuple(sorted(keys.values())),
        ceiling=stage1.value_map.mean_reward(best),
    )


def rollout_metrics(
    rollouts: FloatArray, yardstick: Yardstick, reward_frame: RewardFrame = "nearest"
) -> RolloutMetrics:
    """R̄ (both frames), L4, phase-free distance and Ũ of every rollout (module doc).

    Args:
        rollouts: States, shape (R, N, 2), in task coordinates [m].
        yardstick: The task's yardstick (:func:`build_yardstick`).
        reward_frame: Which R̄ is the headline `rewards`.

    Returns:
        The metrics, each of shape (R,).
    """
    stage1 = yardstick.stage1
    value_map = stage1.value_map
    n = rollouts.shape[1]
    times = np.linspace(0.0, 1.0, n)
    references = {i: _resampled(stage1.aligned[i], n) for i in yardstick.representatives}
    columns: dict[str, list[float]] = {
        k: [] for k in ("direct", "nearest", "l4", "chamfer", "coverage", "utility", "index")
    }
    for rollout in rollouts:
        # The demonstrator whose loop this rollout draws: phase-free, so timing cannot pick it.
        distances = {i: chamfer_distance(rollout, ref) for i, ref in references.items()}
        j = min(distances, key=lambda i: distances[i])
        l4 = shape_loss(rollout, references[j])  # Eq. (9), best shift and direction
        actions = np.zeros_like(rollout)
        actions[:-1] = np.diff(rollout, axis=0) / np.diff(times)[:, None]
        values = np.array(
            [
                mutual_information(rollout, actions),
                symmetry_loss(rollout, float(stage1.thetas[j])),
                closure_loss(rollout),
                smoothness_loss(rollout),
                l4,
            ]
        )
        normalised = yardstick.normaliser.normalise(values, clip=True)
        utility = normalised_utility(
            normalised[None, 0], normalised[None, 1:], UTILITY_WEIGHTS, UTILITY_BETA
        )  # Eq. (8)
        columns["direct"].append(value_map.mean_reward(rollout))  # Eq. (11) / N
        columns["nearest"].append(value_map.mean_reward(stage1.to_best_frame(j, rollout)))
        columns["l4"].append(l4)
        columns["chamfer"].append(distances[j])
        gaps, _ = KDTree(rollout).query(references[j])
        columns["coverage"].append(float(np.mean(gaps <= value_map.bandwidth)))
        columns["utility"].append(float(utility[0]))
        columns["index"].append(j)
    direct, nearest = np.array(columns["direct"]), np.array(columns["nearest"])
    return RolloutMetrics(
        rewards=nearest if reward_frame == "nearest" else direct,
        rewards_direct=direct,
        rewards_nearest=nearest,
        shape_losses=np.array(columns["l4"]),
        shape_distances=np.array(columns["chamfer"]),
        coverage=np.array(columns["coverage"]),
        utilities=np.array(columns["utility"]),
        nearest=np.array(columns["index"], dtype=np.int64),
    )


def _resampled(curve: FloatArray, n: int) -> FloatArray:
    """`curve` (K, 2) linearly resampled to n points (identity when K == n)."""
    if curve.shape[0] == n:
        return curve
    s_old = np.linspace(0.0, 1.0, curve.shape[0])
    s_new = np.linspace(0.0, 1.0, n)
    return np.stack([np.interp(s_new, s_old, curve[:, j]) for j in range(2)], axis=1)


def initial_states(
    demos: Sequence[Demo],
    count: int,
    noise_m: float,
    seed: int,
    references: FloatArray | None = None,
) -> FloatArray:
    """A random demo's first state plus N(0, noise_m²) per axis, shape (count, 2), in [m].

    Args:
        demos: The demos whose starts are drawn.
        count: Number of initial states.
        noise_m: Std of the perturbation per axis [m].
        seed: Seed of the draws (the same picks and noise whatever `references`).
        references: Each demo's closed reference loop, shape (M, K, 2) [m]: the first state is
            then moved to its nearest point on the demo's loop before the noise is added.
    """
    rng = np.random.default_rng(seed)
    starts = np.stack([demo.positions[0] for demo in demos])
    if references is not None:
        starts = np.stack(
            [_nearest_on_loop(p, ref) for p, ref in zip(starts, references, strict=True)]
        )
    picks = rng.integers(0, len(demos), size=count)
    return starts[picks] + rng.normal(0.0, noise_m, size=(count, 2))


def _nearest_on_loop(point: FloatArray, loop: FloatArray) -> FloatArray:
    """The point of the polyline `loop` (K, 2) nearest to `point` (2,)."""
    a, b = loop[:-1], loop[1:]
    ab = b - a
    t = np.clip(np.sum((point - a) * ab, axis=1) / np.maximum(np.sum(ab * ab, axis=1), 1e-30), 0, 1)
    candidates = a + t[:, None] * ab
    return candidates[int(np.argmin(np.sum((candidates - point) ** 2, axis=1)))]


@dataclass(frozen=True, eq=False)
class Yardstick:
    """What every rollout of a task is measured against (built from the noisy set)."""

    stage1: Stage1Result
    """Value map V_E of the noisy set's best demo and the aligned references."""
    normaliser: Normaliser
    """Frozen raw-set (min, max) of MI, L1, L2, L3, L4."""
    size: float
    """Loop size of the best demo [m] (largest extent), for the initial-state noise."""
    representatives: tuple[int, ...]
    """One demo index per distinct demonstrator preference (θ, ρ): the candidate references."""
    ceiling: float
    """R̄ of the best raw demo itself: what a rollout as good as the expert-like demo scores."""

    @property
    def demonstrators(self) -> int:
        """Number of distinct demonstrator preferences."""
        return len(self.representatives)


@dataclass(frozen=True, eq=False)
class RolloutMetrics:
    """Per-rollout metrics of R rollouts, each array of shape (R,)."""

    rewards: FloatArray
    """R̄ (Eq. 11 / N) with V_E read in the config's reward frame, in [0, 1]."""
    rewards_direct: FloatArray
    """R̄ with V_E read directly (the best demonstrator's frame: the paper's protocol)."""
    rewards_nearest: FloatArray
    """R̄ with V_E read in the nearest demonstrator's frame."""
    shape_losses: FloatArray
    """L4 (Eq. 9, best circular shift and direction) to the nearest aligned reference [m]."""
    shape_distances: FloatArray
    """Phase-free (Chamfer) distance to the nearest aligned reference [m]."""
    coverage: FloatArray
    """Share of the nearest reference loop the rollout passes within V_E's bandwidth h, in
    [0, 1]: low for a rollout that stalls or draws part of the loop (which R̄ alone rewards)."""
    utilities: FloatArray
    """Ũ (Eq. 8), in [0, 1]."""
    nearest: np.ndarray
    """Index (into the demos) of the nearest demonstrator's representative, int, shape (R,)."""
