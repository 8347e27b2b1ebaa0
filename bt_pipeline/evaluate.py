"""The paper's evaluation (Sec. IV, Figs. 8-11): imitation learners on noisy vs cleaned demos.

For one task (pure core, :func:`evaluate_task`)::

    noisy demos ──score──> best ──Stage 1──> V_E, x_i^aligned, frozen normaliser   (the yardstick)
    for dataset in (noisy, cleaned):
        for learner in (bc, traj_bc, ileed, node):
            train on the dataset ──> R rollouts of N steps from perturbed initial states
            per rollout: nearest demonstrator j* (phase-free distance to its reference), then
                R̄ (Eq. 11 / N: V_E in j*'s frame), L4 to j*'s aligned reference (Eq. 9),
                Ũ (Eq. 8 with L1-L4, the frozen normaliser, β = 0.5), and for comparison
                R̄ with V_E read directly (the paper's literal protocol) and the phase-free
                distance itself

The yardstick comes from the noisy set only, so both datasets are measured by the same V_E,
references, normaliser and initial states (docs/algorithms.md §7 row 20). docs/evaluation.md
explains every protocol choice, in particular why R̄ is read in the nearest demonstrator's frame:
V_E is a thin ridge along the *best* demonstrator's loop (its θ, ρ), so read directly it scores a
perfect loop of another demonstrator 0.2-0.4 against 0.6-0.7 for the best one's, whatever the
quality; a learner trained on all demonstrators draws some loop among theirs and is then
measured by its distance to the best demonstrator's preference, not by its quality.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.spatial import KDTree

from bt_pipeline.alignment import shape_loss
from bt_pipeline.canonical import Stage1Result, run_stage1
from bt_pipeline.demo import Demo
from bt_pipeline.distance import chamfer_distance
from bt_pipeline.exceptions import ConfigError, DemoError
from bt_pipeline.learners import LEARNERS, LearnerName, learner_config, train_learner
from bt_pipeline.losses import closure_loss, smoothness_loss, symmetry_loss
from bt_pipeline.mi import mutual_information
from bt_pipeline.plane import TaskPlane
from bt_pipeline.records import FloatArray
from bt_pipeline.refine import refine_normaliser
from bt_pipeline.scoring import Normaliser, normalised_utility, score_demos
from bt_pipeline.tasks import Task

Dataset = Literal["noisy", "cleaned", "truth"]
"""What a learner was trained on: the raw demos, the cleaned ones, or (synthetic sets only, as an
upper bound of any cleaning) the demos' ground-truth shapes."""
DATASETS: tuple[Dataset, ...] = ("noisy", "cleaned")
"""The datasets every evaluation compares."""
StartRule = Literal["reference", "demo"]
"""Where rollouts start (before the noise): a random demo's first state moved onto its
demonstrator's reference loop (bt's default), or the raw first state itself (§7 row 20)."""
RewardFrame = Literal["nearest", "best"]
"""Where V_E reads a rollout: mapped from its nearest demonstrator's frame into the best one's
(bt's default), or as it is, in the best demonstrator's frame (the paper's literal protocol)."""
UTILITY_WEIGHTS = (0.2, 0.2, 0.2, 0.4)
"""w_1..w_4 of Ũ for rollouts (the refinement weights, docs/algorithms.md §7 row 8)."""
UTILITY_BETA = 0.5
"""β of Ũ for rollouts: the selection-time value, the same for every learner and dataset."""


@dataclass(frozen=True)
class EvalConfig:
    """Settings of the evaluation protocol."""

    learners: tuple[LearnerName, ...] = LEARNERS
    """Learners to train."""
    rollouts: int = 50
    """Rollouts per trained learner (paper: 50)."""
    init_noise: float = 0.02
    """Std of the initial-state perturbation, as a fraction of the loop size (§7 row 20)."""
    quick: bool = False
    """Use each learner's CI-sized preset."""
    seed: int = 0
    """Seed of training and of the initial states."""
    reward_frame: RewardFrame = "nearest"
    """Frame in which V_E reads a rollout for the headline R̄ (both are always reported)."""
    starts: StartRule = "reference"
    """Where rollouts start before the perturbation."""
    steps: int | None = None
    """Override every learner's optimiser steps (tiny test runs); None keeps the presets."""

    def __post_init__(self) -> None:
        if not self.learners:
            raise ConfigError("give at least one learner")
        for name in self.learners:
            if name not in LEARNERS:
                raise ConfigError(
                    f"unknown learner {name!r}; valid learners: {', '.join(LEARNERS)}"
                )
        if len(set(self.learners)) != len(self.learners):
            raise ConfigError(f"each learner may be given once; got {', '.join(self.learners)}")
        if self.rollouts < 1:
            raise ConfigError(f"--rollouts must be ≥ 1; got {self.rollouts}")
        if not 0.0 <= self.init_noise < 1.0:
            raise ConfigError(f"init_noise must lie in [0, 1); got {self.init_noise}")
        if self.seed < 0:
            raise ConfigError(f"--seed must be ≥ 0; got {self.seed}")
        if self.reward_frame not in ("nearest", "best"):
            raise ConfigError(
                f"reward_frame must be 'nearest' or 'best'; got {self.reward_frame!r}"
            )
        if self.starts not in ("reference", "demo"):
            raise ConfigError(f"starts must be 'reference' or 'demo'; got {self.starts!r}")
        if self.steps is not None and self.steps < 1:
            raise ConfigError(f"steps must be ≥ 1 or None; got {self.steps}")


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


