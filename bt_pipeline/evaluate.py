"""The paper's evaluation (Sec. IV, Figs. 8-11): imitation learners on noisy vs cleaned demos.

For one task (pure core, :func:`evaluate_task`)::

    noisy demos ──score──> best ──Stage 1──> V_E, x_i^aligned, frozen normaliser   (the yardstick)
    for dataset in (noisy, cleaned):
        for learner in (bc, traj_bc, ileed, node):
            train on the dataset ──> 50 rollouts of N steps from perturbed initial states
            per rollout: R̄ (Eq. 11, V_E of the noisy set's best demo), L4 to the nearest
            aligned reference (Eq. 9), Ũ (Eq. 8 with L1-L4, frozen normaliser, β = 0.5)

The yardstick comes from the noisy set only, so both datasets are measured by the same V_E,
references and normaliser (docs/algorithms.md §7 row 20).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from bt_pipeline.alignment import shape_loss
from bt_pipeline.canonical import Stage1Result, run_stage1
from bt_pipeline.demo import Demo
from bt_pipeline.exceptions import ConfigError, DemoError
from bt_pipeline.learners import LEARNERS, LearnerName, learner_config, train_learner
from bt_pipeline.losses import closure_loss, smoothness_loss, symmetry_loss
from bt_pipeline.mi import mutual_information
from bt_pipeline.records import FloatArray
from bt_pipeline.refine import refine_normaliser
from bt_pipeline.scoring import Normaliser, normalised_utility, score_demos
from bt_pipeline.tasks import Task

Dataset = Literal["noisy", "cleaned"]
DATASETS: tuple[Dataset, ...] = ("noisy", "cleaned")
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

    def __post_init__(self) -> None:
        if not self.learners:
            raise ConfigError("give at least one learner")
        for name in self.learners:
            if name not in LEARNERS:
                raise ConfigError(f"unknown learner {name!r}; valid learners: {', '.join(LEARNERS)}")
        if self.rollouts < 1:
            raise ConfigError(f"--rollouts must be ≥ 1; got {self.rollouts}")
        if not 0.0 <= self.init_noise < 1.0:
            raise ConfigError(f"init_noise must lie in [0, 1); got {self.init_noise}")


@dataclass(frozen=True)
class Yardstick:
    """What every rollout of a task is measured against (built from the noisy set)."""

    stage1: Stage1Result
    """Value map V_E of the noisy set's best demo and the aligned references."""
    normaliser: Normaliser
    """Frozen raw-set (min, max) of MI, L1, L2, L3, L4."""
    size: float
    """Loop size of the best demo [m] (largest extent), for the initial-state noise."""


@dataclass(frozen=True)
class LearnerEval:
    """One learner trained on one dataset of one task, and its rollouts' metrics."""

    task: Task
    learner: LearnerName
    dataset: Dataset
    rollouts: FloatArray
    """Rollout states, shape (R, N, 2), in task coordinates [m]."""
    rewards: FloatArray
    """R̄ of each rollout, shape (R,), in [0, 1] (Eq. 11, mean-normalised)."""
    shape_losses: FloatArray
    """L4 of each rollout to its nearest aligned reference, shape (R,), in [m]."""
    utilities: FloatArray
    """Ũ of each rollout, shape (R,), in [0, 1]."""
    train_seconds: float
    """Training wall time [s]."""
    expertise: dict[str, float]
    """ILEED's learned expertise per demonstrator (empty for other learners)."""
    finite: bool
    """Training never produced a non-finite loss and every rollout is finite."""

    def to_json(self) -> dict[str, object]:
        """One row of ``bt evaluate --json``."""
        return {
            "task": self.task,
            "learner": self.learner,
            "dataset": self.dataset,
            "reward_mean": float(np.mean(self.rewards)),
            "reward_std": float(np.std(self.rewards)),
            "shape_loss": float(np.mean(self.shape_losses)),
            "shape_loss_std": float(np.std(self.shape_losses)),
            "utility": float(np.mean(self.utilities)),
            "utility_std": float(np.std(self.utilities)),
            "train_seconds": self.train_seconds,
            "expertise": self.expertise,
        }


def build_yardstick(noisy: Sequence[Demo], seed: int = 0) -> Yardstick:
    """V_E, aligned references and the frozen normaliser of the noisy set."""
    scores = score_demos(noisy)
    stage1 = run_stage1(noisy, scores.best_index, seed=seed)
    normaliser = refine_normaliser(scores.normaliser, stage1.shape_losses)
    best = noisy[scores.best_index].positions
    return Yardstick(stage1=stage1, normaliser=normaliser, size=float(np.max(np.ptp(best, axis=0))))


