"""``bt reproduce``: the paper's Sec. IV end to end on synthetic D1 and D2, for every task.

Data flow, one job per (seed, set, task), jobs in parallel with ``workers``::

    make_d1 / make_d2 (bt_pipeline.synth) ──demos_from_recording──▶ noisy demos
        ──clean_demos (default variant)──▶ cleaned demos (+ distance of both to the true shapes)
        ──evaluate_demos (4 learners × noisy/cleaned, R rollouts each)──▶ TaskEvaluation
    all jobs ──▶ DIR/rewards.png (Fig. 11), DIR/<set>.<task>.rollouts.png (Figs. 8-10, seed 0),
                 DIR/results.json (every row), DIR/report.md (tables, paper side by side, verdict)

Presets (docs/evaluation.md): ``--quick`` is the CI-sized run: D1 and D2 for the three tasks,
the learners' quick presets, 20 rollouts; the full run uses the learners' full presets and the
paper's 50 rollouts. Results depend only on the config and seeds, not on ``workers``.
"""

from __future__ import annotations

import concurrent.futures
import json
import logging
import multiprocessing
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np
from tqdm import tqdm

from bt_pipeline.clean import CleanOptions, clean_demos
from bt_pipeline.demo import Demo, demos_from_recording
from bt_pipeline.distance import distance_to_truth
from bt_pipeline.evaluate import DATASETS, Dataset, EvalConfig, TaskEvaluation, evaluate_demos
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.learners import LEARNERS, LearnerName
from bt_pipeline.plots import RewardBar, plot_reward_bars, plot_rollouts
from bt_pipeline.records import FloatArray
from bt_pipeline.synth import make_d1, make_d2
from bt_pipeline.tasks import TASKS, Task

log = logging.getLogger("bt")

SetName = Literal["D1", "D2"]
"""The paper's synthetic sets: D1 (4 demos, one per demonstrator), D2 (20, five each)."""
SETS: tuple[SetName, ...] = ("D1", "D2")
PAPER_ILEED_D1_GAIN: dict[Task, float] = {"wiping": 0.88, "pick_and_place": 0.418, "weaving": 0.084}
"""Increase of ILEED's mean normalised reward on D1, cleaned minus noisy (paper Sec. IV)."""


@dataclass(frozen=True)
class ReproduceConfig:
    """What ``bt reproduce`` runs."""

    quick: bool = False
    """Use the learners' quick presets (and the quick rollout count)."""
    seeds: int = 1
    """Seeds 0 .. seeds - 1 of the synthetic sets, the cleaner and the learners."""
    tasks: tuple[Task, ...] = TASKS
    """Tasks."""
    sets: tuple[SetName, ...] = SETS
    """Synthetic sets."""
    learners: tuple[LearnerName, ...] = LEARNERS
    """Learners."""
    rollouts: int = 50
    """Rollouts per trained learner."""
    steps: int | None = None
    """Override every learner's optimiser steps (tiny test runs); None keeps the presets."""
    clean_epochs: int | None = None
    """Override the cleaner's refinement epochs (tiny test runs); None keeps its default."""
    workers: int = 1
    """Jobs run in parallel (processes)."""
    oracle: bool = False
    """Also train every learner on the demos' ground-truth shapes (the upper bound of cleaning)."""

    def __post_init__(self) -> None:
        if self.seeds < 1:
            raise ConfigError(f"--seeds must be ≥ 1; got {self.seeds}")
        if self.workers < 1:
            raise ConfigError(f"--workers must be ≥ 1; got {self.workers}")
        if not self.tasks or not self.sets:
            raise ConfigError("reproduce needs at least one task and one set")
        for name in self.sets:
            if name not in SETS:
                raise ConfigError(f"unknown set {name!r}; valid sets: {', '.join(SETS)}")
        EvalConfig(learners=self.learners, rollouts=self.rollouts, steps=self.steps)  # validates

    @classmethod
    def preset(cls, quick: bool, **overrides: object) -> ReproduceConfig:
        """The full run, or the CI-sized one (`quick`: 20 rollouts, quick learner presets)."""
        base = cls(quick=True, rollouts=20) if quick else cls()
        return replace(base, **overrides)  # pyright: ignore[reportArgumentType]  # validated

    def eval_config(self, seed: int) -> EvalConfig:
        """The evaluation settings of one seed."""
        return EvalConfig(
            learners=self.learners,
            rollouts=self.rollouts,
            quick=self.quick,
            seed=seed,
            steps=self.steps,
        )


@dataclass(frozen=True, eq=False)
class JobResult:
    """One (seed, set, task): the evaluation and how well the cleaner did."""

    seed: int
    set_name: SetName
    evaluation: TaskEvaluation
    truth_raw: float
    """Mean phase-free distance of the noisy demos to their true shapes [m]."""
    truth_cleaned: float
    """The same for the cleaned demos [m]."""
    clean_seconds: float
    """Synthesis and cleaning wall time [s]."""
    eval_seconds: float
    """Evaluation wall time (training, rollouts, metrics) [s]."""

    @property
    def task(self) -> Task:
        return self.evaluation.task


