"""The paper's evaluation (Sec. IV, Figs. 8-11): imitation learners on noisy vs cleaned demos.

For one task (pure core, :func:`evaluate_task`)::

    noisy demos ──score──> best ──Stage 1──> V_E, frozen normaliser         (the yardstick)
    true loops (synthetic) or the best raw demo                              (the references)
    for dataset in (noisy, cleaned):
        for learner in (bc, traj_bc, ileed, node):
            train on the dataset ──> R rollouts of N steps from perturbed raw-demo states
            per rollout: R̄ (Eq. 11 / N, V_E read directly: the paper's reading, the headline),
                R̄ in the nearest demonstrator's frame (an alternative), coverage, phase-free
                distance and L4 (Eq. 9) to the nearest independent reference, Ũ (Eq. 8)

Both datasets are measured by the same V_E, references, normaliser and initial states, and none
of them was built from the cleaned set or from the Stage 1 references the cleaned demos were made
from (docs/evaluation.md gives every choice).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from bt_pipeline.data.demo import Demo
from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.tasks import Task
from bt_pipeline.evaluate.learners import (
    LEARNERS,
    STATES,
    LearnerName,
    StateRep,
    learner_config,
    train_learner,
)
from bt_pipeline.evaluate.metrics import (
    RewardFrame,
    RolloutMetrics,
    Yardstick,
    build_yardstick,
    initial_states,
    mean_of,
    rollout_metrics,
    std_of,
)
from bt_pipeline.exceptions import ConfigError, DemoError

Dataset = Literal["noisy", "cleaned", "truth"]
"""What a learner was trained on: the raw demos, the cleaned ones, or (synthetic sets only, as an
upper bound of any cleaning) the demos' ground-truth shapes."""
DATASETS: tuple[Dataset, ...] = ("noisy", "cleaned")
"""The datasets every evaluation compares."""
StartRule = Literal["raw", "first"]
"""Where rollouts start (before the noise): a random sample of a random raw demo (bt's default),
or a random raw demo's first sample (§7 row 20). Raw demos either way: neither dataset's own."""


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
    reward_frame: RewardFrame = "best"
    """Frame in which V_E reads a rollout for the headline R̄: "best" is the paper's reading
    (both are always reported)."""
    starts: StartRule = "raw"
    """Where rollouts start before the perturbation."""
    state: StateRep = "phase"
    """The learners' state: "position" is the paper as written."""
    corrective: bool = True
    """Train on corrective (DART-style) pairs; False is the paper as written."""
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
        if self.starts not in ("raw", "first"):
            raise ConfigError(f"starts must be 'raw' or 'first'; got {self.starts!r}")
        if self.state not in STATES:
            raise ConfigError(f"state must be one of {', '.join(STATES)}; got {self.state!r}")
        if self.steps is not None and self.steps < 1:
            raise ConfigError(f"steps must be ≥ 1 or None; got {self.steps}")


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
            "reward_mean": mean_of(m.rewards),
            "reward_std": std_of(m.rewards),
            "shape_loss": mean_of(m.shape_losses),
            "shape_loss_std": std_of(m.shape_losses),
            "utility": mean_of(m.utilities),
            "utility_std": std_of(m.utilities),
            "reward_direct_mean": mean_of(m.rewards_direct),
            "reward_direct_std": std_of(m.rewards_direct),
            "reward_nearest_mean": mean_of(m.rewards_nearest),
            "reward_nearest_std": std_of(m.rewards_nearest),
            "shape_distance": mean_of(m.shape_distances),
            "shape_distance_std": std_of(m.shape_distances),
            "coverage": mean_of(m.coverage),
            "rollouts": int(self.rollouts.shape[0]),
            "train_seconds": self.train_seconds,
            "final_loss": self.final_loss,
            "finite": self.finite,
            "expertise": self.expertise,
        }


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
    task, _n = check_pair(noisy, cleaned)
    yardstick = yardstick or build_yardstick(noisy, seed=config.seed)
    x0 = rollout_starts(noisy, config, yardstick)
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
            result = evaluate_learner(
                task, learner, dataset, positions, demonstrators, config, yardstick, x0
            )
            results.append(result)
            if on_trained is not None:
                on_trained(result)
    return results


def rollout_starts(noisy: Sequence[Demo], config: EvalConfig, yardstick: Yardstick) -> FloatArray:
    """The initial states every learner of a task is rolled out from, shape (R, 2) [m]: perturbed
    raw-demo states (:attr:`EvalConfig.starts`), the same for every dataset."""
    noise_m = config.init_noise * yardstick.size
    return initial_states(noisy, config.rollouts, noise_m, config.seed, config.starts == "raw")


def evaluate_learner(
    task: Task,
    learner: LearnerName,
    dataset: Dataset,
    positions: FloatArray,
    demonstrators: Sequence[str],
    config: EvalConfig,
    yardstick: Yardstick,
    x0: FloatArray,
) -> LearnerEval:
    """Train one learner on one dataset of a task, roll it out from `x0` and measure it.

    One (dataset, learner) of :func:`evaluate_task`, which calls it in a loop; ``bt reproduce``
    runs each as a job of its own. The result depends only on its arguments (training is seeded by
    ``config.seed``), not on which other learners ran before it or in which process.

    Args:
        task: The task.
        learner: Which learner.
        dataset: What `positions` are (noisy, cleaned or truth).
        positions: Training demos, shape (M, N, 2), in task coordinates [m].
        demonstrators: Who drew each demo (M names; ILEED's expertise groups).
        config: Protocol settings.
        yardstick: The noisy set's yardstick.
        x0: Initial states, shape (R, 2) [m] (:func:`rollout_starts`).
    """
    overrides: dict[str, object] = {"seed": config.seed, "state": config.state}
    if not config.corrective:
        overrides["dart_fraction"] = 0.0
    if config.steps is not None:
        overrides["steps"] = config.steps
    trained = train_learner(
        learner, positions, demonstrators, learner_config(learner, quick=config.quick, **overrides)
    )
    rollouts = trained.policy.rollout(x0, n_samples=positions.shape[1])
    finite = bool(np.all(np.isfinite(rollouts))) and trained.skipped_steps == 0
    history = trained.loss_history[np.isfinite(trained.loss_history)]
    tail = history[-max(1, len(history) // 20) :] if history.size else np.array([np.nan])
    return LearnerEval(
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
    true_loops: Sequence[FloatArray] | None = None,
) -> TaskEvaluation:
    """:func:`evaluate_task`, returned with its yardstick, plane and demo duration.

    `true_loops` are the demonstrators' true loops (synthetic data): the independent references
    of coverage and shape; without them the best raw demo is the reference.
    """
    config = config or EvalConfig()
    check_pair(noisy, cleaned)
    yardstick = build_yardstick(noisy, seed=config.seed, true_loops=true_loops)
    results = evaluate_task(noisy, cleaned, config, on_trained, yardstick, truth)
    return TaskEvaluation(
        task=noisy[0].task,
        yardstick=yardstick,
        results=tuple(results),
        plane=noisy[0].plane,
        duration_s=float(np.mean([d.duration_s for d in noisy])),
    )