@dataclass(frozen=True, eq=False)
class LearnerEval:
    """One learner trained on one dataset of one task, and its rollouts' metrics."""

    task: Task
    learner: LearnerName
    dataset: Dataset
    rollouts: FloatArray
    """Rollout states, shape (R, N, 2), in task coordinates [m]."""
    metrics: RolloutMetrics
    """Per-rollout metrics."""
    train_seconds: float
    """Wall time of the learner's optimiser loop [s] (its own measure: no one-off set-up)."""
    expertise: dict[str, float]
    """ILEED's learned expertise per demonstrator (empty for other learners)."""
    finite: bool
    """Training never produced a non-finite loss and every rollout is finite."""
    final_loss: float
    """Mean training loss over the last 5 % of the steps (learner-specific units)."""

    @property
    def rewards(self) -> FloatArray:
        """Headline R̄ of each rollout, shape (R,)."""
        return self.metrics.rewards

    @property
    def shape_losses(self) -> FloatArray:
        """L4 of each rollout [m], shape (R,)."""
        return self.metrics.shape_losses

    @property
    def utilities(self) -> FloatArray:
        """Ũ of each rollout, shape (R,)."""
        return self.metrics.utilities

    def to_json(self) -> dict[str, object]:
        """One row of ``bt evaluate --json``."""
        m = self.metrics
        return {
            "task": self.task,
            "learner": self.learner,
            "dataset": self.dataset,
            "reward_mean": _mean(m.rewards),
            "reward_std": _std(m.rewards),
            "shape_loss": _mean(m.shape_losses),
            "shape_loss_std": _std(m.shape_losses),
            "utility": _mean(m.utilities),
            "utility_std": _std(m.utilities),
            "reward_direct_mean": _mean(m.rewards_direct),
            "reward_direct_std": _std(m.rewards_direct),
            "reward_nearest_mean": _mean(m.rewards_nearest),
            "reward_nearest_std": _std(m.rewards_nearest),
            "shape_distance": _mean(m.shape_distances),
            "shape_distance_std": _std(m.shape_distances),
            "coverage": _mean(m.coverage),
            "rollouts": int(self.rollouts.shape[0]),
            "train_seconds": self.train_seconds,
            "final_loss": self.final_loss,
            "finite": self.finite,
            "expertise": self.expertise,
        }


def _mean(values: FloatArray) -> float:
    return float(np.mean(values))


def _std(values: FloatArray) -> float:
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


def check_pair(noisy: Sequence[Demo], cleaned: Sequence[Demo]) -> tuple[Task, int]:
    """The task and N shared by a noisy and a cleaned demo set.

    Raises:
        DemoError: Empty sets, mixed tasks, or sets of different N.
    """
    if not noisy or not cleaned:
        raise DemoError("evaluation needs both noisy and cleaned demos of the task")
    tasks = {d.task for d in (*noisy, *cleaned)}
    if len(tasks) != 1:
        raise DemoError(f"evaluate one task at a time; got demos of {sorted(tasks)}")
    lengths = {d.n_samples for d in (*noisy, *cleaned)}
    if len(lengths) != 1:
        raise DemoError(f"noisy and cleaned demos must have the same N; got {sorted(lengths)}")
    return noisy[0].task, noisy[0].n_samples


