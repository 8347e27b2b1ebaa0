"""The crowds of ``bt reproduce``'s conditioned protocol, generated and cleaned (its stage 1).

One job per (seed, set, task, crowd)::

    crowd (see :data:`Crowd`) ──make_set──▶ a synthetic set with its ground truth
        ──clean_demos──▶ datasets of the same demos: noisy, cleaned, best_aligned (the best demo's
        loop aligned to each demo: selection without refinement), truth_shape (each true loop at
        the canonical speed), truth_timing (the intended path at the demo's own timing)
        + each demo's preference (θ, ρ) + each demonstrator's true loop

A preference the file does not state is the cleaner's estimate (``preference_estimated``).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.spatial import KDTree

from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.data.demo import Demo, demos_from_recording
from bt_pipeline.data.random_loops import draw_loop
from bt_pipeline.data.records import DemoRecord, FloatArray
from bt_pipeline.data.synth import SynthSet, make_demo_set
from bt_pipeline.data.synth_crowd import make_crowd_set
from bt_pipeline.data.tasks import TASKS, GuidedTask
from bt_pipeline.evaluate.conditioned import DemonstratorLoop, loops_by_demonstrator
from bt_pipeline.evaluate.distance import distance_to_truth
from bt_pipeline.evaluate.learners import LearnerName
from bt_pipeline.evaluate.reproduce_jobs import SetName, truth_demos
from bt_pipeline.exceptions import ConfigError

Crowd = Literal[
    "independent", "shared", "no_expert", "three_experts", "same_preference", "random_loop"
]
"""How a crowd's demos are drawn:

