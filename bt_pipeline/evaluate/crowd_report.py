"""The conditioned protocol's part of the ``bt reproduce`` report: gate, verdict, share.

Per cell (set, task, crowd, learner, approach), over the seeds (:mod:`bt_pipeline.evaluate.stats`):

1. **the truth gate**: learners trained on the shape-only truth beat those trained on the noisy
   demos (success at τ = 10 mm, paired t-test over seeds, p < 0.01); where it fails the cell
   says the protocol cannot tell, and no cleaned-vs-noisy claim is made;
2. **the verdict**: cleaned vs noisy, paired, p < 0.05, and the share of the truth-noisy gap
   cleaning recovers, with a paired bootstrap interval;
3. the same on shape distance [mm] to each demonstrator's own true loop; the robustness row
   (starts 1-3 cm off the loops) and L4 (Eq. 9) beside them.

Tables: the main crowds (every dataset), then the held-out preference and the per-demonstrator
learner on the shared crowd, then the sweeps and the ablation
(:data:`~bt_pipeline.evaluate.crowd_sets.SWEEPS`). Figures are in
:mod:`~bt_pipeline.evaluate.crowd_figures`.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bt_pipeline.evaluate.conditioned import TAUS_MM
from bt_pipeline.evaluate.crowd_jobs import CrowdRow, CrowdRun
from bt_pipeline.evaluate.crowd_sets import CROWD_DATASETS, GATED_DATASETS
from bt_pipeline.evaluate.plots import LEARNER_TITLES
from bt_pipeline.evaluate.stats import Verdict, verdict

TAU_MM = 10.0
"""τ of the headline success rate."""

CellKey = tuple[str, str, str, str, str]
"""(set, task, crowd, learner, approach)."""
_CROWD_TEXT = {
    "independent": "independent",
    "shared": "shared",
    "no_expert": "shared, no expert",
    "three_experts": "shared, 3 experts of 4",
    "same_preference": "shared, all at θ = 0, ρ = 1",
    "random_loop": "shared, random loop",
}


@dataclass(frozen=True)
class CrowdCell:
    """One cell's per-seed values of each dataset it trained and its verdicts."""

    success: dict[str, np.ndarray]
    """Success at τ = 10 mm per seed, by dataset."""
    robust: dict[str, np.ndarray]
    """The same from starts 1-3 cm off the loops."""
    shape_mm: dict[str, np.ndarray]
    """Mean shape distance [mm] per seed, by dataset."""
    l4_mm: dict[str, np.ndarray]
    """Mean L4 (Eq. 9) [mm] per seed, by dataset."""
    on_success: Verdict | None
    """Gate and verdict on success (None with fewer than 2 seeds)."""
    on_shape: Verdict | None
    """The same on shape distance."""


def crowd_cells(run: CrowdRun) -> dict[CellKey, CrowdCell]:
    """The cells of `run`, in the order their rows were made."""
    grouped: dict[CellKey, dict[str, dict[int, CrowdRow]]] = defaultdict(lambda: defaultdict(dict))
    for row in run.rows:
        key = (row.set_name, row.task, row.crowd, row.learner, row.approach)
        grouped[key][row.dataset][row.seed] = row
    out = {}
    for key, by_dataset in grouped.items():
        seeds = sorted(by_dataset["noisy"])
        success = _per_seed(by_dataset, seeds, lambda r: r.success_at(TAU_MM))
        robust = _per_seed(by_dataset, seeds, lambda r: r.robust[TAUS_MM.index(TAU_MM)])
        shape = _per_seed(by_dataset, seeds, lambda r: r.shape_mm)
        l4 = _per_seed(by_dataset, seeds, lambda r: r.l4_mm)
        on_success = on_shape = None
        if len(seeds) >= 2:
            on_success = verdict(
                success["noisy"], success["cleaned"], success["truth_shape"], higher_is_better=True
            )
            on_shape = verdict(
                shape["noisy"], shape["cleaned"], shape["truth_shape"], higher_is_better=False
            )
        out[key] = CrowdCell(success, robust, shape, l4, on_success, on_shape)
    return out


def _per_seed(
    by_dataset: dict[str, dict[int, CrowdRow]], seeds: list[int], value: Callable[[CrowdRow], float]
) -> dict[str, np.ndarray]:
    """`value` of each seed's row, by dataset (those the cell trained, in CROWD_DATASETS order)."""
    names = [d for d in CROWD_DATASETS if d in by_dataset]
    return {d: np.array([value(by_dataset[d][s]) for s in seeds]) for d in names}


