"""The jobs of ``bt reproduce``: generate and clean each (seed, set, task), then train and
measure each learner on each of its datasets, and the competence checks.

Two stages of jobs, each run in parallel with ``workers`` (:func:`run_reproduce`); the data flow
and the outputs are in :mod:`bt_pipeline.evaluate.reproduce`. Results depend only on the config
and seeds, not on ``workers``, the executor or the order the jobs run in.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.data.demo import Demo, demos_from_recording
from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.synth import make_d1, make_d2
from bt_pipeline.data.tasks import TASKS, GuidedTask, Task, parse_guided_task
from bt_pipeline.evaluate.distance import distance_to_truth
from bt_pipeline.evaluate.learners import LEARNERS, LearnerName, learner_config
from bt_pipeline.evaluate.metrics import Yardstick, build_yardstick
from bt_pipeline.evaluate.oracle import CompetenceRow, competence_check
from bt_pipeline.evaluate.protocol import (
    DATASETS,
    Dataset,
    EvalConfig,
    LearnerEval,
    TaskEvaluation,
    check_pair,
    evaluate_learner,
    rollout_starts,
)
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.execute import ExecutorConfig, reuse_workers, run_jobs

log = logging.getLogger("bt")

SetName = Literal["D1", "D2"]
"""The paper's synthetic sets: D1 (4 demos, one per demonstrator), D2 (20, five each)."""
SETS: tuple[SetName, ...] = ("D1", "D2")
PAPER_ILEED_D1_GAIN: dict[GuidedTask, float] = {
    "wiping": 0.88,
    "pick_and_place": 0.418,
    "weaving": 0.084,
}
"""Increase of ILEED's mean normalised reward on D1, cleaned minus noisy (paper Sec. IV)."""