def rollout_metrics(
    rollouts: FloatArray, yardstick: Yardstick
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """R̄, L4 (nearest reference) and Ũ of every rollout, each shape (R,)."""
    stage1 = yardstick.stage1
    rewards = stage1.value_map.mean_rewards(rollouts)  # Eq. (11) / N
    n = rollouts.shape[1]
    times = np.linspace(0.0, 1.0, n)
    shape_losses, utilities = [], []
    for rollout in rollouts:
        # Eq. (9) against every demonstrator's reference; the nearest one is the rollout's.
        losses = [shape_loss(rollout, _resampled(ref, n)) for ref in stage1.aligned]
        j = int(np.argmin(losses))
        actions = np.zeros_like(rollout)
        actions[:-1] = np.diff(rollout, axis=0) / np.diff(times)[:, None]
        values = np.array(
            [
                mutual_information(rollout, actions),
                symmetry_loss(rollout, float(stage1.thetas[j])),
                closure_loss(rollout),
                smoothness_loss(rollout),
                losses[j],
            ]
        )
        normalised = yardstick.normaliser.normalise(values, clip=True)
        utility = normalised_utility(
            normalised[None, 0], normalised[None, 1:], UTILITY_WEIGHTS, UTILITY_BETA
        )
        shape_losses.append(losses[j])
        utilities.append(float(utility[0]))
    return np.asarray(rewards, dtype=np.float64), np.array(shape_losses), np.array(utilities)


def _resampled(curve: FloatArray, n: int) -> FloatArray:
    """`curve` (K, 2) linearly resampled to n points (identity when K == n)."""
    if curve.shape[0] == n:
        return curve
    s_old = np.linspace(0.0, 1.0, curve.shape[0])
    s_new = np.linspace(0.0, 1.0, n)
    return np.stack([np.interp(s_new, s_old, curve[:, j]) for j in range(2)], axis=1)


def initial_states(demos: Sequence[Demo], count: int, noise_m: float, seed: int) -> FloatArray:
    """A random demo's first state plus N(0, noise_m²) per axis, shape (count, 2), in [m]."""
    rng = np.random.default_rng(seed)
    starts = np.stack([demo.positions[0] for demo in demos])
    picks = rng.integers(0, len(demos), size=count)
    return starts[picks] + rng.normal(0.0, noise_m, size=(count, 2))


def evaluate_task(
    noisy: Sequence[Demo],
    cleaned: Sequence[Demo],
    config: EvalConfig | None = None,
    on_trained: Callable[[LearnerEval], None] | None = None,
) -> list[LearnerEval]:
    """Train every learner on the noisy and on the cleaned demos of one task and measure them.

    Args:
        noisy: The raw demos (they also define the yardstick).
        cleaned: The cleaned demos of the same task (any number, same N).
        config: Protocol settings.
        on_trained: Called after each learner is trained and measured (progress).

    Returns:
        One :class:`LearnerEval` per (dataset, learner), noisy first.

    Raises:
        DemoError: Empty sets, mixed tasks, or sets of different N.
    """
    config = config or EvalConfig()
    if not noisy or not cleaned:
        raise DemoError("evaluation needs both noisy and cleaned demos of the task")
    tasks = {d.task for d in (*noisy, *cleaned)}
    if len(tasks) != 1:
        raise DemoError(f"evaluate one task at a time; got demos of {sorted(tasks)}")
    lengths = {d.n_samples for d in (*noisy, *cleaned)}
    if len(lengths) != 1:
        raise DemoError(f"noisy and cleaned demos must have the same N; got {sorted(lengths)}")
    task = noisy[0].task
    n = noisy[0].n_samples
    yardstick = build_yardstick(noisy, seed=config.seed)
    x0 = initial_states(noisy, config.rollouts, config.init_noise * yardstick.size, config.seed)
    results = []
    for dataset, demos in (("noisy", noisy), ("cleaned", cleaned)):
        positions = np.stack([d.positions for d in demos])
        demonstrators = [d.demonstrator for d in demos]
        for learner in config.learners:
            start = time.perf_counter()
            trained = train_learner(
                learner,
                positions,
                demonstrators,
                learner_config(learner, quick=config.quick, seed=config.seed),
            )
            seconds = time.perf_counter() - start
            rollouts = trained.policy.rollout(x0, n_samples=n)
            finite = bool(np.all(np.isfinite(rollouts))) and trained.skipped_steps == 0
            rewards, losses, utilities = rollout_metrics(rollouts, yardstick)
            result = LearnerEval(
                task=task,
                learner=learner,
                dataset=dataset,  # type: ignore[arg-type]  # literal from DATASETS
                rollouts=rollouts,
                rewards=rewards,
                shape_losses=losses,
                utilities=utilities,
                train_seconds=seconds,
                expertise=dict(trained.expertise),
                finite=finite,
            )
            results.append(result)
            if on_trained is not None:
                on_trained(result)
    return results
