"""Figures of the evaluation (PNG, matplotlib without pyplot): Figs. 8-10 and Fig. 11 of the paper.

* :func:`plot_rollouts` (Figs. 8-10): one task, a grid with rows noisy / cleaned and one column
  per learner; every rollout drawn thin over the independent references (dashed: the true loops,
  or the best raw demo), the initial states as dots, and R̄ and coverage in each panel's title.
* :func:`plot_reward_bars` (Fig. 11): mean R̄ of the rollouts, noisy (grey) vs cleaned (green),
  with one-standard-deviation error bars, per task and learner; one panel per group (e.g. D1,
  D2) and a dotted line per task at the ceiling (R̄ of the best raw demo itself).

Figures are built on :class:`matplotlib.figure.Figure` (no global pyplot state, any thread) and
written atomically (temporary file, then ``os.replace``).
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from bt_pipeline.evaluate.protocol import TaskEvaluation

DATASET_COLORS = {"noisy": "#8c8c8c", "cleaned": "#2ca02c", "truth": "#9ecae1"}
"""Bar colour of each dataset (grey raw, green cleaned as in the Rerun files, pale blue truth)."""
_ROLLOUT_COLORS = {"noisy": "#d62728", "cleaned": "#1f77b4", "truth": "#7f7f7f"}
_REFERENCE_COLOR = "#333333"
LEARNER_TITLES = {"bc": "BC", "traj_bc": "Traj-BC", "ileed": "ILEED", "node": "NODE"}
"""Display name of each learner."""


@dataclass(frozen=True)
class RewardBar:
    """One bar of the Fig. 11-style chart: a learner on a dataset of a task."""

    group: str
    """Panel (e.g. "D1"; "" for a single panel)."""
    task: str
    learner: str
    dataset: str
    mean: float
    """Mean R̄ (over rollouts, and seeds)."""
    std: float
    """Its standard deviation (the error bar)."""
    ceiling: float = float("nan")
    """R̄ of the best raw demo of the task (dotted line; NaN for none)."""


def plot_rollouts(
    evaluation: TaskEvaluation, path: str | os.PathLike[str], title: str = ""
) -> Path:
    """Figs. 8-10: rollouts of every learner on noisy (top) and cleaned (below) demos.

    A third row shows learners trained on the ground truth when the evaluation has one.

    Args:
        evaluation: One task's evaluation.
        path: Destination (.png); parent folders are created.
        title: Figure title; default names the task.

    Returns:
        `path` as a Path.
    """
    learners = evaluation.learners
    references = [np.vstack([r, r[:1]]) for r in evaluation.yardstick.references]  # closed
    all_points = np.concatenate(
        [*references, *(r.rollouts.reshape(-1, 2) for r in evaluation.results)]
    )
    low, high = all_points.min(axis=0), all_points.max(axis=0)
    pad = 0.05 * float(np.max(high - low))
    datasets = evaluation.datasets
    fig = Figure(figsize=(3.2 * len(learners) + 0.6, 3.2 * len(datasets)), layout="constrained")
    axes = fig.subplots(len(datasets), len(learners), squeeze=False, sharex=True, sharey=True)
    for row, dataset in enumerate(datasets):
        for col, learner in enumerate(learners):
            ax = axes[row, col]
            result = evaluation.result(learner, dataset)
            for k, ref in enumerate(references):
                ax.plot(
                    *ref.T,
                    "--",
                    color=_REFERENCE_COLOR,
                    lw=0.8,
                    alpha=0.7,
                    label="references" if k == 0 else None,
                )
            for rollout in result.rollouts:
                ax.plot(*rollout.T, color=_ROLLOUT_COLORS[dataset], lw=0.5, alpha=0.45)
            ax.plot(*result.rollouts[:, 0].T, ".", color="black", ms=2.0)
            ax.set_title(
                f"{LEARNER_TITLES.get(learner, learner)}, {dataset}\n"
                f"R̄ {np.mean(result.rewards):.3f} ± {np.std(result.rewards):.3f}, "
                f"coverage {np.mean(result.metrics.coverage):.2f}",
                fontsize=9,
            )
            ax.set_aspect("equal")
            ax.set_xlim(low[0] - pad, high[0] + pad)
            ax.set_ylim(low[1] - pad, high[1] + pad)
            ax.tick_params(labelsize=7)
            if col == 0:
                ax.set_ylabel(f"{dataset}\ny [m]", fontsize=9)
            if row == len(datasets) - 1:
                ax.set_xlabel("x [m]", fontsize=9)
    axes[0, 0].legend(fontsize=7, loc="upper left")
    n = evaluation.results[0].rollouts.shape[0]
    fig.suptitle(title or f"{evaluation.task}: {n} rollouts per learner, noisy (top) vs cleaned")
    return save_figure(fig, path)


def plot_reward_bars(
    bars: Sequence[RewardBar], path: str | os.PathLike[str], title: str = ""
) -> Path:
    """Fig. 11: mean R̄, noisy vs cleaned with std error bars, per task and learner.

    Args:
        bars: One bar per (group, task, learner, dataset).
        path: Destination (.png); parent folders are created.
        title: Figure title.

    Returns:
        `path` as a Path.
    """
    groups = list(dict.fromkeys(b.group for b in bars))
    fig = Figure(figsize=(11.0, 3.6 * len(groups) + 0.4), layout="constrained")
    axes = fig.subplots(len(groups), 1, squeeze=False)[:, 0]
    datasets = list(dict.fromkeys(b.dataset for b in bars))
    width = 0.76 / len(datasets)
    for ax, group in zip(axes, groups, strict=True):
        mine = [b for b in bars if b.group == group]
        slots = list(dict.fromkeys((b.task, b.learner) for b in mine))
        for d, dataset in enumerate(datasets):
            offset = (d - (len(datasets) - 1) / 2) * width
            by_slot = {(b.task, b.learner): b for b in mine if b.dataset == dataset}
            xs = [k + offset for k, slot in enumerate(slots) if slot in by_slot]
            chosen = [by_slot[slot] for slot in slots if slot in by_slot]
            ax.bar(
                xs,
                [b.mean for b in chosen],
                width,
                yerr=[b.std for b in chosen],
                color=DATASET_COLORS.get(dataset, "#444444"),
                capsize=2.5,
                error_kw={"elinewidth": 0.8},
                label=dataset,
            )
        tasks = list(dict.fromkeys(task for task, _ in slots))
        for t, task in enumerate(tasks):
            xs = [k for k, slot in enumerate(slots) if slot[0] == task]
            ceiling = next((b.ceiling for b in mine if b.task == task), float("nan"))
            if np.isfinite(ceiling):
                ax.hlines(
                    ceiling,
                    min(xs) - 0.45,
                    max(xs) + 0.45,
                    colors="black",
                    linestyles=":",
                    lw=1.0,
                    label="best raw demo" if t == 0 else None,
                )
            ax.text(
                (min(xs) + max(xs)) / 2,
                1.02,
                task,
                ha="center",
                va="bottom",
                transform=ax.get_xaxis_transform(),
                fontsize=9,
            )
            if t:
                ax.axvline(min(xs) - 0.5, color="#cccccc", lw=0.8)
        ax.set_xticks(range(len(slots)))
        ax.set_xticklabels(
            [LEARNER_TITLES.get(learner, learner) for _, learner in slots], fontsize=8
        )
        ax.set_ylabel(f"{group + ': ' if group else ''}mean normalised reward R̄", fontsize=9)
        ax.set_ylim(0.0, 1.0)
        ax.set_xlim(-0.6, len(slots) - 0.4)
        ax.legend(fontsize=8, loc="upper right", ncols=len(datasets) + 1)
    fig.suptitle(title or "Mean reward R̄ of the rollouts: noisy vs cleaned (± 1 std)")
    return save_figure(fig, path)


def save_figure(fig: Figure, path: str | os.PathLike[str]) -> Path:
    """Write `fig` as a PNG atomically (temporary file beside `path`, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:12]}.tmp")
    try:
        fig.savefig(tmp, format="png", dpi=110)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path
