"""Rollout metrics against a yardstick neither dataset was built from: R̄, coverage and shape.

* **R̄** reads the value map V_E of the best *raw* demo (Eq. 11 / N), as the paper does
  (``"best"``, the headline); ``"nearest"`` first maps the rollout from the frame of the
  demonstrator whose Stage 1 loop it lies nearest into the best one's (an alternative column).
* **Coverage, shape distance, L4** compare the rollout with an independent reference loop: the
  ground truth of the nearest demonstrator on synthetic data (``true_loops``), otherwise the best
  raw demo itself. Never the Stage 1 references x_i^aligned, from which the cleaned demos were
  made (they would favour the cleaned set).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from bt_pipeline.clean.stage1.alignment import shape_loss
from bt_pipeline.clean.stage1.extract import Stage1Result, run_stage1
from bt_pipeline.clean.stage2.scales import refine_normaliser
from bt_pipeline.data.demo import Demo
from bt_pipeline.data.records import FloatArray
from bt_pipeline.evaluate.distance import PointSet
from bt_pipeline.exceptions import DemoError
from bt_pipeline.score.losses import closure_loss, smoothness_loss, symmetry_loss
from bt_pipeline.score.mi import mutual_information
from bt_pipeline.score.utility import Normaliser, normalised_utility, score_demos

RewardFrame = Literal["nearest", "best"]
"""Where V_E reads a rollout: as it is, in the best demonstrator's frame (the paper's reading,
the default), or mapped from its nearest demonstrator's frame into the best one's."""
UTILITY_WEIGHTS = (0.2, 0.2, 0.2, 0.4)
"""w_1..w_4 of Ũ for rollouts (the refinement weights, docs/algorithms.md §7 row 8)."""
UTILITY_BETA = 0.5
"""β of Ũ for rollouts: the selection-time value, the same for every learner and dataset."""
COVERAGE_TOLERANCE_M = 0.005
"""A reference point is covered when the rollout passes within this distance [m]."""


def mean_of(values: FloatArray) -> float:
    return float(np.mean(values))


def std_of(values: FloatArray) -> float:
    return float(np.std(values))


def build_yardstick(
    noisy: Sequence[Demo], seed: int = 0, true_loops: Sequence[FloatArray] | None = None
) -> Yardstick:
    """V_E, the frozen normaliser and the independent references of the noisy set.

    Args:
        noisy: The raw demos.
        seed: Seed of Stage 1 (as the cleaner's).
        true_loops: The demonstrators' true loops (K, 2) [m] (synthetic data); None: the best raw
            demo is the one reference.

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
        references=tuple(np.asarray(t, dtype=np.float64) for t in true_loops)
        if true_loops
        else (best.copy(),),
        truth=bool(true_loops),
    )


def rollout_metrics(
    rollouts: FloatArray, yardstick: Yardstick, reward_frame: RewardFrame = "best"
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
    frames = {i: _resampled(stage1.aligned[i], n) for i in yardstick.representatives}
    references = [_resampled(np.vstack([r, r[:1]]), n) for r in yardstick.references]  # closed
    # every k-d tree once (a reference's per call, a rollout's per rollout), not per distance
    frame_sets = {i: PointSet.of(f) for i, f in frames.items()}
    reference_sets = [PointSet.of(r) for r in yardstick.references]
    columns: dict[str, list[float]] = {
        k: [] for k in ("direct", "nearest", "l4", "chamfer", "coverage", "utility", "index")
    }
    for rollout in rollouts:
        drawn = PointSet.of(rollout, "a rollout")
        # The independent loop this rollout draws: phase-free, so timing cannot pick it.
        distances = [drawn.chamfer(ref) for ref in reference_sets]
        r = int(np.argmin(distances))
        l4 = shape_loss(rollout, references[r])  # Eq. (9), best shift and direction
        # The demonstrator frame for the "nearest" reading of V_E (an alternative column only).
        frame_gaps = {i: drawn.chamfer(ref) for i, ref in frame_sets.items()}
        j = min(frame_gaps, key=lambda i: frame_gaps[i])
        actions = np.zeros_like(rollout)
        actions[:-1] = np.diff(rollout, axis=0) / np.diff(times)[:, None]
        values = np.array(
            [
                mutual_information(rollout, actions),
                symmetry_loss(rollout, float(stage1.l1_thetas()[j])),
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
        columns["chamfer"].append(distances[r])
        gaps = drawn.gaps(yardstick.references[r])
        columns["coverage"].append(float(np.mean(gaps <= COVERAGE_TOLERANCE_M)))
        columns["utility"].append(float(utility[0]))
        columns["index"].append(r)
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
    demos: Sequence[Demo], count: int, noise_m: float, seed: int, anywhere: bool = True
) -> FloatArray:
    """Rollout starts: raw demo states plus N(0, noise_m²) per axis, shape (count, 2), in [m].

    Args:
        demos: The raw demos (never the cleaned ones, so the starts favour neither dataset).
        count: Number of initial states.
        noise_m: Std of the perturbation per axis [m].
        seed: Seed of the draws.
        anywhere: A random sample of a random demo (default); False: a random demo's first
            sample (§7 row 20).
    """
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, len(demos), size=count)
    samples = rng.integers(0, [demos[p].n_samples for p in picks]) if anywhere else np.zeros(count)
    starts = np.stack([demos[p].positions[int(k)] for p, k in zip(picks, samples, strict=True)])
    return starts + rng.normal(0.0, noise_m, size=(count, 2))


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
    references: tuple[FloatArray, ...]
    """Independent reference loops (K, 2) [m]: the demonstrators' true loops, or the best raw
    demo."""
    truth: bool
    """Whether `references` are ground truth."""

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
    """L4 (Eq. 9, best circular shift and direction) to the nearest independent reference [m]."""
    shape_distances: FloatArray
    """Phase-free (Chamfer) distance to the nearest independent reference [m]."""
    coverage: FloatArray
    """Share of the nearest independent reference the rollout passes within 5 mm, in [0, 1]:
    low for a rollout that stalls or draws part of the loop (which R̄ alone rewards)."""
    utilities: FloatArray
    """Ũ (Eq. 8), in [0, 1]."""
    nearest: np.ndarray
    """Index into the yardstick's references of the nearest one, int, shape (R,)."""
