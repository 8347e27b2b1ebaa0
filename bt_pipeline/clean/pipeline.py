"""The two-stage cleaner end to end (paper Algorithm 1), as a library call.

Data flow for one task (pure core, :func:`clean_demos`)::

    demos (M, N, 2) ──selection (segment, θ/ρ, Eqs. 3-8, shape gate)──> spans, best demo
        └─ Stage 1 (Sec. III-B): DMP x^d ─> V_E, x^g ─> x_i^aligned, L4 (Eq. 9)
        └─ Stage 2 (Sec. III-C): LSTM x_i ─> x̂_i, adaptive β from R̄ (Eq. 11)
        └─ metrics before / after (true KSG, L1-L4, Stage 2's objective) and Ũ: raw and
           cleaned spans read as the ranking reads them, against the raw set's normaliser
           (the one Ũ: :mod:`bt_pipeline.clean.cleaned_utility`)

I/O at the edges (:mod:`bt_pipeline.clean.driver`): read recordings, group by task, clean each task
(in parallel with ``workers``), stage ``<task>.cleaned.hdf5`` and ``<task>.rrd`` as each task
finishes and publish them only once every task has succeeded, so an error leaves no partial
output. With ``chunk_executor`` set, a task of more than K demos sends its per-demo steps and
Stage 2 chunks out as jobs (:mod:`bt_pipeline.clean.fan_out`), with identical results.
Selection is :mod:`bt_pipeline.clean.selection`, shared with ``bt score``.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from bt_pipeline.clean.cleaned_utility import cleaned_utilities, moved_from_raw, on_raw_times
from bt_pipeline.clean.fan_out import metrics_step, per_demo, retime_step
from bt_pipeline.clean.guide_fit import PreferenceRange
from bt_pipeline.clean.loop_learn import TaskLoop
from bt_pipeline.clean.periodic import (
    PreferenceEstimate,
    fit_quality,
    phase_loop,
    smooth_residual,
)
from bt_pipeline.clean.pivot import pivoted, read_pivot
from bt_pipeline.clean.segment import Segment
from bt_pipeline.clean.selection import select_demos
from bt_pipeline.clean.stage1.extract import Stage1Result, run_stage1
from bt_pipeline.clean.stage2.chunked import DEFAULT_CHUNK_SIZE, refine_in_chunks
from bt_pipeline.clean.stage2.config import EpochStats, RefineConfig, RefineResult, Variant
from bt_pipeline.clean.stage2.scales import refine_normaliser
from bt_pipeline.data.demo import DEFAULT_SAMPLES, Demo
from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.tasks import Task
from bt_pipeline.exceptions import ConfigError, DemoError
from bt_pipeline.execute import ExecutorConfig
from bt_pipeline.score.utility import Normaliser, ScoreConfig, TaskScores, normalised_utility

MIN_EXTENT_M = 1e-3
"""A demo whose bounding box is smaller than this in both directions does not move [m]."""


@dataclass(frozen=True)
class CleanOptions:
    """Settings of a cleaning run."""

    seed: int = 0
    """Seed of Stage 1's rollouts and of the network (deterministic for a seed)."""
    epochs: int | None = None
    """Most refinement epochs; None takes the variant's own."""
    variant: Variant = "default"
    """``"default"`` (bt's design) or ``"paper"`` (the paper's configuration)."""
    write_rrd: bool = True
    """Also write a Rerun recording per task."""
    workers: int = 1
    """Tasks cleaned in parallel (processes)."""
    strict: bool = False
    """Stop at the first unreadable file instead of skipping it with a warning."""
    n_samples: int = DEFAULT_SAMPLES
    """N, samples per demo."""
    progress: bool = True
    """Show progress bars on stderr."""
    score: ScoreConfig = field(default_factory=ScoreConfig)
    """Selection-stage scoring settings."""
    preference_range: PreferenceRange = field(default_factory=PreferenceRange)
    """Allowed θ/ρ when they are estimated (default θ within ±45°, ρ within 0.5-2)."""
    chunk_size: int = DEFAULT_CHUNK_SIZE
    """K, most demos refined by one network: Stage 2 of a larger task runs in chunks sharing the
    task's Stage 1 and frozen normalisers (bt_pipeline.clean.stage2.chunked, docs/scale.md)."""
    chunk_executor: ExecutorConfig | None = None
    """Where a task's chunks run when it has several; None: one after another in this process."""

    def __post_init__(self) -> None:
        if self.chunk_size < 1:
            raise ConfigError(f"--chunk-size must be ≥ 1; got {self.chunk_size}")
        if self.workers < 1:
            raise ConfigError(f"--workers must be ≥ 1; got {self.workers}")
        if self.epochs is not None and self.epochs < 1:
            raise ConfigError(f"--epochs must be ≥ 1; got {self.epochs}")
        if self.seed < 0:
            raise ConfigError(f"--seed must be ≥ 0; got {self.seed}")
        if self.n_samples < 16:
            raise ConfigError(f"samples per demo must be ≥ 16; got {self.n_samples}")

    def refine_config(self) -> RefineConfig:
        """The Stage 2 settings these options ask for."""
        return RefineConfig(variant=self.variant, epochs=self.epochs, seed=self.seed)


