"""The report of ``bt reproduce``: per-cell statistics, results JSON, reward bars, Markdown."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bt_pipeline.data.tasks import Task
from bt_pipeline.evaluate.learners import LearnerName
from bt_pipeline.evaluate.protocol import (
    DATASETS,
)
from bt_pipeline.evaluate.reproduce_jobs import PAPER_ILEED_D1_GAIN, ReproduceRun, SetName
from bt_pipeline.viz.plots import RewardBar


def report_markdown(
    run: ReproduceRun, table: dict[tuple[SetName, Task, LearnerName, str], Cell]
) -> str:
    """The Markdown report: setup, cleaning quality, tables, the paper side by side, verdict."""
    c = run.config
    seeds = f"seeds 0..{c.seeds - 1}" if c.seeds > 1 else "seed 0"
    lines = [
        f"# bt reproduce ({'quick' if c.quick else 'full'}): learners on noisy vs cleaned demos",
        "",
        f"Synthetic sets {', '.join(c.sets)} × tasks {', '.join(c.tasks)}, {seeds}; learners "
        f"{', '.join(c.learners)} ({'quick' if c.quick else 'full'} presets"
        + (f", {c.steps} steps each" if c.steps else "")
        + f"), {c.rollouts} rollouts per trained learner; cleaner: default variant"
        + (f", {c.clean_epochs} epochs" if c.clean_epochs else "")
        + f". Wall time {run.seconds:.0f} s with {c.workers} worker(s).",
        "",
        "R̄ is the mean value-map reward of a rollout (Eq. 11 / N) read in the frame of the "
        "demonstrator whose loop the rollout draws; **R̄ paper** reads V_E directly, in the best "
        "demonstrator's frame, as the paper does. L4 is Eq. 9 (time-aligned) to that "
        "demonstrator's aligned reference, *shape* its phase-free distance. "
        "docs/evaluation.md explains each choice.",
        "",
        "## Cleaning quality (mean distance of the demos to their true shapes)",
        "",
        "| set | task | noisy [mm] | cleaned [mm] |",
        "|---|---|---|---|",
    ]
    for set_name in c.sets:
        for task in c.tasks:
            jobs = [j for j in run.jobs if (j.set_name, j.task) == (set_name, task)]
            raw, clean = (
                1e3 * np.mean([getattr(j, a) for j in jobs]) for a in ("truth_raw", "truth_cleaned")
            )
            lines.append(f"| {set_name} | {task} | {raw:.2f} | {clean:.2f} |")
    spread = " (± std over seeds of the per-seed means)" if c.seeds > 1 else ""
    lines += ["", f"## Results: mean ± std over rollouts{spread}", ""]
    if c.oracle:
        lines += [
            "*R̄ truth*: the same learner trained on the demos' ground-truth shapes, the upper "
            "bound of what any cleaning can give under this protocol.",
            "",
        ]
    oracle_head = " R̄ truth |" if c.oracle else ""
    for set_name in c.sets:
        lines += [
            f"### {set_name}",
            "",
            "| task | learner | R̄ noisy | R̄ cleaned | Δ R̄ | verdict |" + oracle_head + " R̄ "
            "paper noisy → cleaned | coverage noisy → cleaned | L4 [mm] noisy → cleaned | "
            "shape [mm] noisy → cleaned | Ũ noisy → cleaned |",
            "|---|---|---|---|---|---|---|---|---|---|---|" + ("---|" if c.oracle else ""),
        ]
        for task in c.tasks:
            ceiling = np.mean(
                [
                    j.evaluation.yardstick.ceiling
                    for j in run.jobs
                    if (j.set_name, j.task) == (set_name, task)
                ]
            )
            for learner in c.learners:
                n, k = (table[(set_name, task, learner, d)] for d in DATASETS)
                lines.append(
                    f"| {task} | {learner} | {_pm(n, c.seeds)} | {_pm(k, c.seeds)} | "
                    f"{k.mean - n.mean:+.3f} | {verdict(n, k)} | "
                    + (
                        f"{_pm(table[(set_name, task, learner, 'truth')], c.seeds)} | "
                        if c.oracle
                        else ""
                    )
                    + f"{n.direct:.3f} → {k.direct:.3f} | "
                    f"{n.coverage:.2f} → {k.coverage:.2f} | "
                    f"{1e3 * n.shape_loss:.1f} → {1e3 * k.shape_loss:.1f} | "
                    f"{1e3 * n.shape_distance:.1f} → {1e3 * k.shape_distance:.1f} | "
                    f"{n.utility:.3f} → {k.utility:.3f} |"
                )
            blanks = "| " * (9 + c.oracle)
            lines.append(f"| {task} | *best raw demo (ceiling)* | {ceiling:.3f} {blanks}|")
        lines.append("")
    lines += _paper_section(run, table) + _verdict_section(run, table) + _timing_section(run, table)
    lines += [
        "## Figures",
        "",
        "![Fig. 11-style rewards](rewards.png)",
        "",
        *(
            f"![{j.set_name} {j.task}]({j.set_name}.{j.task}.rollouts.png)"
            for j in run.jobs
            if j.seed == 0
        ),
    ]
    return "\n".join(lines)


def _pm(cell: Cell, seeds: int) -> str:
    text = f"{cell.mean:.3f} ± {cell.std:.3f}"
    text += f" (± {cell.seed_std:.3f})" if seeds > 1 else ""
    return text if cell.finite else text + " NON-FINITE"


def _standard_error(noisy: Cell, cleaned: Cell) -> float:
    return float(np.sqrt(noisy.std**2 / noisy.count + cleaned.std**2 / cleaned.count))


def verdict(noisy: Cell, cleaned: Cell) -> str:
    """ "cleaned" / "noisy" when the difference of R̄ exceeds 2 standard errors, else "tie"."""
    delta, se = cleaned.mean - noisy.mean, _standard_error(noisy, cleaned)
    return "cleaned" if delta > 2.0 * se else "noisy" if delta < -2.0 * se else "tie"


def _paper_section(run: ReproduceRun, table: dict) -> list[str]:
    if "D1" not in run.config.sets or "ileed" not in run.config.learners:
        return []
    lines = [
        "## The paper's claim side by side (ILEED on D1, gain in mean normalised reward)",
        "",
        "| task | paper | bt: R̄ (nearest frame) | bt: R̄ paper (best frame) |",
        "|---|---|---|---|",
    ]
    for task in run.config.tasks:
        n, k = (table[("D1", task, "ileed", d)] for d in DATASETS)
        lines.append(
            f"| {task} | {PAPER_ILEED_D1_GAIN[task]:+.3f} | {k.mean - n.mean:+.3f} "
            f"({n.mean:.3f} → {k.mean:.3f}) | {k.direct - n.direct:+.3f} "
            f"({n.direct:.3f} → {k.direct:.3f}) |"
        )
    return [*lines, ""]


def _verdict_section(run: ReproduceRun, table: dict) -> list[str]:
    keys = [
        (s, t, lr) for s in run.config.sets for t in run.config.tasks for lr in run.config.learners
    ]
    verdicts = {key: verdict(table[(*key, "noisy")], table[(*key, "cleaned")]) for key in keys}
    count = {v: sum(1 for x in verdicts.values() if x == v) for v in ("cleaned", "tie", "noisy")}
    lines = [
        "## Where cleaned beats noisy, and where it does not",
        "",
        f"Of {len(keys)} (set, task, learner) cells, R̄ is higher on cleaned demos by more than "
        f"two standard errors in **{count['cleaned']}**, lower by more than two in "
        f"**{count['noisy']}**, and within two in **{count['tie']}** (standard errors over "
        "rollouts; they ignore training-seed variance, which `--seeds` shows).",
        "",
    ]
    for label, which in (("Cleaned worse", "noisy"), ("No clear difference", "tie")):
        worse = [key for key in keys if verdicts[key] == which]
        if worse:
            items = ", ".join(
                f"{s} {t} {lr} ({table[(s, t, lr, 'noisy')].mean:.3f} → "
                f"{table[(s, t, lr, 'cleaned')].mean:.3f})"
                for s, t, lr in worse
            )
            lines += [f"- {label}: {items}."]
    partial = [
        key
        for key in keys
        if min(table[(*key, "noisy")].coverage, table[(*key, "cleaned")].coverage) < 0.5
    ]
    if partial:
        items = ", ".join(
            f"{s} {t} {lr} ({table[(s, t, lr, 'noisy')].coverage:.2f} → "
            f"{table[(s, t, lr, 'cleaned')].coverage:.2f})"
            for s, t, lr in partial
        )
        lines += [
            "- Rollouts trace less than half of the loop (coverage < 0.5) on at least one side "
            f"in: {items}. There R̄ compares failure modes (stalling on or tracing part of the "
            "V_E ridge; a stall on its peak can even score above the ceiling), not the task."
        ]
    shape_better = sum(
        1
        for key in keys
        if table[(*key, "cleaned")].shape_distance < table[(*key, "noisy")].shape_distance
    )
    l4_better = sum(
        1 for key in keys if table[(*key, "cleaned")].shape_loss < table[(*key, "noisy")].shape_loss
    )
    direct_better = sum(
        1 for key in keys if table[(*key, "cleaned")].direct > table[(*key, "noisy")].direct
    )
    if run.config.oracle:
        gains = []
        for task in run.config.tasks:
            mine = [key for key in keys if key[1] == task]
            truth, clean = (
                np.mean([table[(*key, d)].mean - table[(*key, "noisy")].mean for key in mine])
                for d in ("truth", "cleaned")
            )
            gains.append(f"{task} {truth:+.3f} with the truth, {clean:+.3f} cleaned")
        lines += [
            "- Mean gain in R̄ over noisy, by task (all sets and learners): "
            + "; ".join(gains)
            + ". The truth column bounds what any cleaning can give to these learners."
        ]
    lines += [
        f"- Phase-free shape distance lower on cleaned demos in {shape_better} of {len(keys)} "
        f"cells; L4 lower in {l4_better}; R̄ paper (best frame) higher in {direct_better}.",
        "",
    ]
    return lines


def _timing_section(run: ReproduceRun, table: dict) -> list[str]:
    lines = [
        "## Timings",
        "",
        f"Whole run {run.seconds:.0f} s wall. Synthesis + cleaning per job "
        f"{np.mean([j.clean_seconds for j in run.jobs]):.1f} s, evaluation per job "
        f"{np.mean([j.eval_seconds for j in run.jobs]):.1f} s (mean).",
        "",
        "| learner | " + " | ".join(f"train [s] {s}" for s in run.config.sets) + " |",
        "|---|" + "---|" * len(run.config.sets),
    ]
    for learner in run.config.learners:
        times = [
            np.mean(
                [
                    table[(s, t, learner, d)].train_seconds
                    for t in run.config.tasks
                    for d in DATASETS
                ]
            )
            for s in run.config.sets
        ]
        lines.append(f"| {learner} | " + " | ".join(f"{x:.1f}" for x in times) + " |")
    return [*lines, ""]


@dataclass(frozen=True)
class Cell:
    """One (set, task, learner, dataset) aggregated over seeds."""

    mean: float
    """R̄ pooled over the rollouts of every seed."""
    std: float
    """Its standard deviation over those rollouts."""
    seed_std: float
    """Standard deviation of the per-seed means (0 for one seed)."""
    direct: float
    """R̄ with V_E read directly (the paper's frame), pooled."""
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
                    out[(set_name, task, learner, dataset)] = Cell(
                        mean=float(np.mean(rewards)),
                        std=float(np.std(rewards)),
                        seed_std=float(np.std([np.mean(e.metrics.rewards) for e in evals])),
                        direct=float(np.mean([e.metrics.rewards_direct for e in evals])),
                        shape_loss=float(np.mean([e.metrics.shape_losses for e in evals])),
                        shape_distance=float(np.mean([e.metrics.shape_distances for e in evals])),
                        coverage=float(np.mean([e.metrics.coverage for e in evals])),
                        utility=float(np.mean([e.metrics.utilities for e in evals])),
                        count=int(rewards.size),
                        train_seconds=float(np.mean([e.train_seconds for e in evals])),
                        finite=all(e.finite for e in evals),
                    )
    return out


def results_json(run: ReproduceRun) -> dict[str, object]:
    """Every evaluated row, with its set and seed, plus the cleaning quality and timings."""
    rows = []
    for job in run.jobs:
        for result in job.evaluation.results:
            rows.append(
                {
                    "set": job.set_name,
                    "seed": job.seed,
                    **result.to_json(),
                    "reward_ceiling": job.evaluation.yardstick.ceiling,
                }
            )
    cleaning = [
        {
            "set": j.set_name,
            "task": j.task,
            "seed": j.seed,
            "truth_distance_raw": j.truth_raw,
            "truth_distance_cleaned": j.truth_cleaned,
            "clean_seconds": j.clean_seconds,
            "eval_seconds": j.eval_seconds,
        }
        for j in run.jobs
    ]
    config = run.config
    return {
        "config": {
            "quick": config.quick,
            "seeds": config.seeds,
            "tasks": list(config.tasks),
            "sets": list(config.sets),
            "learners": list(config.learners),
            "rollouts": config.rollouts,
            "steps": config.steps,
            "clean_epochs": config.clean_epochs,
            "oracle": config.oracle,
        },
        "seconds": run.seconds,
        "results": rows,
        "cleaning": cleaning,
    }


def reward_bars(run: ReproduceRun) -> list[RewardBar]:
    """Fig. 11 bars: one panel per set, pooled over seeds."""
    ceilings = {
        (j.set_name, j.task): float(
            np.mean(
                [
                    k.evaluation.yardstick.ceiling
                    for k in run.jobs
                    if (k.set_name, k.task) == (j.set_name, j.task)
                ]
            )
        )
        for j in run.jobs
    }
    return [
        RewardBar(set_name, task, learner, dataset, c.mean, c.std, ceilings[(set_name, task)])
        for (set_name, task, learner, dataset), c in cells(run).items()
    ]
