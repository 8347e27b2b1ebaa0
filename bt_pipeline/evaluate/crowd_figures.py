"""The conditioned protocol's figures: success against τ, and rollouts over the true loops.

``success_tau.png``: success against τ (2-20 mm) per dataset, one panel per main crowd, with
Wilson intervals over the pooled rollouts of every seed and cell (they describe the rollouts; the
verdicts use the seeds). ``rollouts.<task>.png``: for one cell per task (seed 0, the shared crowd,
the first learner), each dataset's first rollout per demonstrator (thick) over that
demonstrator's true loop (thin, the same colour).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from bt_pipeline.evaluate.conditioned import TAUS_MM
from bt_pipeline.evaluate.crowd_jobs import CrowdRun
from bt_pipeline.evaluate.crowd_sets import CROWD_DATASETS
from bt_pipeline.evaluate.plots import LEARNER_TITLES, save_figure
from bt_pipeline.evaluate.stats import wilson

_COLORS = {"noisy": "#8c8c8c", "cleaned": "#2ca02c", "best_aligned": "#ff7f0e"}
_COLORS |= {"truth_shape": "#1f77b4", "truth_timing": "#9ecae1"}
_WHO = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b")


def plot_success_tau(run: CrowdRun, path: str | os.PathLike[str]) -> Path:
    """Success against τ per dataset, one panel per main crowd (module doc)."""
    crowds = list(run.settings.crowds)
    fig = Figure(figsize=(5.0 * len(crowds), 3.8), layout="constrained")
    axes = fig.subplots(1, len(crowds), squeeze=False)[0]
    for ax, crowd in zip(axes, crowds, strict=True):
        for dataset in CROWD_DATASETS:
            rows = [
                r
                for r in run.rows
                if r.crowd == crowd and r.dataset == dataset and r.approach == "conditioned"
            ]
            n = sum(r.rollouts for r in rows)
            if not n:
                continue
            hits = [sum(r.successes[k] for r in rows) for k in range(len(TAUS_MM))]
            low, high = zip(*(wilson(h, n) for h in hits), strict=True)
            ax.plot(TAUS_MM, np.array(hits) / n, marker="o", color=_COLORS[dataset], label=dataset)
            ax.fill_between(TAUS_MM, low, high, color=_COLORS[dataset], alpha=0.2, lw=0)
        ax.set_xlabel("τ [mm]")
        ax.set_ylabel("success rate (all learners, seeds, sets)")
        ax.set_title(f"{crowd} crowd", fontsize=10)
        ax.set_ylim(0.0, 1.02)
        ax.legend(fontsize=8, loc="lower right")
    fig.suptitle("Conditioned learners: success against τ (95 % Wilson intervals over rollouts)")
    return save_figure(fig, path)


def plot_task_rollouts(run: CrowdRun, task: str, path: str | os.PathLike[str]) -> Path | None:
    """Rollouts over the true loops for one cell of `task` (module doc); None if none kept."""
    crowd = "shared" if "shared" in run.settings.crowds else run.settings.crowds[0]
    learner = run.learners[0]
    set_name = run.settings.sets[0]
    rows = {
        r.dataset: r
        for r in run.rows
        if (r.set_name, r.task, r.crowd, r.learner, r.approach)
        == (set_name, task, crowd, learner, "conditioned")
        and r.examples is not None
    }
    prepared = next(
        (
            p
            for p in run.prepared
            if (p.seed, p.set_name, p.task, p.crowd) == (0, set_name, task, crowd)
        ),
        None,
    )
    if prepared is None or not rows:
        return None
    names = [d for d in CROWD_DATASETS if d in rows and d != "truth_timing"]
    fig = Figure(figsize=(3.6 * len(names), 3.8), layout="constrained")
    axes = fig.subplots(1, len(names), squeeze=False)[0]
    for ax, dataset in zip(axes, names, strict=True):
        examples = rows[dataset].examples
        assert examples is not None
        for d, loop in enumerate(prepared.loops):
            color = _WHO[d % len(_WHO)]
            closed = np.concatenate([loop.loop, loop.loop[:1]])
            ax.plot(*(1e3 * closed.T), color=color, lw=0.8, alpha=0.6)
            if np.isfinite(examples[d]).all():
                ax.plot(*(1e3 * examples[d].T), color=color, lw=2.0, label=loop.name)
        r = rows[dataset]
        ax.set_title(f"{dataset}: success@10 mm {r.success_at(10.0):.2f}", fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlabel("u [mm]")
        ax.set_ylabel("v [mm]")
    axes[0].legend(fontsize=7, loc="best")
    fig.suptitle(
        f"{task}, {crowd} crowd, seed 0, {LEARNER_TITLES.get(learner, learner)} conditioned: one "
        "rollout per demonstrator (thick) over its true loop (thin)",
        fontsize=9,
    )
    return save_figure(fig, path)