@dataclass(frozen=True)
class DemoMetrics:
    """The scores of one demo, raw or cleaned."""

    mutual_information: float
    """I(S; A) by KSG-1 [nats]."""
    symmetry: float
    """L1 [m] (Eq. 4)."""
    closure: float
    """L2 [m] (Eq. 5)."""
    smoothness: float
    """L3 (Eq. 6)."""
    shape: float
    """L4 [m] (Eq. 9): mean distance from the demo's aligned reference x_i^aligned. A cleaned
    demo of the default variant lies between its raw samples and that reference (a gain per
    sample), so its L4 is what is left of the way to it: 0 when cleaning followed it fully."""
    objective: float
    """Stage 2's objective term Ũ_i (Eq. 8 with L1-L4 on the N samples, Stage 2's frozen
    normalisers and the demo's final β): what refinement maximises."""
    utility: float
    """Ũ (Eq. 8) as ``bt score`` reads it: the span's ranking metrics against the raw set's
    normaliser (:func:`bt_pipeline.score.utility.utilities_against`), the same number for a
    raw demo as ``bt score``, the app's table, the Rerun summaries and ``bt view`` show."""

    def as_array(self) -> FloatArray:
        """(MI, L1, L2, L3, L4), the columns of the refinement normaliser."""
        return np.array(
            [self.mutual_information, self.symmetry, self.closure, self.smoothness, self.shape]
        )


@dataclass(frozen=True)
class TaskCleanResult:
    """Everything the cleaner computed for one task (the pure core's output)."""

    task: Task
    """The task."""
    demos: tuple[Demo, ...]
    """The kept periodic span of each raw demo, N samples uniform in time, in input order
    (``raw_samples()`` gives the raw samples and times inside the span)."""
    scores: TaskScores
    """Selection-stage scores of the raw demos."""
    stage1: Stage1Result
    """Canonical motion, value map and aligned references."""
    refine: RefineResult
    """Stage 2 output and its per-epoch history."""
    raw: tuple[DemoMetrics, ...]
    """Metrics of each raw demo."""
    cleaned: tuple[DemoMetrics, ...]
    """Metrics of each cleaned demo."""
    seconds: dict[str, float]
    """Wall time per stage: ``score``, ``stage1``, ``stage2``, ``metrics`` [s]."""
    notes: tuple[str, ...] = ()
    """Things a user should know (estimated θ/ρ, a one-demo task, ...)."""
    segments: tuple[Segment, ...] = ()
    """The kept periodic span of each raw demo (``demos`` hold these spans)."""
    preferences: tuple[PreferenceEstimate, ...] = ()
    """θ/ρ used for each demo, with whether they were estimated and how confidently."""
    loop: TaskLoop | None = None
    """The loop the demos were measured against (the task's guide or learned from them)."""
    best_reason: str = ""
    """Why the best demo is the best when it is not the highest Ũ (the shape gate's line)."""

    @property
    def positions(self) -> FloatArray:
        """The cleaned demos x̂_i, shape (M, N, 2), in task coordinates [m]."""
        return self.refine.refined

    @property
    def best_index(self) -> int:
        """Index of the best raw demo."""
        return self.scores.best_index

    def on_raw_times(self, i: int) -> tuple[FloatArray, FloatArray]:
        """Demo i's cleaned span at the raw sample times inside it: (times (K,) [s], (K, 2) [m]).

        The best demo, passed through unrefined (the default variant), is its raw samples as
        they are: read back from the N-sample grid, a long span lost up to 0.1 mm to chords
        (an expert-like demo 0.2 mm from its truth came back 0.3 mm away).
        """
        passed = i == self.best_index and not self.refine.settings.refine_best
        return on_raw_times(self.demos[i], self.positions[i], passed)

    def moved(self, i: int) -> tuple[float, float]:
        """How far cleaning moved demo i from its raw samples: (mean, max) distance [m] between
        each raw sample of its span and the cleaned demo at the same time."""
        return moved_from_raw(self.demos[i], self.on_raw_times(i)[1])