def run_job(job: tuple[int, SetName, Task, ReproduceConfig]) -> JobResult:
    """Generate, clean and evaluate one (seed, set, task) (runs in a worker when workers > 1)."""
    seed, set_name, task, config = job
    start = time.perf_counter()
    synth = (make_d1 if set_name == "D1" else make_d2)(task, seed)
    demos = demos_from_recording(synth.recording)
    options = CleanOptions(seed=seed, epochs=config.clean_epochs, write_rrd=False, progress=False)
    cleaned_result = clean_demos(demos, options)
    cleaned = [d.with_positions(cleaned_result.positions[i]) for i, d in enumerate(demos)]
    truths = [d.truth for d in synth.demos]
    truth_raw = np.mean(
        [distance_to_truth(d.positions, t) for d, t in zip(demos, truths, strict=True)]
    )
    truth_cleaned = np.mean(
        [distance_to_truth(d.positions, t) for d, t in zip(cleaned, truths, strict=True)]
    )
    clean_seconds = time.perf_counter() - start
    start = time.perf_counter()
    truth = truth_demos(demos, truths) if config.oracle else None
    evaluation = evaluate_demos(demos, cleaned, config.eval_config(seed), truth=truth)
    return JobResult(
        seed=seed,
        set_name=set_name,
        evaluation=evaluation,
        truth_raw=float(truth_raw),
        truth_cleaned=float(truth_cleaned),
        clean_seconds=clean_seconds,
        eval_seconds=time.perf_counter() - start,
    )


def truth_demos(demos: Sequence[Demo], truths: Sequence[FloatArray]) -> list[Demo]:
    """Each demo's ground-truth loop as a demo: one period from the point nearest the demo's
    start, at the truth's own (canonical-phase) speed, N samples, closed."""
    out = []
    for demo, truth in zip(demos, truths, strict=True):
        k = int(np.argmin(np.linalg.norm(truth - demo.positions[0], axis=1)))
        loop = np.roll(truth, -k, axis=0)
        loop = np.concatenate([loop, loop[:1]])
        s_old, s_new = np.linspace(0.0, 1.0, len(loop)), np.linspace(0.0, 1.0, demo.n_samples)
        positions = np.stack([np.interp(s_new, s_old, loop[:, j]) for j in range(2)], axis=1)
        out.append(demo.with_positions(positions))
    return out


@dataclass(frozen=True, eq=False)
class ReproduceRun:
    """Every job of a run, in (set, task, seed) order, and its config and wall time."""

    config: ReproduceConfig
    jobs: tuple[JobResult, ...]
    seconds: float
    """Wall time of the whole run [s]."""

    @property
    def datasets(self) -> tuple[Dataset, ...]:
        """Evaluated datasets: noisy, cleaned (and truth with the oracle)."""
        return (*DATASETS, "truth") if self.config.oracle else DATASETS


def run_reproduce(config: ReproduceConfig, progress: bool = True) -> ReproduceRun:
    """Run every (seed, set, task) job of `config` (progress bar on stderr)."""
    start = time.perf_counter()
    jobs: list[tuple[int, SetName, Task, ReproduceConfig]] = [
        (seed, set_name, task, config)
        for set_name in config.sets
        for task in config.tasks
        for seed in range(config.seeds)
    ]
    bar = tqdm(total=len(jobs), desc="reproduce", unit="job", file=sys.stderr, disable=not progress)
    results: list[JobResult] = []
    with bar:
        if config.workers > 1 and len(jobs) > 1:
            context = multiprocessing.get_context("spawn")
            with concurrent.futures.ProcessPoolExecutor(
                max_workers=min(config.workers, len(jobs)), mp_context=context
            ) as pool:
                for result in pool.map(run_job, jobs):
                    results.append(result)
                    bar.update(1)
        else:
            for job in jobs:
                bar.set_postfix_str(f"{job[1]} {job[2]} seed {job[0]}")
                results.append(run_job(job))
                bar.update(1)
    return ReproduceRun(config=config, jobs=tuple(results), seconds=time.perf_counter() - start)


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


def write_outputs(run: ReproduceRun, out_dir: str | Path) -> list[Path]:
    """Figures, results.json and report.md of `run` in `out_dir`; returns the written paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    what = "quick" if run.config.quick else "full"
    paths = [
        plot_reward_bars(
            reward_bars(run),
            out / "rewards.png",
            f"bt reproduce ({what}): mean R̄ of the rollouts, noisy vs cleaned (± 1 std)",
        )
    ]
    for job in run.jobs:
        if job.seed == 0:
            paths.append(
                plot_rollouts(
                    job.evaluation,
                    out / f"{job.set_name}.{job.task}.rollouts.png",
                    f"{job.set_name} {job.task}: rollouts of learners trained on noisy (top) vs "
                    "cleaned (bottom) demos",
                )
            )
    paths.append(_write_text(out / "results.json", json.dumps(results_json(run), indent=1)))
    paths.append(_write_text(out / "report.md", report_markdown(run, cells(run))))
    return paths


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


def _write_text(path: Path, text: str) -> Path:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text + "\n", encoding="utf-8")
    tmp.replace(path)
    return path


def reproduce(config: ReproduceConfig, out_dir: str | Path, progress: bool = True) -> list[Path]:
    """Run `config` and write its outputs into `out_dir` (see the module doc)."""
    run = run_reproduce(config, progress)
    log.info("reproduce: %d jobs in %.0f s", len(run.jobs), run.seconds)
    return write_outputs(run, out_dir)


__all__ = [
    "PAPER_ILEED_D1_GAIN",
    "SETS",
    "Cell",
    "JobResult",
    "ReproduceConfig",
    "ReproduceRun",
    "SetName",
    "cells",
    "report_markdown",
    "reproduce",
    "results_json",
    "run_job",
    "run_reproduce",
    "truth_demos",
    "verdict",
    "write_outputs",
]
