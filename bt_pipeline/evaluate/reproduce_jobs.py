"""The jobs of ``bt reproduce``: each (seed, set, task) generates, cleans and evaluates.

One job per (seed, set, task), run in parallel with ``workers``; the data flow and the outputs
are in :mod:`bt_pipeline.evaluate.reproduce`. Results depend only on the config and seeds, not on
``workers``.
"""

from __future__ import annotations

import concurrent.futures
import logging
import multiprocessing
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from tqdm import tqdm

from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.data.demo import Demo, demos_from_recording
from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.synth import make_d1, make_d2
from bt_pipeline.data.tasks import TASKS, Task
from bt_pipeline.evaluate.distance import distance_to_truth
from bt_pipeline.evaluate.learners import LEARNERS, LearnerName
from bt_pipeline.evaluate.protocol import (
    DATASETS,
    Dataset,
    EvalConfig,
    TaskEvaluation,
    evaluate_demos,
)
from bt_pipeline.exceptions import ConfigError

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