def check_usable(demos: Sequence[Demo]) -> None:
    """Raise a DemoError naming the first demo that cannot be cleaned (it does not move)."""
    for demo in demos:
        extent = np.ptp(demo.positions, axis=0)
        if float(np.max(extent)) < MIN_EXTENT_M:
            raise DemoError(
                f"{demo.label} does not move (extent {1e3 * float(np.max(extent)):.3f} mm); a "
                f"demo must span at least {1e3 * MIN_EXTENT_M:.0f} mm to be cleaned"
            )


def _with_utility(
    values: FloatArray,
    normaliser: Normaliser,
    weights: Sequence[float],
    betas: FloatArray,
    utility: FloatArray,
) -> tuple[DemoMetrics, ...]:
    """Metric records from raw values, shape (M, 5), with Stage 2's objective (Eq. 8 with its
    normaliser and per-demo β) and each demo's Ũ, shape (M,)."""
    normalised = normaliser.normalise(values, clip=True)
    objective = normalised_utility(normalised[:, 0], normalised[:, 1:], weights, betas)
    return tuple(
        DemoMetrics(*(float(v) for v in row), objective=float(o), utility=float(u))
        for row, o, u in zip(values, objective, utility, strict=True)
    )


def clean_demos(
    demos: Sequence[Demo],
    options: CleanOptions | None = None,
    on_epoch: Callable[[EpochStats], None] | None = None,
) -> TaskCleanResult:
    """Clean the demos of one task (paper Algorithm 1).

    Args:
        demos: M ≥ 1 demos of one task, N samples each (a single demo is cleaned against itself).
        options: Settings; defaults when None.
        on_epoch: Called after every refinement epoch (progress bars, live logging).

    Returns:
        The cleaned demos with every intermediate result and the metrics before and after.

    Raises:
        DemoError: No demos, demos of several tasks or lengths, or a degenerate demo (named).
    """
    options = options or CleanOptions()
    if not demos:
        raise DemoError("no demos to clean")
    tasks = {demo.task for demo in demos}
    if len(tasks) != 1:
        raise DemoError(f"clean one task at a time; got demos of {sorted(tasks)}")
    lengths = {demo.n_samples for demo in demos}
    if len(lengths) != 1:
        raise DemoError(f"every demo must have the same number of samples; got {sorted(lengths)}")
    check_usable(demos)
    notes: list[str] = []
    if len(demos) == 1:
        notes.append(f"{demos[0].label} is the only demo: it is cleaned against itself")

    fan_out = options.chunk_executor if len(demos) > options.chunk_size else None
    k_max, task_label = options.chunk_size, str(demos[0].task)
    selection = select_demos(
        demos,
        options.score,
        options.preference_range,
        executor=fan_out,
        chunk_size=k_max,
    )
    demos = list(selection.demos)
    segments, preferences, scores = selection.segments, selection.preferences, selection.scores
    notes += selection.notes
    seconds = dict(selection.seconds)
    # Stage 2's normaliser (Eq. 7) reads L1-L3 on the N-sample demos it refines, as Stage 2
    # computes them; the ranking reads them per loop, along the path and at ρ = 1
    # (bt_pipeline.clean.selection).
    frozen = Normaliser.from_raw_metrics(selection.plain, options.score.delta)

    start = time.perf_counter()
    best = scores.best_index
    stage1_demos = list(demos)
    stage1_demos[best], guide_filled = phase_loop(demos[best], segments[best])
    if guide_filled:
        notes.append(
            f"{demos[best].label} (the best demo) does not cover a whole loop: the missing "
            f"phases of the canonical motion come from the task's {selection.loop.source} loop"
        )
    stage1 = run_stage1(stage1_demos, best, seed=options.seed, best_cycles=1.0)
    if preferences[best].estimated and selection.loop.source != "guide":
        # θ/ρ hidden against a learned loop: the box centre's frame is only the learned loop's
        # (a guide's is its own, centred where bt draws it); where do the demos' loops turn?
        centre = "the best demo's box centre"
        if selection.loop.loop.placed:
            # The best demo's loop kept where it was drawn (clean/best_loop.py): the plane's
            # origin is the point the demos turn it about, as a guide's centre is.
            stage1, centre = pivoted(stage1, np.zeros(2)), "the task plane's origin"
        pivot = read_pivot(
            [s.guide for s in segments],
            [fit_quality(s) for s in segments],
            best,
            stage1.centre,
        )
        if pivot.read:
            stage1 = pivoted(stage1, pivot.point)
            notes.append(
                f"the {task_label} demos' fits turn and scale their loops about a point "
                f"{1e3 * pivot.offset_m:.1f} mm from {centre} (θ/ρ hidden): "
                "their references turn about it"
            )
    # Every reference sits at the best demo's centre c (or the pivot), as in the paper (Sec.
    # III-B): a demo's offset from c is not read as its preference (docs/refinement.md step 5).
    aligned = np.stack(
        per_demo(
            retime_step,
            list(zip(demos, preferences, strict=True)),
            (stage1.global_shape, stage1.centre),
            executor=fan_out,
            chunk_size=k_max,
            label=f"align {task_label}",
        )
    )
    positions = np.stack([demo.positions for demo in demos])
    stage1 = dataclasses.replace(
        stage1,
        aligned=aligned,
        shape_losses=np.mean(np.linalg.norm(aligned - positions, axis=2), axis=1),
        estimated=np.array([p.estimated for p in preferences]),
        symmetry_axis_deg=selection.loop.symmetry_axis[0],
    )
    seconds["stage1"] = time.perf_counter() - start

    start = time.perf_counter()
    normaliser = refine_normaliser(frozen, stage1.shape_losses)
    refined = refine_in_chunks(  # Stage 1 is shared by chunks of at most K demos (issue 14).
        positions,
        stage1,
        normaliser=normaliser,
        config=options.refine_config(),
        chunk_size=options.chunk_size,
        executor=options.chunk_executor,
        on_epoch=on_epoch,
        progress=options.progress,
        label=str(demos[0].task),
    )
    if options.variant == "default":
        smoothed = smooth_residual(refined.refined, stage1.aligned, demos)
        if not refined.settings.refine_best:
            smoothed[best] = refined.refined[best]  # Passed through as it is.
        refined = dataclasses.replace(refined, refined=smoothed)
    seconds["stage2"] = time.perf_counter() - start

    start = time.perf_counter()
    l1_thetas = stage1.l1_thetas()
    metrics = per_demo(
        metrics_step,
        [
            (positions[i], refined.refined[i], stage1.aligned[i], float(l1_thetas[i]))
            for i in range(len(demos))
        ],
        (options.score.k, options.score.alphas),
        executor=fan_out,
        chunk_size=k_max,
        label=f"metrics {task_label}",
    )
    raw_values = np.array([raw for raw, _ in metrics])
    cleaned_values = np.array([cleaned for _, cleaned in metrics])
    weights = refined.settings.weights
    # The one Ũ (bt score's): each cleaned span read as the ranking reads the raw ones, against
    # the raw set's normaliser; the raw demos keep the selection's Ũ.
    utility_cleaned, lowered = cleaned_utilities(
        demos,
        refined.refined,
        None if refined.settings.refine_best else best,
        segments,
        scores,
        options.score,
        selection.loop.symmetry_axis[0],
    )
    utility_raw = np.array([s.utility for s in scores.scores])
    raw = _with_utility(raw_values, normaliser, weights, refined.betas, utility_raw)
    cleaned = _with_utility(cleaned_values, normaliser, weights, refined.betas, utility_cleaned)
    notes += lowered
    seconds["metrics"] = time.perf_counter() - start
    return TaskCleanResult(
        task=demos[0].task,
        demos=tuple(demos),
        scores=scores,
        stage1=stage1,
        refine=refined,
        raw=raw,
        cleaned=cleaned,
        seconds=seconds,
        notes=tuple(notes),
        segments=segments,
        preferences=preferences,
        loop=selection.loop,
        best_reason=selection.best_reason,
    )