def crowd_section(run: CrowdRun, cells: dict[CellKey, CrowdCell]) -> list[str]:
    """The Markdown section that leads the report."""
    s = run.settings
    main = {k: c for k, c in cells.items() if k[2] in s.crowds and k[4] == "conditioned"}
    lines = [
        "## Does cleaning help a learner that keeps each demonstrator's preference?",
        "",
        f"Crowds {', '.join(s.crowds)} (shared: the naive demos share their biases, "
        "bt_pipeline/data/synth_crowd.py), sets "
        f"{', '.join(s.sets)}, seeds 0..{s.seeds - 1}. Every learner takes each demo's "
        "(θ, ρ) as an input and is rolled out "
        f"{s.per_demonstrator} times per demonstrator from that demonstrator's true loop, its "
        "second period scored against that loop. **Success** at τ: the rollout passes within τ "
        "of ≥ 90 % of the loop, returns within τ of its start and goes ≥ 0.95 times around. "
        "**Robust**: the same from starts 1-3 cm off the loop. **L4**: Eq. 9 against the true "
        "loop (it reads the timing too). Datasets: noisy, cleaned, best aligned (the best demo's "
        "loop aligned to each demo: what selection buys without refinement), and the "
        "generator's truth, shape-only and shape-plus-timing. "
        f"Wall time {run.seconds:.0f} s.",
        "",
        "| set | task | crowd | learner | success@10 mm noisy / cleaned / best aligned / truth "
        "shape / truth timing | robust@10 mm noisy / cleaned / truth | shape [mm] noisy / "
        "cleaned / best aligned / truth shape | L4 [mm] noisy / cleaned / truth | gate "
        "(truth vs noisy) | cleaned vs noisy | share of the gap recovered |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (set_name, task, crowd, learner, _), cell in main.items():
        lines.append(
            f"| {set_name} | {task} | {crowd} | {LEARNER_TITLES.get(learner, learner)} | "
            f"{_values(cell.success, CROWD_DATASETS, 2)} | "
            f"{_values(cell.robust, GATED_DATASETS, 2)} | "
            f"{_values(cell.shape_mm, CROWD_DATASETS[:4], 1)} | "
            f"{_values(cell.l4_mm, GATED_DATASETS, 1)} | {_verdict_columns(cell.on_success)} |"
        )
    lines += ["", *_summary(main), "", *why_lines(run), "", "![success against τ](success_tau.png)"]
    lines += [""]
    tasks = dict.fromkeys(k[1] for k in main)
    lines += [f"![rollouts, {t}](rollouts.{t}.png)" for t in tasks] + [""]
    lines += _held_out_section(run, cells) + _sweep_section(run, cells)
    return lines


def why_lines(run: CrowdRun) -> list[str]:
    """Per main crowd, from this run's own numbers: how much of their true loops the demos cover
    (a learner gets no example of a part its demos leave out), and whose rollouts succeed with
    the cleaned demos: the best demo's demonstrator's or the others'."""
    out = []
    for crowd in run.settings.crowds:
        prepared = [p for p in run.prepared if p.crowd == crowd]
        if not prepared:
            continue
        others = {
            d: np.concatenate([np.delete(p.coverage[d], p.best) for p in prepared])
            for d in ("noisy", "cleaned")
        }
        best_cov = np.array([p.coverage["cleaned"][p.best] for p in prepared])
        own, rest = [], []
        by_key = {(p.seed, p.set_name, p.task): p for p in prepared}
        for r in run.rows:
            if (r.crowd, r.dataset, r.approach) != (crowd, "cleaned", "conditioned"):
                continue
            p = by_key[(r.seed, r.set_name, r.task)]
            names = [loop.name for loop in p.loops]
            b = names.index(p.demonstrators[p.best])
            own.append(r.success_by_demonstrator[b])
            rest += [v for d, v in enumerate(r.success_by_demonstrator) if d != b]
        out.append(
            f"- *Why, {crowd} crowd.* The demos other than the cleaner's best cover "
            f"{others['noisy'].mean():.2f} of their true loops within {TAU_MM:.0f} mm raw and "
            f"{others['cleaned'].mean():.2f} cleaned; {np.mean(others['cleaned'] >= 0.9):.0%} "
            f"of them cover ≥ 0.9 cleaned (the best demo: {best_cov.mean():.2f}). Cleaning "
            "refines each demo where and as far as it was drawn (the best demo's loop is aligned "
            "to each demo's own samples): a part every naive demo leaves out, or a lobe every one "
            "skips, stays out, and a shared drift or bulge moves the aligned loop with it; a "
            "learner given a naive demonstrator's preference has no example of the true loop. "
            "Learners trained on the cleaned "
            f"demos succeed at {TAU_MM:.0f} mm in {np.nanmean(own):.2f} of the best demo's "
            f"demonstrator's rollouts and {np.nanmean(rest):.2f} of the others'."
        )
    return out


def _held_out_section(run: CrowdRun, cells: dict[CellKey, CrowdCell]) -> list[str]:
    """The held-out preference and the per-demonstrator learner, on the shared crowd."""
    rows = {k: c for k, c in cells.items() if k[4] in ("held_out", "per_demonstrator")}
    if not rows:
        return []
    seen = {k[:4]: c for k, c in cells.items() if k[4] == "conditioned"}
    lines = [
        "### A preference never seen, and one policy per demonstrator (shared crowd)",
        "",
        "**Held out**: per seed, demonstrator (seed mod 4) is left out of training and the "
        "conditioned policy is rolled out for its preference only. **Per demonstrator**: one "
        "unconditioned policy per demonstrator, trained on its demos alone (one demo in D1). "
        "*Seen* is the conditioned policy trained on everyone, the same cell's main row.",
        "",
        "| set | task | learner | approach | success@10 mm noisy / cleaned / truth shape | "
        "seen: noisy / cleaned / truth | gate (truth vs noisy) | cleaned vs noisy | share of "
        "the gap recovered |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for (set_name, task, crowd, learner, approach), cell in rows.items():
        base = seen.get((set_name, task, crowd, learner))
        seen_text = "—" if base is None else _values(base.success, GATED_DATASETS, 2)
        lines.append(
            f"| {set_name} | {task} | {LEARNER_TITLES.get(learner, learner)} | "
            f"{approach.replace('_', ' ')} | {_values(cell.success, GATED_DATASETS, 2)} | "
            f"{seen_text} | {_verdict_columns(cell.on_success)} |"
        )
    for approach in ("held_out", "per_demonstrator"):
        part = {k: c for k, c in rows.items() if k[4] == approach}
        if part:
            lines += ["", f"*{approach.replace('_', ' ')}*:", *_summary(part)]
    return [*lines, ""]


def _sweep_section(run: CrowdRun, cells: dict[CellKey, CrowdCell]) -> list[str]:
    """The sweep of the expert share, the θ = 0, ρ = 1 ablation and the random loops."""
    s = run.settings
    rows = {k: c for k, c in cells.items() if k[2] in s.sweeps and k[2] not in s.crowds}
    if not rows:
        return []
    lines = [
        "### Sweeps: the expert share, one shared preference, loops bt never drew",
        "",
        "Shared-bias crowds with no expert-like demo or 3 of 4; with every demonstrator at "
        "θ = 0, ρ = 1 (where the paper's pooled, unconditioned protocol is legitimate: the "
        "preference input is then constant); and on a loop drawn at random per seed and task "
        "instead of the task's guide. Learners "
        f"{', '.join(LEARNER_TITLES.get(lr, lr) for lr in s.sweep_learners)}.",
        "",
        "| set | task | crowd | learner | success@10 mm noisy / cleaned / truth shape | shape "
        "[mm] noisy / cleaned / truth | gate (truth vs noisy) | cleaned vs noisy | share of "
        "the gap recovered |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for (set_name, task, crowd, learner, _), cell in rows.items():
        lines.append(
            f"| {set_name} | {task} | {_CROWD_TEXT.get(crowd, crowd)} | "
            f"{LEARNER_TITLES.get(learner, learner)} | "
            f"{_values(cell.success, GATED_DATASETS, 2)} | "
            f"{_values(cell.shape_mm, GATED_DATASETS, 1)} | {_verdict_columns(cell.on_success)} |"
        )
    for crowd in s.sweeps:
        part = {k: c for k, c in rows.items() if k[2] == crowd}
        if part:
            lines += ["", f"*{_CROWD_TEXT.get(crowd, crowd)}*:", *_summary(part)]
    return [*lines, ""]


def _values(by: dict[str, np.ndarray], names: tuple[str, ...], digits: int) -> str:
    return " / ".join(f"{by[d].mean():.{digits}f}" if d in by else "—" for d in names)


def _verdict_columns(v: Verdict | None) -> str:
    """The gate, the verdict and the share, as three table cells."""
    if v is None:
        return "one seed: no gate | — | —"
    gate = ("passes: " if v.gate.passed else "fails: ") + v.gate.reason
    if not v.gate.passed:
        return f"{gate} | cannot tell | —"
    return f"{gate} | {v.outcome} | {_share(v)}"


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
                "approach": r.approach,
                "success": dict(zip(map(str, TAUS_MM), r.success, strict=True)),
                "robust_success": dict(zip(map(str, TAUS_MM), r.robust, strict=True)),
                "shape_mm": r.shape_mm,
                "shape_by_demonstrator_mm": [
                    v if np.isfinite(v) else None for v in r.shape_by_demonstrator_mm
                ],
                "l4_mm": r.l4_mm,
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
                "approach": key[4],
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