def evaluate_task(
    noisy: Sequence[Demo],
    cleaned: Sequence[Demo],
    config: EvalConfig | None = None,
    on_trained: Callable[[LearnerEval], None] | None = None,
    yardstick: Yardstick | None = None,
    truth: Sequence[Demo] | None = None,
) -> list[LearnerEval]:
    """Train every learner on the noisy and on the cleaned demos of one task and measure them.

    Args:
        noisy: The raw demos (they also define the yardstick and the initial states).
        cleaned: The cleaned demos of the same task (any number, same N).
        config: Protocol settings.
        on_trained: Called after each learner is trained and measured (progress).
        yardstick: The noisy set's yardstick if already built (:func:`build_yardstick` with
            the config's seed); built here when None.
        truth: Demos of the ground-truth shapes (synthetic sets), a third dataset measured the
            same way: the upper bound of what cleaning can give under this protocol.

    Returns:
        One :class:`LearnerEval` per (dataset, learner): noisy, cleaned, then truth.

    Raises:
        DemoError: Empty sets, mixed tasks, or sets of different N.
    """
    config = config or EvalConfig()
    task, n = check_pair(noisy, cleaned)
    yardstick = yardstick or build_yardstick(noisy, seed=config.seed)
    references = yardstick.stage1.aligned if config.starts == "reference" else None
    noise_m = config.init_noise * yardstick.size
    x0 = initial_states(noisy, config.rollouts, noise_m, config.seed, references)
    overrides: dict[str, object] = {"seed": config.seed}
    if config.steps is not None:
        overrides["steps"] = config.steps
    if truth is not None:
        check_pair(noisy, truth)
    datasets: list[tuple[Dataset, Sequence[Demo]]] = [("noisy", noisy), ("cleaned", cleaned)]
    if truth is not None:
        datasets.append(("truth", truth))
    results = []
    for dataset, demos in datasets:
        positions = np.stack([d.positions for d in demos])
        demonstrators = [d.demonstrator for d in demos]
        for learner in config.learners:
            trained = train_learner(
                learner,
                positions,
                demonstrators,
                learner_config(learner, quick=config.quick, **overrides),
            )
            rollouts = trained.policy.rollout(x0, n_samples=n)
            finite = bool(np.all(np.isfinite(rollouts))) and trained.skipped_steps == 0
            history = trained.loss_history[np.isfinite(trained.loss_history)]
            tail = history[-max(1, len(history) // 20) :] if history.size else np.array([np.nan])
            result = LearnerEval(
                task=task,
                learner=learner,
                dataset=dataset,
                rollouts=rollouts,
                metrics=rollout_metrics(rollouts, yardstick, config.reward_frame),
                train_seconds=trained.seconds,
                expertise=dict(trained.expertise),
                finite=finite,
                final_loss=float(np.mean(tail)),
            )
            results.append(result)
            if on_trained is not None:
                on_trained(result)
    return results


@dataclass(frozen=True, eq=False)
class TaskEvaluation:
    """Every learner's evaluation on one task, with what it was measured against."""

    task: Task
    """The task."""
    yardstick: Yardstick
    """The noisy set's yardstick."""
    results: tuple[LearnerEval, ...]
    """One per (dataset, learner), noisy first."""
    plane: TaskPlane
    """The noisy set's task plane (maps rollouts to 3-D)."""
    duration_s: float
    """Mean duration of the noisy demos [s] (a rollout spans one demo)."""

    def result(self, learner: str, dataset: str) -> LearnerEval:
        """The evaluation of `learner` on `dataset`.

        Raises:
            ConfigError: No such pair was evaluated.
        """
        for r in self.results:
            if r.learner == learner and r.dataset == dataset:
                return r
        raise ConfigError(f"{learner} on {dataset} {self.task} was not evaluated")

    @property
    def learners(self) -> tuple[LearnerName, ...]:
        """Evaluated learners, in order."""
        return tuple(dict.fromkeys(r.learner for r in self.results))

    @property
    def datasets(self) -> tuple[Dataset, ...]:
        """Evaluated datasets, in order (noisy, cleaned, and truth when given)."""
        return tuple(dict.fromkeys(r.dataset for r in self.results))


def evaluate_demos(
    noisy: Sequence[Demo],
    cleaned: Sequence[Demo],
    config: EvalConfig | None = None,
    on_trained: Callable[[LearnerEval], None] | None = None,
    truth: Sequence[Demo] | None = None,
) -> TaskEvaluation:
    """:func:`evaluate_task`, returned with its yardstick, plane and demo duration."""
    config = config or EvalConfig()
    check_pair(noisy, cleaned)
    yardstick = build_yardstick(noisy, seed=config.seed)
    results = evaluate_task(noisy, cleaned, config, on_trained, yardstick, truth)
    return TaskEvaluation(
        task=noisy[0].task,
        yardstick=yardstick,
        results=tuple(results),
        plane=noisy[0].plane,
        duration_s=float(np.mean([d.duration_s for d in noisy])),
    )
