"""Per-cell statistics of ``bt reproduce``: pooled rewards, readings and the verdict test.

A *cell* is one (set, task, learner, dataset) pooled over the run's seeds. Its verdict (cleaned vs
noisy, :func:`verdict_test`) is paired over the seeds with :mod:`bt_pipeline.evaluate.stats`:
noisy, cleaned and truth of one seed share its synthetic set, yardstick and rollout starts, so
each seed gives one pair of mean R̄, and the rollouts of one trained model are never counted as
independent samples. With truth rows (``--oracle``) the truth gate comes first, as in the
conditioned protocol; with one seed there is no test (docs/evaluation.md, protocol item 6).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from bt_pipeline.data.tasks import Task
from bt_pipeline.evaluate.learners import LearnerName
from bt_pipeline.evaluate.protocol import DATASETS
from bt_pipeline.evaluate.reproduce_jobs import JobResult, ReproduceRun, SetName
from bt_pipeline.evaluate.stats import GapShare, Gate, PairedTest, paired
from bt_pipeline.evaluate.stats import verdict as paired_verdict


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
    """Mean R̄ of each seed, seeds 0, 1, ... in order (the samples of the verdict)."""
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


VerdictWord = Literal["cleaned", "noisy", "tie", "cannot tell", "no test"]
"""A cell's verdict: cleaned's R̄ higher or lower than noisy's, no significant difference,
the truth gate failed (the protocol cannot tell), or no test (fewer than 2 seeds)."""
ALPHA = 0.05
"""Level of the two-sided cleaned-vs-noisy paired t-test."""
GATE_ALPHA = 0.01
"""Level of the truth gate (truth beats noisy, paired t-test), as in the conditioned protocol."""


@dataclass(frozen=True)
class CellVerdict:
    """Cleaned vs noisy in one (set, task, learner), paired over seeds (module doc)."""

    word: VerdictWord
    reason: str
    """Why there is no test or the protocol cannot tell; empty otherwise."""
    test: PairedTest | None
    """Cleaned (b) vs noisy (a) over the seeds, higher R̄ better; None without a test."""
    gate: Gate | None
    """Truth vs noisy over the seeds (p < 0.01); None without truth rows or without a test."""
    gap: GapShare | None
    """Share of the truth-noisy gap cleaning recovers; None without truth rows or a test."""

    def text(self) -> str:
        """The report's cell, e.g. ``cleaned (paired t, 3 seeds, better in 3/3, p = 0.004)``."""
        if self.test is None:
            return self.reason
        if self.gate is not None and not self.gate.passed:
            return f"cannot tell: {self.reason}"
        t = self.test
        text = f"{self.word} (paired t, {t.n} seeds, better in {t.wins}/{t.n}, {_p(t.p_t)}"
        if np.isfinite(t.p_wilcoxon):
            text += f"; Wilcoxon {_p(t.p_wilcoxon)}"
        return text + ("; truth gate passed)" if self.gate is not None else ")")


def verdict_test(noisy: Cell, cleaned: Cell, truth: Cell | None = None) -> CellVerdict:
    """The verdict of one cell from its per-seed mean R̄ (module doc).

    With ≥ 2 seeds: with `truth`, the truth gate first (truth beats noisy, paired t-test over
    seeds, p < 0.01: :func:`~bt_pipeline.evaluate.stats.truth_gate`), "cannot tell" where it
    fails; then cleaned vs noisy, paired t-test over seeds (two-sided): "cleaned" / "noisy" when
    p < 0.05 in that direction, "tie" otherwise. Fewer than 2 seeds, or a non-finite seed mean:
    "no test", and no per-rollout test instead (one model's rollouts are not independent samples
    of a learner trained on that data).
    """
    arrays = [noisy.seed_means, cleaned.seed_means] + ([truth.seed_means] if truth else [])
    if min(len(a) for a in arrays) < 2:
        return CellVerdict("no test", "one seed: no test", None, None, None)
    if not all(np.all(np.isfinite(a)) for a in arrays):
        return CellVerdict("no test", "non-finite R̄ in a seed: no test", None, None, None)
    if truth is None:
        test = paired(noisy.seed_means, cleaned.seed_means, higher_is_better=True)
        return CellVerdict(_word(test), "", test, None, None)
    v = paired_verdict(
        noisy.seed_means,
        cleaned.seed_means,
        truth.seed_means,
        higher_is_better=True,
        alpha=GATE_ALPHA,
        cleaned_alpha=ALPHA,
    )
    if not v.gate.passed:
        g = v.gate.test
        how = "is worse than" if g.p_t < GATE_ALPHA else "does not clearly beat"
        reason = f"truth {how} noisy (paired t, {g.n} seeds, {_p(g.p_t)}; the gate needs p < 0.01)"
        return CellVerdict("cannot tell", reason, v.cleaned_vs_noisy, v.gate, v.gap)
    return CellVerdict(_word(v.cleaned_vs_noisy), "", v.cleaned_vs_noisy, v.gate, v.gap)


def _word(test: PairedTest) -> VerdictWord:
    if test.p_t < ALPHA:  # NaN (every difference 0) is not
        return "cleaned" if test.mean_diff > 0 else "noisy"
    return "tie"


def _p(p: float) -> str:
    if not np.isfinite(p):
        return "p undefined"
    return "p < 0.001" if p < 0.001 else f"p = {p:.2g}"


def verdict_shape(noisy: Cell, cleaned: Cell) -> str:
    """ "cleaned" when the cleaned-trained rollouts lie nearer the true loops (lower mean shape
    distance), "noisy" when farther, "tie" within 0.1 mm."""
    delta = noisy.shape_distance - cleaned.shape_distance
    return "cleaned" if delta > 1e-4 else "noisy" if delta < -1e-4 else "tie"


def verdict(noisy: Cell, cleaned: Cell, truth: Cell | None = None) -> VerdictWord:
    """The word of :func:`verdict_test`."""
    return verdict_test(noisy, cleaned, truth).word
