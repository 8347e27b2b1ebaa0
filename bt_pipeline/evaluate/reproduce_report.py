"""The report of ``bt reproduce``: per-cell statistics, results JSON, reward bars, Markdown."""

from __future__ import annotations

import numpy as np

from bt_pipeline.data.tasks import Task
from bt_pipeline.evaluate.cells import (
    Cell,
    CellVerdict,
    cells,
    verdict,
    verdict_shape,
    verdict_test,
)
from bt_pipeline.evaluate.learners import LearnerName
from bt_pipeline.evaluate.plots import RewardBar
from bt_pipeline.evaluate.protocol import DATASETS
from bt_pipeline.evaluate.reproduce_jobs import PAPER_ILEED_D1_GAIN, ReproduceRun, SetName
from bt_pipeline.evaluate.reproduce_verdicts import (
    cell_verdict,
    verdict_cell,
    verdict_section,
    verdicts_json,
)


def report_markdown(
    run: ReproduceRun, table: dict[tuple[SetName, Task, LearnerName, str], Cell]
) -> str:
    """The Markdown report: setup, cleaning quality, competence, tables, the paper, verdict."""
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
        "Learners see the phase of a canonical oscillator besides the position and train on "
        "corrective (DART-style) pairs, the same way on both datasets. Rollouts start at random "
        "raw-demo states plus 2 % noise. **R̄** is the paper's reading: the mean value-map reward "
        "of a rollout (Eq. 11 / N), V_E of the best raw demo read directly. Extra readings: "
        "*R̄ nearest* (V_E read in the nearest demonstrator's frame) and *min-max* (each model's "
        "mean R̄ normalised across the eight noisy/cleaned models of its set, task and seed). "
        "Coverage (share of the true loop within 5 mm of the rollout), *shape* (phase-free "
        "distance) and L4 (Eq. 9) are measured against the demonstrators' **true loops**, which "
        "neither dataset was built from. docs/evaluation.md explains each choice.",
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
    lines += ["", *competence_section(run)]
    spread = " (± std over seeds of the per-seed means)" if c.seeds > 1 else ""
    lines += ["", f"## Results: R̄ mean ± std over rollouts{spread}", ""]
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
            "| task | learner | R̄ noisy | R̄ cleaned | Δ R̄ | verdict (paired over seeds) |"
            + oracle_head
            + " R̄ nearest noisy → cleaned | min-max noisy → cleaned | coverage noisy → cleaned |"
            " shape [mm] noisy → cleaned | L4 [mm] noisy → cleaned | Ũ noisy → cleaned |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|" + ("---|" if c.oracle else ""),
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
                    f"{k.mean - n.mean:+.3f} | {verdict_cell(table, set_name, task, learner)} | "
                    + (
                        f"{_pm(table[(set_name, task, learner, 'truth')], c.seeds)} | "
                        if c.oracle
                        else ""
                    )
                    + f"{n.nearest:.3f} → {k.nearest:.3f} | "
                    f"{n.minmax:.2f} → {k.minmax:.2f} | "
                    f"{n.coverage:.2f} → {k.coverage:.2f} | "
                    f"{1e3 * n.shape_distance:.1f} → {1e3 * k.shape_distance:.1f} | "
                    f"{1e3 * n.shape_loss:.1f} → {1e3 * k.shape_loss:.1f} | "
                    f"{n.utility:.3f} → {k.utility:.3f} |"
                )
            blanks = "| " * (10 + c.oracle)
            lines.append(f"| {task} | *best raw demo (ceiling)* | {ceiling:.3f} {blanks}|")
        lines.append("")
    lines += _paper_section(run, table) + verdict_section(run, table) + _timing_section(run, table)
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


