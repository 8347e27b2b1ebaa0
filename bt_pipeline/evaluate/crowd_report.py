"""The conditioned protocol's part of the ``bt reproduce`` report: gate, verdict, share, figure.

Per cell (set, task, crowd, learner), over the seeds (:mod:`bt_pipeline.evaluate.stats`):

1. **the truth gate**: learners trained on the shape-only truth beat those trained on the noisy
   demos (success at τ = 10 mm, paired t-test over seeds, p < 0.01); where it fails the cell
   says the protocol cannot tell, and no cleaned-vs-noisy claim is made;
2. **the verdict**: cleaned vs noisy, paired, p < 0.05, and the share of the truth-noisy gap
   cleaning recovers, with a paired bootstrap interval;
3. the same on shape distance [mm] to each demonstrator's own true loop, and the
   shape-plus-timing truth beside it.

The figure shows success against τ (2-20 mm) per dataset, with Wilson intervals over the pooled
rollouts of every seed and cell (they describe the rollouts, the verdicts use the seeds).
"""

from __future__ import annotations

import os
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from bt_pipeline.evaluate.conditioned import TAUS_MM
from bt_pipeline.evaluate.crowd_jobs import CROWD_DATASETS, CrowdRow, CrowdRun
from bt_pipeline.evaluate.stats import Verdict, verdict, wilson
from bt_pipeline.viz.plots import LEARNER_TITLES, save_figure

TAU_MM = 10.0
"""τ of the headline success rate."""
_COLORS = {"noisy": "#8c8c8c", "cleaned": "#2ca02c", "best_aligned": "#ff7f0e"}
_COLORS |= {"truth_shape": "#1f77b4", "truth_timing": "#9ecae1"}

CellKey = tuple[str, str, str, str]
"""(set, task, crowd, learner)."""


@dataclass(frozen=True)
class CrowdCell:
    """One cell's per-seed values of each dataset and its verdicts."""

    success: dict[str, np.ndarray]
    """Success at τ = 10 mm per seed, by dataset."""
    shape_mm: dict[str, np.ndarray]
    """Mean shape distance [mm] per seed, by dataset."""
    on_success: Verdict | None
    """Gate and verdict on success (None with fewer than 2 seeds)."""
    on_shape: Verdict | None
    """The same on shape distance."""


def crowd_cells(run: CrowdRun) -> dict[CellKey, CrowdCell]:
    """The cells of `run`, in (set, task, crowd, learner) order."""
    grouped: dict[CellKey, dict[str, dict[int, CrowdRow]]] = defaultdict(lambda: defaultdict(dict))
    for row in run.rows:
        key = (row.set_name, row.task, row.crowd, row.learner)
        grouped[key][row.dataset][row.seed] = row
    out = {}
    for key, by_dataset in grouped.items():
        seeds = sorted(by_dataset["noisy"])
        success = {
            d: np.array([by_dataset[d][s].success_at(TAU_MM) for s in seeds])
            for d in CROWD_DATASETS
        }
        shape = {d: np.array([by_dataset[d][s].shape_mm for s in seeds]) for d in CROWD_DATASETS}
        on_success = on_shape = None
        if len(seeds) >= 2:
            on_success = verdict(
                success["noisy"], success["cleaned"], success["truth_shape"], higher_is_better=True
            )
            on_shape = verdict(
                shape["noisy"], shape["cleaned"], shape["truth_shape"], higher_is_better=False
            )
        out[key] = CrowdCell(success, shape, on_success, on_shape)
    return out