@dataclass(frozen=True)
class ReproduceConfig:
    """What ``bt reproduce`` runs."""

    quick: bool = False
    """Use the learners' quick presets (and the quick rollout count)."""
    seeds: int = 1
    """Seeds 0 .. seeds - 1 of the synthetic sets, the cleaner and the learners."""
    tasks: tuple[GuidedTask, ...] = TASKS
    """Tasks: synthetic sets exist only for the tasks with a built-in guide shape."""
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
    competence: bool = True
    """Run the competence checks (perfect demos of one and of four demonstrators, the four also
    given to conditioned learners) as oracle rows."""
    paper_learners: bool = False
    """The learners as the paper wrote them: 2-D position state, no corrective data."""

    def __post_init__(self) -> None:
        if self.seeds < 1:
            raise ConfigError(f"--seeds must be ≥ 1; got {self.seeds}")
        if self.workers < 1:
            raise ConfigError(f"--workers must be ≥ 1; got {self.workers}")
        if not self.tasks or not self.sets:
            raise ConfigError("reproduce needs at least one task and one set")
        for task in self.tasks:
            parse_guided_task(task)
        for name in self.sets:
            if name not in SETS:
                raise ConfigError(f"unknown set {name!r}; valid sets: {', '.join(SETS)}")
        EvalConfig(learners=self.learners, rollouts=self.rollouts, steps=self.steps)  # validates

    @classmethod
    def preset(cls, quick: bool, **overrides: object) -> ReproduceConfig:
        """The full run (3 seeds, 50 rollouts), or the CI-sized one (`quick`: one seed, 20
        rollouts, quick learner presets)."""
        base = cls(quick=True, rollouts=20) if quick else cls(seeds=3)
        return replace(base, **overrides)  # pyright: ignore[reportArgumentType]  # validated

    def eval_config(self, seed: int) -> EvalConfig:
        """The evaluation settings of one seed."""
        return EvalConfig(
            learners=self.learners,
            rollouts=self.rollouts,
            quick=self.quick,
            seed=seed,
            steps=self.steps,
            state="position" if self.paper_learners else "phase",
            corrective=not self.paper_learners,
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
    """Synthesis, cleaning and yardstick wall time [s]."""
    eval_seconds: float
    """Evaluation wall time (training, rollouts, metrics), summed over its learner jobs [s]."""

    @property
    def task(self) -> Task:
        return self.evaluation.task


@dataclass(frozen=True, eq=False)
class PreparedSet:
    """One (seed, set, task) generated and cleaned, with what its learners are measured by."""

    seed: int
    set_name: SetName
    task: GuidedTask
    data: dict[Dataset, tuple[FloatArray, tuple[str, ...]]]
    """Training positions (M, N, 2) [m] and demonstrators of each dataset (noisy, cleaned, and
    truth with the oracle)."""
    yardstick: Yardstick
    """The noisy set's yardstick (independent references: the true loops)."""
    x0: FloatArray
    """Rollout starts, shape (R, 2) [m], shared by every learner and dataset."""
    plane: TaskPlane
    """The noisy set's task plane."""
    duration_s: float
    """Mean duration of the noisy demos [s]."""
    truth_raw: float
    """Mean phase-free distance of the noisy demos to their true shapes [m]."""
    truth_cleaned: float
    """The same for the cleaned demos [m]."""
    seconds: float
    """Wall time of this preparation [s]."""


def prepare_set(job: tuple[int, SetName, GuidedTask, ReproduceConfig]) -> PreparedSet:
    """Generate and clean one (seed, set, task) and build its yardstick and rollout starts (a job
    of the first stage; runs in a worker when workers > 1)."""
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
    datasets: dict[Dataset, Sequence[Demo]] = {"noisy": demos, "cleaned": cleaned}
    if config.oracle:
        datasets["truth"] = truth_demos(demos, truths)
    for other in datasets.values():
        check_pair(demos, other)
    eval_config = config.eval_config(seed)
    loops = {d.record.demonstrator: d.truth for d in synth.demos}  # one per demonstrator
    yardstick = build_yardstick(demos, seed=eval_config.seed, true_loops=list(loops.values()))
    return PreparedSet(
        seed=seed,
        set_name=set_name,
        task=task,
        data={
            name: (np.stack([d.positions for d in ds]), tuple(d.demonstrator for d in ds))
            for name, ds in datasets.items()
        },
        yardstick=yardstick,
        x0=rollout_starts(demos, eval_config, yardstick),
        plane=demos[0].plane,
        duration_s=float(np.mean([d.duration_s for d in demos])),
        truth_raw=float(truth_raw),
        truth_cleaned=float(truth_cleaned),
        seconds=time.perf_counter() - start,
    )


@dataclass(frozen=True, eq=False)
class LearnerJob:
    """One learner on one dataset of one prepared (seed, set, task): a job of the second stage."""

    task: Task
    learner: LearnerName
    dataset: Dataset
    positions: FloatArray
    """Training demos, shape (M, N, 2) [m]."""
    demonstrators: tuple[str, ...]
    config: EvalConfig
    yardstick: Yardstick
    x0: FloatArray


def run_learner(job: LearnerJob) -> tuple[LearnerEval, float]:
    """Train, roll out and measure one learner (runs in a worker when workers > 1); returns its
    evaluation and wall time [s]."""
    start = time.perf_counter()
    result = evaluate_learner(
        job.task,
        job.learner,
        job.dataset,
        job.positions,
        job.demonstrators,
        job.config,
        job.yardstick,
        job.x0,
    )
    return result, time.perf_counter() - start


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
    competence: tuple[CompetenceRow, ...] = ()
    """The competence checks (oracle rows), seed 0, in (check, task, learner) order."""

    @property
    def datasets(self) -> tuple[Dataset, ...]:
        """Evaluated datasets: noisy, cleaned (and truth with the oracle)."""
        return (*DATASETS, "truth") if self.config.oracle else DATASETS


CompetenceCheck = Literal["one", "four", "four_conditioned"]
"""The competence checks (:mod:`~bt_pipeline.evaluate.oracle`): perfect demos of one
demonstrator, of the four D1 demonstrators, and of the four given to a conditioned learner."""
COMPETENCE_CHECKS: tuple[CompetenceCheck, ...] = ("one", "four", "four_conditioned")
CompetenceJob = tuple[CompetenceCheck, GuidedTask, LearnerName, ReproduceConfig]
"""(check, task, learner, config): one competence check."""


def run_competence(job: CompetenceJob) -> CompetenceRow:
    """One competence check, seed 0 (runs in a worker when workers > 1); the conditioned one
    trains the quick presets, as the conditioned protocol does (its ``quick_learners``)."""
    check, task, learner, config = job
    conditioned = check == "four_conditioned"
    quick, steps, paper = config.quick or conditioned, config.steps, config.paper_learners
    return competence_check(
        "four" if conditioned else check, task, learner, quick, 0, min(20, config.rollouts),
        steps, paper, conditioned=conditioned,
    )  # fmt: skip


STEP_COST: dict[LearnerName, float] = {"bc": 1.0, "traj_bc": 1.1, "ileed": 1.4, "node": 14.0}
"""CPU cost of one optimiser step of each learner, relative to BC's. Measured on the full presets
(``benchmarks/evaluation/bench_reproduce.py --estimate-full``: BC 9-10 s, Traj-BC 8-12 s,
ILEED 8-10 s, NODE 22-25 s of CPU per learner job of 1500, 1500, 1200 and 300 steps); it orders
the jobs, it does not change them."""
COMPETENCE_COST = 0.7
"""A competence check's cost as a share of the same learner's job (measured: 6-15 s of CPU)."""


def job_cost(learner: LearnerName, config: ReproduceConfig, demos: int = 4) -> float:
    """Estimated CPU cost of training and measuring `learner` on `demos` demos (arbitrary units):
    optimiser steps × :data:`STEP_COST`, plus the per-demo phase estimation and the metrics."""
    steps = config.steps or learner_config(learner, quick=config.quick).steps
    return steps * STEP_COST[learner] + 20.0 * demos + 2.0 * config.rollouts


def _run_stage2(job: LearnerJob | CompetenceJob) -> tuple[LearnerEval, float] | CompetenceRow:
    return run_learner(job) if isinstance(job, LearnerJob) else run_competence(job)


def _label(job: LearnerJob | CompetenceJob) -> str:
    if isinstance(job, LearnerJob):
        return f"{job.task} {job.learner} {job.dataset} seed {job.config.seed}"
    return f"competence {job[0]} {job[1]} {job[2]}"


def run_reproduce(
    config: ReproduceConfig, progress: bool = True, executor: ExecutorConfig | None = None
) -> ReproduceRun:
    """Run every (seed, set, task) of `config` and its competence checks (progress bars on
    stderr), in two stages of jobs:

    1. one job per (seed, set, task): generate, clean, build the yardstick and the rollout starts
       (:func:`prepare_set`);
    2. one job per (seed, set, task, dataset, learner) (:func:`run_learner`) and per competence
       check, submitted longest first (:func:`job_cost`) so that the workers finish together.

    Every job is seeded by its own config, so the results do not depend on the executor, the
    number of workers or the order the jobs run in.
    """
    start = time.perf_counter()
    executor = executor or ExecutorConfig("processes", config.workers)
    keys: list[tuple[int, SetName, GuidedTask]] = [
        (s, n, t) for n in config.sets for t in config.tasks for s in range(config.seeds)
    ]
    with reuse_workers(executor):  # one pool of workers for both stages
        prepared = run_jobs(
            prepare_set,
            [(*key, config) for key in keys],
            executor,
            desc="reproduce: clean",
            progress=progress,
            label=lambda job: f"{job[1]} {job[2]} seed {job[0]}",
        )
        jobs: list[LearnerJob | CompetenceJob] = []
        costs: list[float] = []
        for p in prepared:
            eval_config = config.eval_config(p.seed)
            for dataset, (positions, demonstrators) in p.data.items():
                for learner in config.learners:
                    job = LearnerJob(
                        p.task,
                        learner,
                        dataset,
                        positions,
                        demonstrators,
                        eval_config,
                        p.yardstick,
                        p.x0,
                    )
                    jobs.append(job)
                    costs.append(job_cost(learner, config, positions.shape[0]))
        if config.competence:
            for check in COMPETENCE_CHECKS:
                sized = replace(config, quick=True) if check == "four_conditioned" else config
                for task in config.tasks:
                    for learner in config.learners:
                        jobs.append((check, task, learner, config))
                        costs.append(job_cost(learner, sized) * COMPETENCE_COST)
        order = sorted(range(len(jobs)), key=lambda i: -costs[i])  # longest first
        done = run_jobs(
            _run_stage2,
            [jobs[i] for i in order],
            executor,
            desc="reproduce: train",
            progress=progress,
            label=_label,
        )
    results: list = [None] * len(jobs)
    for i, result in zip(order, done, strict=True):
        results[i] = result
    per_set = (len(DATASETS) + int(config.oracle)) * len(config.learners)
    return ReproduceRun(
        config=config,
        jobs=tuple(
            _assemble(p, results[k * per_set : (k + 1) * per_set]) for k, p in enumerate(prepared)
        ),
        seconds=time.perf_counter() - start,
        competence=tuple(results[len(prepared) * per_set :]),
    )


def _assemble(prepared: PreparedSet, evals: Sequence[tuple[LearnerEval, float]]) -> JobResult:
    """The :class:`JobResult` of one prepared set from its learner jobs' results, in the order the
    jobs were made (dataset, then learner)."""
    return JobResult(
        seed=prepared.seed,
        set_name=prepared.set_name,
        evaluation=TaskEvaluation(
            task=prepared.task,
            yardstick=prepared.yardstick,
            results=tuple(e for e, _ in evals),
            plane=prepared.plane,
            duration_s=prepared.duration_s,
        ),
        truth_raw=prepared.truth_raw,
        truth_cleaned=prepared.truth_cleaned,
        clean_seconds=prepared.seconds,
        eval_seconds=sum(seconds for _, seconds in evals),
    )