def competence_section(run: ReproduceRun) -> list[str]:
    """The oracle rows: competence on perfect demos of one and of the four D1 demonstrators,
    the four also given to conditioned learners."""
    rows = run.competence
    if not rows:
        return []
    lines = [
        "## Oracle rows: can the learners learn the tasks? (perfect demos, no cleaning)",
        "",
        "One demonstrator: each learner trained on 4 perfect demos of teacher_a (the generator's "
        "intended path, each with its own start phase and speed profile), rolled out from 20 "
        "perturbed demo states. Pass: coverage ≥ 0.9 and shape ≤ 2 × the demos' own (floored at "
        "1 mm). *Attracting*: share of rollouts from 1-3 cm off the loop that end one period "
        "later within 2 mm of it (largest final gap in brackets).",
        "",
        "| task | learner | coverage | shape [mm] | demos' own [mm] | pass | attracting |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r.check == "one":
            lines.append(
                f"| {r.task} | {r.learner} | {r.coverage:.2f} | {1e3 * r.shape_error_m:.2f} | "
                f"{1e3 * r.demos_error_m:.2f} | {'yes' if r.passed else '**no**'} | "
                f"{r.converged:.2f} ({1e3 * r.final_gap_m:.1f} mm) |"
            )
    conditioned = [r for r in rows if r.check == "four_conditioned"]
    if conditioned:
        lines += [
            "",
            "Four demonstrators, conditioned: one perfect demo each of teacher_a-d, every learner "
            "given each demo's (θ, ρ) as an input (the conditioned protocol's learners, quick "
            "presets) and each rollout run with the preference of the demonstrator it started "
            "from. *Own loop, worst demonstrator*: per demonstrator the mean distance of its "
            "rollouts to its own loop, the largest of the four. Pass: ≤ 2 mm.",
            "",
            "| task | learner | coverage of own loop | own loop, worst demonstrator [mm] | "
            "mean loop [mm] | nearest loop is own | pass | attracting |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for r in conditioned:
            lines.append(
                f"| {r.task} | {r.learner} | {r.coverage:.2f} | {1e3 * r.worst_own_error_m:.2f} "
                f"| {1e3 * r.mean_loop_error_m:.1f} | {r.nearest_own:.2f} | "
                f"{'yes' if r.passed else '**no**'} | {r.converged:.2f} |"
            )
    four = [r for r in rows if r.check == "four"]
    if four:
        lines += [
            "",
            "Four demonstrators, unconditioned (one perfect demo each of teacher_a-d, "
            "θ = 5, -5, 10, -10°, ρ = 1-1.3): each rollout against the loop of the "
            "demonstrator whose demo it started from (*own*), and against the mean-preference "
            "loop (θ = 0°, ρ = 1.15). A single policy that averages the preferences lies nearer "
            "the mean loop than its own.",
            "",
            "| task | learner | coverage of own loop | shape to own [mm] | shape to mean loop "
            "[mm] | nearest loop is own | attracting |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in four:
            lines.append(
                f"| {r.task} | {r.learner} | {r.coverage:.2f} | {1e3 * r.shape_error_m:.1f} | "
                f"{1e3 * r.mean_loop_error_m:.1f} | {r.nearest_own:.2f} | {r.converged:.2f} |"
            )
        averaging = sum(r.mean_loop_error_m < r.shape_error_m for r in four)
        lines += [
            "",
            f"In {averaging} of {len(four)} (task, learner) pairs the rollouts lie nearer the "
            "mean-preference loop than their own demonstrator's: one policy trained on several "
            "preferences averages them.",
        ]
    return [*lines, ""]


def _pm(cell: Cell, seeds: int) -> str:
    text = f"{cell.mean:.3f} ± {cell.std:.3f}"
    text += f" (± {cell.seed_std:.3f})" if seeds > 1 else ""
    return text if cell.finite else text + " NON-FINITE"


def _paper_section(run: ReproduceRun, table: dict) -> list[str]:
    if "D1" not in run.config.sets or "ileed" not in run.config.learners:
        return []
    lines = [
        "## The paper's claim side by side (ILEED on D1, gain in mean normalised reward)",
        "",
        "| task | paper | bt: R̄ (paper's reading) | bt: R̄ nearest frame | bt: min-max |",
        "|---|---|---|---|---|",
    ]
    for task in run.config.tasks:
        n, k = (table[("D1", task, "ileed", d)] for d in DATASETS)
        lines.append(
            f"| {task} | {PAPER_ILEED_D1_GAIN[task]:+.3f} | {k.mean - n.mean:+.3f} "
            f"({n.mean:.3f} → {k.mean:.3f}) | {k.nearest - n.nearest:+.3f} "
            f"({n.nearest:.3f} → {k.nearest:.3f}) | {k.minmax - n.minmax:+.2f} "
            f"({n.minmax:.2f} → {k.minmax:.2f}) |"
        )
    return [*lines, ""]


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


def results_json(run: ReproduceRun) -> dict[str, object]:
    """Every evaluated row, with its set and seed, plus the cleaning quality, timings and each
    (set, task, learner)'s verdict."""
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
        "competence": [r.to_json() for r in run.competence],
        "cleaning": cleaning,
        "verdicts": verdicts_json(run),
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


__all__ = [
    "Cell",
    "CellVerdict",
    "cell_verdict",
    "cells",
    "report_markdown",
    "results_json",
    "reward_bars",
    "verdict",
    "verdict_cell",
    "verdict_shape",
    "verdict_test",
]
