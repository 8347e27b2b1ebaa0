"""The jobs of ``bt reproduce``'s conditioned protocol: crowds, cleaned, and conditioned learners.

Two stages of jobs, as the paper's protocol (:mod:`~bt_pipeline.evaluate.reproduce_jobs`)::

    stage 1, one job per (seed, set, task, crowd):
        crowd "independent" (make_d1 / make_d2) or "shared" (make_crowd_set: shared biases)
        ──clean_demos──▶ five datasets of the same demos: noisy, cleaned, best_aligned (the best
        demo's loop aligned to each demo: selection without refinement), truth_shape (each true
        loop at the canonical speed), truth_timing (the intended path at the demo's own timing)
        + each demo's preference (θ, ρ) + each demonstrator's true loop
    stage 2, one job per (prepared set, dataset, learner):
        train conditioned on (θ, ρ), roll out per demonstrator ──▶ CrowdRow (per-seed scores)

A preference the file does not state is the cleaner's estimate (``preference_estimated``). The
verdict per cell is made over seeds (:mod:`~bt_pipeline.evaluate.crowd_report`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.data.demo import Demo, demos_from_recording
from bt_pipeline.data.records import DemoRecord, FloatArray
from bt_pipeline.data.synth import SynthSet, make_demo_set
from bt_pipeline.data.synth_crowd import make_crowd_set
from bt_pipeline.data.tasks import GuidedTask
from bt_pipeline.evaluate.conditioned import (
    TAUS_MM,
    DemonstratorLoop,
    evaluate_conditioned,
    loops_by_demonstrator,
)
from bt_pipeline.evaluate.distance import distance_to_truth
from bt_pipeline.evaluate.learners import LearnerName
from bt_pipeline.evaluate.reproduce_jobs import SetName, truth_demos
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.execute import ExecutorConfig, run_jobs

Crowd = Literal["independent", "shared"]
"""How the naive demos' defects are drawn: each its own (bt synth's default), or shared biases
(:mod:`bt_pipeline.data.synth_crowd`)."""
CROWDS: tuple[Crowd, ...] = ("independent", "shared")
CrowdDataset = Literal["noisy", "cleaned", "best_aligned", "truth_shape", "truth_timing"]
CROWD_DATASETS: tuple[CrowdDataset, ...] = (
    "noisy",
    "cleaned",
    "best_aligned",
    "truth_shape",
    "truth_timing",
)
"""noisy, cleaned; best_aligned: the best demo's loop turned, scaled and timed to each demo
(Stage 1's x_i^aligned: what selection buys without the refinement); the truth, shape-only and
shape-plus-timing."""
SIZES: dict[SetName, int] = {"D1": 4, "D2": 20}


@dataclass(frozen=True)
class CrowdSettings:
    """What the conditioned protocol of one ``bt reproduce`` run covers."""

    seeds: int = 10
    """Seeds 0 .. seeds - 1 (the verdicts are paired over them: at least 2, 10 for power)."""
    crowds: tuple[Crowd, ...] = CROWDS
    sets: tuple[SetName, ...] = ("D1",)
    per_demonstrator: int = 12
    """Rollouts per demonstrator and trained learner."""
    experts: int = 1
    """Expert-like demos in a shared-bias crowd."""
    quick_learners: bool = True
    """Train the learners' quick presets in the full run too: conditioned on the four D1
    demonstrators they draw each one's perfect loop within 2 mm (tests/test_oracle.py),
    and the 1,200 trainings of 10 seeds x 2 crowds x 3 tasks x 5 datasets x 4 learners then take
    minutes, not hours."""

    def __post_init__(self) -> None:
        if self.seeds < 1 or self.per_demonstrator < 1:
            raise ConfigError(
                f"the conditioned protocol needs ≥ 1 seed and ≥ 1 rollout per demonstrator; got "
                f"{self.seeds} and {self.per_demonstrator}"
            )
        for crowd in self.crowds:
            if crowd not in CROWDS:
                raise ConfigError(f"unknown crowd {crowd!r}; valid: {', '.join(CROWDS)}")


@dataclass(frozen=True, eq=False)
class PreparedCrowd:
    """One (seed, set, task, crowd), generated and cleaned, with its five datasets."""

    seed: int
    set_name: SetName
    task: GuidedTask
    crowd: Crowd
    positions: dict[CrowdDataset, FloatArray]
    """Training demos of each dataset, shape (M, N, 2) [m]."""
    preferences: FloatArray
    """Each demo's (θ [deg], ρ), shape (M, 2): stated, or the cleaner's estimate."""
    demonstrators: tuple[str, ...]
    loops: tuple[DemonstratorLoop, ...]
    """Each demonstrator's true loop and preference."""
    truth_raw_mm: float
    """Mean phase-free distance of the noisy demos to their true loops [mm]."""
    truth_cleaned_mm: float
    """The same for the cleaned demos [mm]."""
    seconds: float


def make_set(
    set_name: SetName, task: GuidedTask, crowd: Crowd, seed: int, experts: int = 1
) -> SynthSet:
    """The synthetic set of one (set, task, crowd, seed)."""
    if crowd == "shared":
        return make_crowd_set(task, SIZES[set_name], seed, experts=experts)
    return make_demo_set(task, SIZES[set_name], seed)


PrepareJob = tuple[int, SetName, GuidedTask, Crowd, CrowdSettings, int | None]
"""(seed, set, task, crowd, settings, the cleaner's epochs): one stage-1 job."""


def prepare_crowd(job: PrepareJob) -> PreparedCrowd:
    """Stage 1: generate and clean one (seed, set, task, crowd) (module doc)."""
    seed, set_name, task, crowd, settings, clean_epochs = job
    start = time.perf_counter()
    synth = make_set(set_name, task, crowd, seed, settings.experts)
    demos = demos_from_recording(synth.recording)
    options = CleanOptions(seed=seed, epochs=clean_epochs, write_rrd=False, progress=False)
    result = clean_demos(demos, options)
    cleaned = [d.with_positions(result.positions[i]) for i, d in enumerate(demos)]
    truths = [d.truth for d in synth.demos]
    records = list(synth.recording.demos.values())
    datasets: dict[CrowdDataset, Sequence[Demo]] = {
        "noisy": demos,
        "cleaned": cleaned,
        "best_aligned": [d.with_positions(result.stage1.aligned[i]) for i, d in enumerate(demos)],
        "truth_shape": truth_demos(demos, truths),
        "truth_timing": timed_truth(demos, records),
    }
    estimates = result.preferences
    preferences = np.array(
        [
            [d.theta_deg, d.rho]
            if d.theta_deg is not None and d.rho is not None
            else [estimates[i].theta_deg, estimates[i].rho]
            for i, d in enumerate(demos)
        ],
        dtype=np.float64,
    )
    names = tuple(d.demonstrator for d in demos)
    # A demonstrator is rolled out with the preference its demos were trained with.
    loops, _ = loops_by_demonstrator(names, preferences, truths)

    def mean_gap(ds: Sequence[Demo]) -> float:
        gaps = [distance_to_truth(d.positions, t) for d, t in zip(ds, truths, strict=True)]
        return 1e3 * float(np.mean(gaps))

    return PreparedCrowd(
        seed=seed,
        set_name=set_name,
        task=task,
        crowd=crowd,
        positions={k: np.stack([d.positions for d in ds]) for k, ds in datasets.items()},
        preferences=preferences,
        demonstrators=names,
        loops=tuple(loops),
        truth_raw_mm=mean_gap(demos),
        truth_cleaned_mm=mean_gap(cleaned),
        seconds=time.perf_counter() - start,
    )


def timed_truth(demos: Sequence[Demo], records: Sequence[DemoRecord]) -> list[Demo]:
    """Each demo's intended path at its own timing (its ``truth_uv`` attr), N samples uniform
    in time, as the demo's own positions are."""
    out = []
    for demo, record in zip(demos, records, strict=True):
        uv = np.asarray(record.attrs["truth_uv"], dtype=np.float64)
        t = np.asarray(record.timestamps, dtype=np.float64)
        s = np.linspace(t[0], t[-1], demo.n_samples)
        path = np.stack([np.interp(s, t, uv[:, j]) for j in range(2)], axis=1)
        out.append(demo.with_positions(path))
    return out


@dataclass(frozen=True)
class CrowdRow:
    """One learner on one dataset of one prepared set: its per-seed scores."""

    seed: int
    set_name: SetName
    task: GuidedTask
    crowd: Crowd
    learner: LearnerName
    dataset: CrowdDataset
    success: tuple[float, ...]
    """Success rate at each τ of :data:`~bt_pipeline.evaluate.conditioned.TAUS_MM`."""
    robust: tuple[float, ...]
    """The same from starts 1-3 cm off the true loops."""
    shape_mm: float
    """Mean Chamfer distance of the rollouts to their demonstrator's true loop [mm]."""
    shape_by_demonstrator_mm: tuple[float, ...]
    """The same per demonstrator [mm]."""
    successes: tuple[int, ...]
    """Successful rollouts at each τ (for Wilson intervals over the rollouts)."""
    rollouts: int
    train_seconds: float

    def success_at(self, tau_mm: float) -> float:
        """The success rate at τ (one of TAUS_MM)."""
        return self.success[TAUS_MM.index(tau_mm)]


CrowdJob = tuple[PreparedCrowd, CrowdDataset, LearnerName, bool, int, int | None]
"""(prepared set, dataset, learner, quick, rollouts per demonstrator, steps)."""


def run_crowd_learner(job: CrowdJob) -> CrowdRow:
    """Stage 2: one conditioned learner on one dataset (runs in a worker when workers > 1)."""
    prepared, dataset, learner, quick, per_demonstrator, steps = job
    e = evaluate_conditioned(
        learner,
        dataset,
        prepared.positions[dataset],
        prepared.preferences,
        prepared.loops,
        seed=prepared.seed,
        per_demonstrator=per_demonstrator,
        quick=quick,
        steps=steps,
        demonstrators=prepared.demonstrators,
    )
    ok = e.scores.success
    return CrowdRow(
        seed=prepared.seed,
        set_name=prepared.set_name,
        task=prepared.task,
        crowd=prepared.crowd,
        learner=learner,
        dataset=dataset,
        success=tuple(float(v) for v in ok.mean(axis=0)),
        robust=tuple(float(v) for v in e.robust.success.mean(axis=0)),
        shape_mm=float(np.mean(e.scores.shape_mm)),
        shape_by_demonstrator_mm=tuple(
            float(v) for v in e.scores.by_demonstrator(e.scores.shape_mm)
        ),
        successes=tuple(int(v) for v in ok.sum(axis=0)),
        rollouts=int(ok.shape[0]),
        train_seconds=e.train_seconds,
    )


@dataclass(frozen=True, eq=False)
class CrowdRun:
    """Every row of the conditioned protocol of one run."""

    settings: CrowdSettings
    learners: tuple[LearnerName, ...]
    prepared: tuple[PreparedCrowd, ...]
    rows: tuple[CrowdRow, ...]
    seconds: float


def run_crowd(
    settings: CrowdSettings,
    *,
    tasks: Sequence[GuidedTask],
    learners: Sequence[LearnerName],
    quick: bool,
    executor: ExecutorConfig,
    steps: int | None = None,
    clean_epochs: int | None = None,
    progress: bool = True,
) -> CrowdRun:
    """Both stages of the conditioned protocol on `executor` (module doc); results depend only
    on the arguments, not on the executor or the order the jobs run in."""
    start = time.perf_counter()
    keys: list[PrepareJob] = [
        (s, n, t, c, settings, clean_epochs)
        for n in settings.sets
        for t in tasks
        for c in settings.crowds
        for s in range(settings.seeds)
    ]
    prepared = run_jobs(
        prepare_crowd,
        keys,
        executor,
        desc="reproduce: clean crowds",
        progress=progress,
        label=lambda job: f"{job[1]} {job[2]} {job[3]} seed {job[0]}",
    )
    jobs: list[CrowdJob] = [
        (p, dataset, learner, quick, settings.per_demonstrator, steps)
        for p in prepared
        for dataset in CROWD_DATASETS
        for learner in learners
    ]
    rows = run_jobs(
        run_crowd_learner,
        jobs,
        executor,
        desc="reproduce: conditioned learners",
        progress=progress,
        label=lambda job: f"{job[0].set_name} {job[0].task} {job[0].crowd} {job[2]} {job[1]}",
    )
    return CrowdRun(
        settings, tuple(learners), tuple(prepared), tuple(rows), time.perf_counter() - start
    )
