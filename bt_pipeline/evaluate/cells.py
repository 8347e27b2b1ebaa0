"""Per-cell statistics of ``bt reproduce``: pooled rewards, readings and the verdict test.

A *cell* is one (set, task, learner, dataset) pooled over the run's seeds. Its verdict (cleaned vs
noisy) is Welch's t-test on the per-seed mean R̄ when there are ≥ 2 seeds, on the per-rollout R̄
otherwise (docs/evaluation.md, protocol item 6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from bt_pipeline.data.tasks import Task
from bt_pipeline.evaluate.learners import LearnerName
from bt_pipeline.evaluate.protocol import DATASETS
from bt_pipeline.evaluate.reproduce_jobs import JobResult, ReproduceRun, SetName


@dataclass(frozen=True)
class Cell:
    """One (set, task, learner, dataset) aggregated over seeds."""

    mean: float
    """R̄ pooled over the rollouts of every seed."""
    std: float
    """Its standard deviation over those rollouts."""
    seed_std: float
    """Standard deviation of the per-seed means (0 for one seed)."""
    nearest: float
    """R̄ with V_E read in the nearest demonstrator's frame, pooled."""
    minmax: float
    """Mean R̄ min-max normalised across the models of its (set, task, seed), mean over seeds."""
    seed_means: tuple[float, ...]
    """Mean R̄ of each seed."""
    rewards: np.ndarray
    """R̄ of every rollout of every seed, shape (count,)."""
    shape_loss: float
    """L4 [m], pooled mean."""
    shape_distance: float
    """Phase-free distance to the nearest reference [m], pooled mean."""
    coverage: float
    """Share of the nearest reference loop the rollouts pass within h, pooled mean."""
    utility: float
    """Ũ, pooled mean."""
    count: int
    """Rollouts pooled."""
    train_seconds: float
    """Mean training time [s]."""
    finite: bool
    """Every seed trained without non-finite steps and rolled out finitely."""


def cells(run: ReproduceRun) -> dict[tuple[SetName, Task, LearnerName, str], Cell]:
    """Every (set, task, learner, dataset) of the run, pooled over seeds."""
    out = {}
    for set_name in run.config.sets:
        for task in run.config.tasks:
            jobs = [j for j in run.jobs if j.set_name == set_name and j.task == task]
            for learner in run.config.learners:
                for dataset in run.datasets:
                    evals = [j.evaluation.result(learner, dataset) for j in jobs]
                    rewards = np.concatenate([e.metrics.rewards for e in evals])
                    seed_means = tuple(float(np.mean(e.metrics.rewards)) for e in evals)
                    out[(set_name, task, learner, dataset)] = Cell(
                        mean=float(np.mean(rewards)),
                        std=float(np.std(rewards)),
                        seed_std=float(np.std(seed_means)),
                        nearest=float(np.mean([e.metrics.rewards_nearest for e in evals])),
                        minmax=float(np.mean([_minmax(j, learner, dataset) for j in jobs])),
                        seed_means=seed_means,
                        rewards=rewards,
                        shape_loss=float(np.mean([e.metrics.shape_losses for e in evals])),
                        shape_distance=float(np.mean([e.metrics.shape_distances for e in evals])),
                        coverage=float(np.mean([e.metrics.coverage for e in evals])),
                        utility=float(np.mean([e.metrics.utilities for e in evals])),
                        count=int(rewards.size),
                        train_seconds=float(np.mean([e.train_seconds for e in evals])),
                        finite=all(e.finite for e in evals),
                    )
    return out


def _minmax(job: JobResult, learner: str, dataset: str) -> float:
    """Mean R̄ of (learner, dataset) min-max normalised across the job's noisy and cleaned
    models (the Eq. 7 reading of "mean normalised reward"); 0.5 when all are equal."""
    means = {
        (r.learner, r.dataset): float(np.mean(r.metrics.rewards))
        for r in job.evaluation.results
        if r.dataset in DATASETS
    }
    if (learner, dataset) not in means:  # the truth dataset: against the same range
        means[(learner, dataset)] = float(
            np.mean(job.evaluation.result(learner, dataset).metrics.rewards)
        )
    low, high = min(means.values()), max(means.values())
    return 0.5 if high - low < 1e-12 else (means[(learner, dataset)] - low) / (high - low)


def verdict_test(noisy: Cell, cleaned: Cell) -> tuple[str, str, float]:
    """The verdict of one cell, the test used and its p-value.

    With ≥ 2 seeds: Welch's t-test on the per-seed mean R̄ (training-seed variance counts);
    with one seed: Welch's t-test on the per-rollout R̄. "cleaned" / "noisy" when p < 0.05 in
    that direction, "tie" otherwise.
    """
    if len(noisy.seed_means) >= 2 and len(cleaned.seed_means) >= 2:
        a, b, test = np.array(cleaned.seed_means), np.array(noisy.seed_means), "Welch t, seeds"
    else:
        a, b, test = cleaned.rewards, noisy.rewards, "Welch t, rollouts"
    if np.ptp(np.concatenate([a, b])) < 1e-12:
        return "tie", test, 1.0
    result = stats.ttest_ind(a, b, equal_var=False)
    p = float(result.pvalue)  # pyright: ignore[reportAttributeAccessIssue]  # missing from the stub
    if not np.isfinite(p):
        p = 1.0
    if p < 0.05:
        return ("cleaned" if a.mean() > b.mean() else "noisy"), test, p
    return "tie", test, p


def verdict_shape(noisy: Cell, cleaned: Cell) -> str:
    """ "cleaned" when the cleaned-trained rollouts lie nearer the true loops (lower mean shape
    distance), "noisy" when farther, "tie" within 0.1 mm."""
    delta = noisy.shape_distance - cleaned.shape_distance
    return "cleaned" if delta > 1e-4 else "noisy" if delta < -1e-4 else "tie"


def verdict(noisy: Cell, cleaned: Cell) -> str:
    """The verdict of :func:`verdict_test`."""
    return verdict_test(noisy, cleaned)[0]
