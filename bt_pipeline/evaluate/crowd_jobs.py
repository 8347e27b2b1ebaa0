"""The jobs of ``bt reproduce``'s conditioned protocol: crowds, cleaned, and conditioned learners.

Two stages of jobs, as the paper's protocol (:mod:`~bt_pipeline.evaluate.reproduce_jobs`)::

    stage 1, one job per (seed, set, task, crowd): generate and clean
        (:func:`~bt_pipeline.evaluate.crowd_sets.prepare_crowd`) ──▶ PreparedCrowd
    stage 2, one job per (prepared set, dataset, learner, approach):
        train (conditioned on (θ, ρ); held out; or per demonstrator), roll out per demonstrator
        ──▶ CrowdRow (one seed's scores)

    main crowds (independent, shared):   every dataset x every learner, conditioned
    shared crowd:                        held out (every learner), per demonstrator (some)
    sweeps (no_expert, three_experts,    noisy / cleaned / truth_shape x the sweep learners
            same_preference, random_loop)

The verdict per cell is made over seeds (:mod:`~bt_pipeline.evaluate.crowd_report`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.tasks import GuidedTask
from bt_pipeline.evaluate.conditioned import TAUS_MM, Approach, evaluate_conditioned
from bt_pipeline.evaluate.crowd_sets import (
    CROWD_DATASETS,
    GATED_DATASETS,
    Crowd,
    CrowdDataset,
    CrowdSettings,
    PreparedCrowd,
    PrepareJob,
    prepare_crowd,
)
from bt_pipeline.evaluate.learners import LearnerName
from bt_pipeline.evaluate.reproduce_jobs import SetName
from bt_pipeline.execute import ExecutorConfig, run_jobs


@dataclass(frozen=True)
class CrowdRow:
    """One learner on one dataset of one prepared set: its per-seed scores."""

    seed: int
    set_name: SetName
    task: GuidedTask
    crowd: Crowd
    learner: LearnerName
    dataset: CrowdDataset
    approach: Approach
    success: tuple[float, ...]
    """Success rate at each τ of :data:`~bt_pipeline.evaluate.conditioned.TAUS_MM`."""
    robust: tuple[float, ...]
    """The same from starts 1-3 cm off the true loops."""
    shape_mm: float
    """Mean Chamfer distance of the rollouts to their demonstrator's true loop [mm]."""
    shape_by_demonstrator_mm: tuple[float, ...]
    """The same per demonstrator [mm] (NaN for one not rolled out)."""
    l4_mm: float
    """Mean L4 (Eq. 9) of the rollouts against their demonstrator's true loop [mm]."""
    success_by_demonstrator: tuple[float, ...]
    """Success at τ = 10 mm of each demonstrator's rollouts (NaN for one not rolled out)."""
    successes: tuple[int, ...]
    """Successful rollouts at each τ (for Wilson intervals over the rollouts)."""
    rollouts: int
    train_seconds: float
    examples: FloatArray | None
    """Seed 0's first rollout per demonstrator, (D, n, 2) [m] (for the figures), else None."""

    def success_at(self, tau_mm: float) -> float:
        """The success rate at τ (one of TAUS_MM)."""
        return self.success[TAUS_MM.index(tau_mm)]


CrowdJob = tuple[PreparedCrowd, CrowdDataset, LearnerName, Approach, bool, int, int | None]
"""(prepared set, dataset, learner, approach, quick, rollouts per demonstrator, steps)."""


def run_crowd_learner(job: CrowdJob) -> CrowdRow:
    """Stage 2: one learner on one dataset (runs in a worker when workers > 1)."""
    prepared, dataset, learner, approach, quick, per_demonstrator, steps = job
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
        approach=approach,
        held_out=prepared.seed % len(prepared.loops),
    )
    ok = e.scores.success
    return CrowdRow(
        seed=prepared.seed,
        set_name=prepared.set_name,
        task=prepared.task,
        crowd=prepared.crowd,
        learner=learner,
        dataset=dataset,
        approach=approach,
        success=tuple(float(v) for v in ok.mean(axis=0)),
        robust=tuple(float(v) for v in e.robust.success.mean(axis=0)),
        shape_mm=float(np.mean(e.scores.shape_mm)),
        shape_by_demonstrator_mm=tuple(
            float(v) for v in e.scores.by_demonstrator(e.scores.shape_mm)
        ),
        l4_mm=float(np.mean(e.scores.l4_mm)),
        success_by_demonstrator=tuple(
            float(v) for v in e.scores.by_demonstrator(ok[:, TAUS_MM.index(10.0)])
        ),
        successes=tuple(int(v) for v in ok.sum(axis=0)),
        rollouts=int(ok.shape[0]),
        train_seconds=e.train_seconds,
        examples=e.examples if prepared.seed == 0 else None,
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
        for c in dict.fromkeys((*settings.crowds, *settings.sweeps))
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
        (p, dataset, learner, approach, quick, settings.per_demonstrator, steps)
        for p in prepared
        for dataset, learner, approach in stage2_units(settings, p.crowd, learners)
    ]
    rows = run_jobs(
        run_crowd_learner,
        jobs,
        executor,
        desc="reproduce: conditioned learners",
        progress=progress,
        label=lambda j: f"{j[0].set_name} {j[0].task} {j[0].crowd} {j[2]} {j[1]} {j[3]}",
    )
    return CrowdRun(
        settings, tuple(learners), tuple(prepared), tuple(rows), time.perf_counter() - start
    )


_Unit = tuple[CrowdDataset, LearnerName, Approach]


def stage2_units(
    settings: CrowdSettings, crowd: Crowd, learners: Sequence[LearnerName]
) -> list[tuple[CrowdDataset, LearnerName, Approach]]:
    """The (dataset, learner, approach) trained on one prepared set of `crowd` (module doc)."""

    def grid(
        datasets: Sequence[CrowdDataset], chosen: Sequence[LearnerName], a: Approach
    ) -> list[_Unit]:
        return [(d, lr, a) for d in datasets for lr in chosen]

    units: list[_Unit] = []
    if crowd in settings.crowds:
        units += grid(CROWD_DATASETS, learners, "conditioned")
    if crowd == "shared" and crowd in settings.crowds:
        if settings.held_out:
            units += grid(GATED_DATASETS, learners, "held_out")
        chosen: list[LearnerName] = [
            lr for lr in learners if lr in settings.per_demonstrator_learners
        ]
        units += grid(GATED_DATASETS, chosen, "per_demonstrator")
    if crowd in settings.sweeps and crowd not in settings.crowds:
        chosen: list[LearnerName] = [lr for lr in learners if lr in settings.sweep_learners]
        units += grid(GATED_DATASETS, chosen, "conditioned")
    return units