- ``independent``: every naive demo's defects its own (bt synth's default);
- ``shared``: the naive demos share biases (:mod:`bt_pipeline.data.synth_crowd`), one
  expert-like demo (the settings' ``experts``);
- ``no_expert`` / ``three_experts``: the same with 0 or 3 expert-like demos of 4 (the sweep of
  the expert share);
- ``same_preference``: shared biases, every demonstrator at θ = 0, ρ = 1 (the ablation where
  the paper's pooled protocol is legitimate);
- ``random_loop``: shared biases on a loop drawn at random per (seed, task)
  (:func:`bt_pipeline.data.random_loops.draw_loop`), not the task's guide.
"""
CROWDS: tuple[Crowd, ...] = (
    "independent",
    "shared",
    "no_expert",
    "three_experts",
    "same_preference",
    "random_loop",
)
MAIN_CROWDS: tuple[Crowd, ...] = ("independent", "shared")
"""The crowds of the report's main table (every dataset)."""
SWEEPS: tuple[Crowd, ...] = ("no_expert", "three_experts", "same_preference", "random_loop")
"""The sweep and ablation crowds (datasets noisy, cleaned and truth_shape)."""
CrowdDataset = Literal["noisy", "cleaned", "best_aligned", "truth_shape", "truth_timing"]
CROWD_DATASETS: tuple[CrowdDataset, ...] = (
    "noisy",
    "cleaned",
    "best_aligned",
    "truth_shape",
    "truth_timing",
)
"""noisy, cleaned; best_aligned: the best demo's loop turned, scaled and timed to each demo
(Stage 1's x_i^aligned: what selection buys without the refinement, the best-demo-only
baseline); the truth, shape-only and shape-plus-timing."""
GATED_DATASETS: tuple[CrowdDataset, ...] = ("noisy", "cleaned", "truth_shape")
"""What a verdict needs: the sweeps, the held-out and the per-demonstrator rows train these."""
SIZES: dict[SetName, int] = {"D1": 4, "D2": 20}
COVERAGE_M = 0.010
"""Tolerance of :attr:`PreparedCrowd.coverage` [m] (the report's τ)."""
_LOOP_STREAM = 35  # Seeds the random loops apart from the sets' own streams.


@dataclass(frozen=True)
class CrowdSettings:
    """What the conditioned protocol of one ``bt reproduce`` run covers."""

    seeds: int = 10
    """Seeds 0 .. seeds - 1 (the verdicts are paired over them: at least 2, 10 for power)."""
    crowds: tuple[Crowd, ...] = MAIN_CROWDS
    """Crowds with every dataset and learner."""
    sets: tuple[SetName, ...] = ("D1",)
    per_demonstrator: int = 12
    """Rollouts per demonstrator and trained learner."""
    experts: int = 1
    """Expert-like demos in a shared-bias crowd."""
    quick_learners: bool = True
    """Train the learners' quick presets in the full run too: conditioned on the four D1
    demonstrators they draw each one's perfect loop within 2 mm
    (tests/pipeline/evaluate/test_oracle.py), and the thousands of trainings then take minutes,
    not hours."""
    sweeps: tuple[Crowd, ...] = SWEEPS
    """Sweep and ablation crowds, trained on :data:`GATED_DATASETS` by `sweep_learners`."""
    sweep_learners: tuple[LearnerName, ...] = ("bc", "ileed")
    held_out: bool = True
    """On the shared crowd, per seed, hold demonstrator ``seed mod D`` out of training and roll
    out for it (every learner, :data:`GATED_DATASETS`)."""
    per_demonstrator_learners: tuple[LearnerName, ...] = ("bc",)
    """On the shared crowd, these learners also trained once per demonstrator on its demos
    alone (unconditioned)."""

    def __post_init__(self) -> None:
        if self.seeds < 1 or self.per_demonstrator < 1:
            raise ConfigError(
                f"the conditioned protocol needs ≥ 1 seed and ≥ 1 rollout per demonstrator; got "
                f"{self.seeds} and {self.per_demonstrator}"
            )
        for crowd in (*self.crowds, *self.sweeps):
            if crowd not in CROWDS:
                raise ConfigError(f"unknown crowd {crowd!r}; valid: {', '.join(CROWDS)}")


@dataclass(frozen=True, eq=False)
class PreparedCrowd:
    """One (seed, set, task, crowd), generated and cleaned, with its datasets."""

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
    coverage: dict[CrowdDataset, FloatArray]
    """Each dataset's demos: the share of their true loop within 10 mm of them, shape (M,)
    (a learner trained on a demo that leaves part of its loop out has no example of that part)."""
    best: int
    """Index of the cleaner's best demo."""
    seconds: float


def make_set(
    set_name: SetName, task: GuidedTask, crowd: Crowd, seed: int, experts: int = 1
) -> SynthSet:
    """The synthetic set of one (set, task, crowd, seed) (:data:`Crowd`)."""
    size = SIZES[set_name]
    if crowd == "independent":
        return make_demo_set(task, size, seed)
    if crowd == "random_loop":
        rng = np.random.default_rng([seed, TASKS.index(task), _LOOP_STREAM])
        shape = draw_loop("random", rng)
        return make_crowd_set(task, size, seed, experts=experts, shape=shape)
    experts = {"no_expert": 0, "three_experts": min(3, size)}.get(crowd, experts)
    same = crowd == "same_preference"
    return make_crowd_set(task, size, seed, experts=experts, same_preference=same)


PrepareJob = tuple[int, SetName, GuidedTask, Crowd, CrowdSettings, int | None]
"""(seed, set, task, crowd, settings, the cleaner's epochs): one stage-1 job."""


def prepare_crowd(job: PrepareJob) -> PreparedCrowd:
    """Generate and clean one (seed, set, task, crowd) (module doc)."""
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

    def coverage(ds: Sequence[Demo]) -> FloatArray:
        return np.array(
            [
                np.mean(KDTree(d.positions).query(t)[0] <= COVERAGE_M)
                for d, t in zip(ds, truths, strict=True)
            ]
        )

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
        coverage={k: coverage(ds) for k, ds in datasets.items()},
        best=int(result.stage1.best_index),
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