def crowd_section(run: CrowdRun, cells: dict[CellKey, CrowdCell]) -> list[str]:
    """The Markdown section that leads the report."""
    s = run.settings
    lines = [
        "## Does cleaning help a learner that keeps each demonstrator's preference?",
        "",
        f"Crowds {', '.join(s.crowds)} (shared: the naive demos share a corner cut, an undershot "
        "stretch, a pause place and a backwards minority), sets "
        f"{', '.join(s.sets)}, seeds 0..{s.seeds - 1}. Every learner takes each demo's "
        "(θ, ρ) as an input and is rolled out "
        f"{s.per_demonstrator} times per demonstrator from that demonstrator's true loop, its "
        "second period scored against that loop. **Success** at τ: the rollout passes within τ "
        "of ≥ 90 % of the loop, returns within τ of its start and goes ≥ 0.95 times around. "
        "Datasets: noisy, cleaned, best aligned (the best demo's loop aligned to each demo: what "
        "selection buys without refinement), and the generator's truth, shape-only and "
        "shape-plus-timing. "
        f"Wall time {run.seconds:.0f} s.",
        "",
        "| set | task | crowd | learner | success@10 mm noisy / cleaned / best aligned / truth "
        "shape / truth timing | shape [mm] noisy / cleaned / best aligned / truth shape | gate "
        "(truth vs noisy) | cleaned vs noisy | share of the gap recovered |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for (set_name, task, crowd, learner), cell in cells.items():
        rates = " / ".join(f"{cell.success[d].mean():.2f}" for d in CROWD_DATASETS)
        shapes = " / ".join(f"{cell.shape_mm[d].mean():.1f}" for d in CROWD_DATASETS[:4])
        v = cell.on_success
        if v is None:
            gate, outcome, share = "one seed: no gate", "—", "—"
        else:
            gate = ("passes: " if v.gate.passed else "fails: ") + v.gate.reason
            outcome = v.outcome if v.gate.passed else "—"
            share = _share(v) if v.gate.passed else "—"
        name = LEARNER_TITLES.get(learner, learner)
        lines.append(
            f"| {set_name} | {task} | {crowd} | {name} | {rates} | {shapes} | {gate} | "
            f"{outcome} | {share} |"
        )
    lines += ["", *_summary(cells), "", "![success against τ](success_tau.png)", ""]
    return lines


def _share(v: Verdict) -> str:
    g = v.gap
    if not np.isfinite(g.share):
        return g.note or "—"
    ci = "" if not np.all(np.isfinite(g.ci)) else f" (95 % CI {g.ci[0]:.0%} to {g.ci[1]:.0%})"
    return f"{g.share:.0%}{ci}"


def _summary(cells: dict[CellKey, CrowdCell]) -> list[str]:
    """Counts over cells: the gate, the verdicts, the share ≥ 50 %; on success and on shape."""
    out = []
    for what, pick in (("success@10 mm", "on_success"), ("shape distance", "on_shape")):
        verdicts = [getattr(c, pick) for c in cells.values() if getattr(c, pick) is not None]
        if not verdicts:
            out.append(f"- On {what}: one seed, no verdict (a verdict needs ≥ 2 seeds; use 10).")
            continue
        gated = [v for v in verdicts if v.gate.passed]
        better = sum(v.outcome == "cleaned better" for v in gated)
        worse = sum(v.outcome == "cleaned worse" for v in gated)
        half = sum(np.isfinite(v.gap.share) and v.gap.share >= 0.5 for v in gated)
        out.append(
            f"- On {what}: the truth gate passes in {len(gated)} of {len(verdicts)} cells; there, "
            f"cleaned is better than noisy in {better}, worse in {worse}, and recovers ≥ 50 % "
            f"of the gap in {half}."
        )
    return out


def plot_success_tau(run: CrowdRun, path: str | os.PathLike[str]) -> Path:
    """Success against τ per dataset, one panel per crowd, Wilson intervals (module doc)."""
    crowds = list(run.settings.crowds)
    fig = Figure(figsize=(5.0 * len(crowds), 3.8), layout="constrained")
    axes = fig.subplots(1, len(crowds), squeeze=False)[0]
    for ax, crowd in zip(axes, crowds, strict=True):
        for dataset in CROWD_DATASETS:
            rows = [r for r in run.rows if r.crowd == crowd and r.dataset == dataset]
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


def crowd_json(run: CrowdRun, cells: dict[CellKey, CrowdCell]) -> dict[str, object]:
    """The conditioned protocol's rows and cells for results.json."""
    return {
        "rows": [
            {
                "seed": r.seed,
                "set": r.set_name,
                "task": r.task,
                "crowd": r.crowd,
                "learner": r.learner,
                "dataset": r.dataset,
                "success": dict(zip(map(str, TAUS_MM), r.success, strict=True)),
                "robust_success": dict(zip(map(str, TAUS_MM), r.robust, strict=True)),
                "shape_mm": r.shape_mm,
                "shape_by_demonstrator_mm": list(r.shape_by_demonstrator_mm),
                "train_seconds": r.train_seconds,
            }
            for r in run.rows
        ],
        "cells": [
            {
                "set": key[0],
                "task": key[1],
                "crowd": key[2],
                "learner": key[3],
                "verdict_success": None if c.on_success is None else c.on_success.summary(),
                "verdict_shape": None if c.on_shape is None else c.on_shape.summary(),
            }
            for key, c in cells.items()
        ],
        "cleaning_mm": [
            {
                "seed": p.seed,
                "set": p.set_name,
                "task": p.task,
                "crowd": p.crowd,
                "noisy": p.truth_raw_mm,
                "cleaned": p.truth_cleaned_mm,
            }
            for p in run.prepared
        ],
        "seconds": run.seconds,
    }
