"""Selection (paper Sec. III-A) on each demo's periodic part, for ``bt clean`` and ``bt score``.

Data flow for one task::

    raw demos ──learn the task's loop (guide or learned, loop_learn)──segment──> kept spans,
    cycles, loop fits ──pool──> θ/ρ per demo (given or
    estimated) ──> span demos (N samples each) ──score (Eqs. 3-8, L1-L3 per loop, along the
    path, at ρ = 1)──> Ũ ──shape gate──> ranks and the best demo

Scoring reads the kept span, not the whole recording: a rest, an approach and a retreat are not
the task (issue 9), and the ranking reads L1-L3 per loop, along the path and at ρ = 1 so a demo's
loop count, speed profile and preference do not rank it (:func:`periodic.ranking_metrics`). The
best demo is the eligible one (it follows the task's guide about as closely as any,
:mod:`bt_pipeline.clean.shape_gate`) with the highest Ũ.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bt_pipeline.clean.best_loop import best_demo_loop
from bt_pipeline.clean.fan_out import per_demo, segment_step
from bt_pipeline.clean.guide_fit import PreferenceRange
from bt_pipeline.clean.loop_learn import TaskLoop, learn_task_loop
from bt_pipeline.clean.periodic import (
    UNCERTAIN,
    PreferenceEstimate,
    pool_preferences,
    ranking_metrics,
    span_demo,
)
from bt_pipeline.clean.segment import Segment
from bt_pipeline.clean.shape_gate import (
    eligible,
    gate_best,
    gate_reason,
    guide_misfit,
    repeat_misfit,
)
from bt_pipeline.clean.span_close import WHOLE, closed_span
from bt_pipeline.data.demo import Demo
from bt_pipeline.data.records import FloatArray
from bt_pipeline.execute import ExecutorConfig
from bt_pipeline.score.utility import (
    RawMetrics,
    ScoreConfig,
    TaskScores,
    raw_metrics,
    score_demos,
    set_utilities,
)

OFF_GUIDE_CYCLES = 0.5
"""A demo whose own loop closes has less than this many loops found on the guide: it is off it"""
OFF_GUIDE_SHARE = 0.25
"""and when this share of such demos (two at least) is, the guide is set aside."""


@dataclass(frozen=True)
class Selection:
    """What selection found for one task."""

    demos: tuple[Demo, ...]
    """The kept periodic span of each demo, N samples uniform in time, with the θ/ρ used."""
    segments: tuple[Segment, ...]
    """The kept span, cycles and guide fit of each raw demo."""
    preferences: tuple[PreferenceEstimate, ...]
    """θ/ρ of each demo: given, or estimated and pooled per demonstrator."""
    plain: tuple[RawMetrics, ...]
    """Eqs. (3)-(6) on each span demo's N samples, as Stage 2 computes them (its normaliser)."""
    scores: TaskScores
    """Ũ of each span demo (ranking metrics), with the shape gate's ranks and best demo."""
    notes: tuple[str, ...]
    """Estimated θ/ρ, a partial loop, the gate overriding Ũ."""
    seconds: dict[str, float]
    """Wall time of ``loop``, ``segment`` and ``score`` [s]."""
    loop: TaskLoop
    """The loop the demos were measured against: the task's guide or learned from them."""
    misfits: tuple[float, ...] = ()
    """The shape gate's misfit of each demo (:func:`~bt_pipeline.clean.shape_gate.guide_misfit`)."""
    whole: tuple[bool, ...] = ()
    """Whether each demo covers a whole loop (:data:`~.span_close.WHOLE`: the shape gate)."""
    repeat_misfits: tuple[float, ...] = ()
    """Each demo's distance to its own loop (:func:`~.shape_gate.repeat_misfit`; NaN: under
    two loops)."""
    best_reason: str = ""
    """Why the best demo is the best when it is not the highest Ũ
    (:func:`~bt_pipeline.clean.shape_gate.gate_reason`); empty when it is."""

    def span_json(self, i: int) -> dict[str, Any]:
        """Demo i's :func:`span_attrs` and whether its θ/ρ were estimated."""
        preference = self.preferences[i]
        return span_attrs(self.segments[i], preference) | {
            "preference_estimated": preference.estimated
        }


def select_demos(
    demos: Sequence[Demo],
    config: ScoreConfig | None = None,
    allowed: PreferenceRange | None = None,
    *,
    executor: ExecutorConfig | None = None,
    chunk_size: int = 10**9,
) -> Selection:
    """Segment, estimate θ/ρ, score and pick the best demo of one task (module doc).

    Args:
        demos: M ≥ 1 demos of one task, N samples each (their raw samples are segmented).
        config: Scoring settings; defaults when None.
        allowed: Allowed θ/ρ when estimated; defaults when None.
        executor: Where the per-demo segmentation runs in chunks of `chunk_size` (None: here).
        chunk_size: Demos per segmentation job.

    Raises:
        DemoError: A demo that does not move or has no loop (named).
    """
    config = config or ScoreConfig()
    allowed = allowed or PreferenceRange()
    start = time.perf_counter()
    task_loop = learn_task_loop(demos)
    learned = time.perf_counter() - start
    selection = _select(demos, task_loop, config, allowed, executor, chunk_size)
    off = off_guide(demos, task_loop, selection.segments)
    if off:  # The demos close loops of their own that the guide does not hold: learn theirs.
        start = time.perf_counter()
        task_loop = learn_task_loop(demos, use_guide=False, known=task_loop)
        note = (
            f"{', '.join(demos[i].label for i in off)} close loops of their own, but less than "
            f"half a loop of each lies on the {demos[0].task} guide: the guide is set aside "
            f"and their own loop, learned from {len(task_loop.used)} demos, is used"
        )
        task_loop = dataclasses.replace(task_loop, notes=(*task_loop.notes, note))
        learned += time.perf_counter() - start
        selection = _select(demos, task_loop, config, allowed, executor, chunk_size)
    best = selection.scores.best_index
    best_loop = best_demo_loop(task_loop, demos[best], selection.segments[best])
    if best_loop is not None:  # Once more against the best demo's own loop (loop_learn step 6).
        # The gate keeps the first pass's misfits: against the best demo's own loop, that demo
        # would always follow it most closely.
        again = _select(demos, best_loop, config, allowed, executor, chunk_size, selection)
        spent = {k: v + again.seconds.get(k, 0.0) for k, v in selection.seconds.items()}
        selection = dataclasses.replace(again, seconds=spent)
    best = selection.scores.best_index
    closed = closed_span(demos[best], selection.segments[best])
    if closed is not selection.segments[best]:  # Its whole loop passes through (best_loop.py).
        segments, spans = list(selection.segments), list(selection.demos)
        segments[best] = closed
        spans[best] = span_demo(
            demos[best], closed, demos[0].n_samples, selection.preferences[best]
        )
        selection = dataclasses.replace(selection, segments=tuple(segments), demos=tuple(spans))
    selection.seconds["loop"] = learned
    return selection


def off_guide(demos: Sequence[Demo], task_loop: TaskLoop, segments: Sequence[Segment]) -> list[int]:
    """The demos that show the guide is not the task's loop, or none (step 4 checked again).

    The guide is kept when some demo traces it and the demos' consensus lies near it
    (:mod:`bt_pipeline.clean.loop_learn`); a loop near the guide but not it (a figure-eight of
    unequal lobes, with 20 demos one of which happens to lie near the guide) passes that test,
    and segmentation against the guide then finds a tenth of a loop in demos that draw four
    of their own. So when a quarter or more of the demos whose path holds a loop of its own
    (two at least) have less than half a loop found on the guide, they are returned and the
    loop is learned from the demos instead; unless a demo traced the guide (within 2 %): a
    majority that shares one bias (the same wrong lobe of an eight) does not outvote it.
    """
    if task_loop.source != "guide" or task_loop.traced:
        return []  # A demo that traced the guide is not outvoted (loop_learn step 4).
    closers = [i for i, d in enumerate(demos) if task_loop.repeats.get(d.label, 0.0) >= 1.0]
    off = [i for i in closers if segments[i].cycles < OFF_GUIDE_CYCLES]
    return off if len(off) >= max(2, math.ceil(OFF_GUIDE_SHARE * len(closers))) else []


def _select(
    demos: Sequence[Demo],
    task_loop: TaskLoop,
    config: ScoreConfig,
    allowed: PreferenceRange,
    executor: ExecutorConfig | None,
    chunk_size: int,
    gate: Selection | None = None,
) -> Selection:
    """:func:`select_demos` against one loop (the shape gate reads `gate`'s misfits, whole
    loops and repeat misfits, when given, as the demos')."""
    seconds: dict[str, float] = {}
    start = time.perf_counter()
    segments = tuple(
        per_demo(
            segment_step,
            list(demos),
            (allowed, task_loop.loop, task_loop.hints()),
            executor=executor,
            chunk_size=chunk_size,
            label=f"segment {demos[0].task}",
        )
    )
    preferences = pool_preferences(demos, segments)
    spans = tuple(
        span_demo(demo, segment, demos[0].n_samples, preference)
        for demo, segment, preference in zip(demos, segments, preferences, strict=True)
    )
    seconds["segment"] = time.perf_counter() - start
    notes: list[str] = list(task_loop.notes)
    for demo, segment, preference in zip(spans, segments, preferences, strict=True):
        if preference.estimated:
            doubt = " (uncertain)" if preference.confidence < UNCERTAIN else ""
            notes.append(
                f"{demo.label}: θ/ρ missing, estimated{doubt} from the task's {task_loop.source} "
                f"loop (frame: {task_loop.frame}) and pooled "
                f"over {demo.demonstrator}'s demos as θ = {preference.theta_deg:.1f}°, "
                f"ρ = {preference.rho:.3f} (confidence {preference.confidence:.2f})"
            )
        if segment.cycles < 0.5:
            notes.append(f"{demo.label}: only {segment.cycles:.2f} of a loop was found")

    start = time.perf_counter()
    axis = task_loop.symmetry_axis[0]
    parts = [
        _ranking_inputs(d, s, p, config, axis)
        for d, s, p in zip(spans, segments, preferences, strict=True)
    ]
    plain = tuple(p for p, _ in parts)
    by_utility = score_demos(spans, config, metrics=[t.ranked for _, t in parts])
    # The best demo is taken among those that follow the guide about as closely as any: Ũ is
    # blind to a slow wobble (bt_pipeline/clean/shape_gate.py).
    if gate is not None:
        misfits, whole, repeat = list(gate.misfits), list(gate.whole), list(gate.repeat_misfits)
    else:
        misfits = [t.misfit for _, t in parts]
        whole = [
            s.cycles >= WHOLE or d.label in task_loop.own
            for d, s in zip(demos, segments, strict=True)
        ]
        repeat = [
            repeat_misfit(span, task_loop.own.get(d.label), task_loop.repeats.get(d.label, 0.0))
            for d, span in zip(demos, spans, strict=True)
        ]
    scores = gate_best(
        by_utility, eligible(np.array(misfits), whole=np.array(whole), repeat=np.array(repeat))
    )
    reason = ""
    if scores.best_index != by_utility.best_index:
        first, best = by_utility.best_index, scores.best_index
        reason = gate_reason(
            spans[first].label,
            spans[best].label,
            misfits[first],
            misfits[best],
            task_loop.source,
            whole[first] or not any(whole),
        )
        notes.append(reason)
    seconds["score"] = time.perf_counter() - start
    return Selection(
        spans,
        segments,
        preferences,
        plain,
        scores,
        tuple(notes),
        seconds,
        task_loop,
        tuple(misfits),
        tuple(whole),
        tuple(repeat),
        reason,
    )


@dataclass(frozen=True, slots=True)  # one per take in the app's library: no __dict__
class TakeScore:
    """What one demo brings to its task's ranking, from the demo alone (the app's library)."""

    ranked: RawMetrics
    """Eqs. (3)-(6) on its periodic part, per loop, along the path and at ρ = 1."""
    misfit: float
    """The shape gate's misfit (:func:`~bt_pipeline.clean.shape_gate.guide_misfit`)."""


def take_score(
    demo: Demo, config: ScoreConfig | None = None, allowed: PreferenceRange | None = None
) -> TakeScore:
    """:func:`select_demos`'s per-demo part for one demo: segmented, θ/ρ given or fitted to it
    alone (not pooled), scored on its span. :func:`rank_takes` then ranks a set of them.

    Raises:
        DemoError: The demo does not move or has no loop.
    """
    config = config or ScoreConfig()
    (segment,) = segment_step([demo], (allowed or PreferenceRange(), None, None))
    (preference,) = pool_preferences([demo], [segment])
    span = span_demo(demo, segment, demo.n_samples, preference)
    return _ranking_inputs(span, segment, preference, config)[1]


def rank_takes(
    takes: Sequence[TakeScore], config: ScoreConfig | None = None
) -> tuple[FloatArray, np.ndarray]:
    """Ũ of each take over the set (Eqs. 7-8, as :func:`select_demos` scores) and whether each
    may be the best (the shape gate's eligibility): shapes (M,), (M,)."""
    config = config or ScoreConfig()
    utility, _ = set_utilities([t.ranked for t in takes], config)
    return utility, eligible(np.array([t.misfit for t in takes]))


def _ranking_inputs(
    span: Demo,
    segment: Segment,
    preference: PreferenceEstimate,
    config: ScoreConfig,
    axis_deg: float = 0.0,
) -> tuple[RawMetrics, TakeScore]:
    """A span demo's Eqs. (3)-(6) on its N samples (Stage 2's normaliser reads them), and its
    ranking metrics and misfit (:func:`ranked_metrics`)."""
    plain, ranked = ranked_metrics(span, segment, config, axis_deg)
    return plain, TakeScore(ranked, guide_misfit(span, segment, preference))


def ranked_metrics(
    span: Demo, segment: Segment, config: ScoreConfig, axis_deg: float = 0.0
) -> tuple[RawMetrics, RawMetrics]:
    """A span demo's Eqs. (3)-(6) on its N samples, and the metrics it is ranked by (its Ũ's
    inputs: :func:`~bt_pipeline.clean.periodic.ranking_metrics`); L1 mirrors about the task
    loop's axis, `axis_deg` from the vertical of its frame
    (:attr:`~bt_pipeline.clean.loop_learn.TaskLoop.symmetry_axis`). A cleaned span (its cleaned
    samples at the raw times) is read the same way, so its Ũ is on the raw demos' scale."""
    theta = None if span.theta_deg is None else span.theta_deg + axis_deg
    plain = raw_metrics(span.positions, span.actions, theta, config)
    ranked = ranking_metrics(span, segment.cycles, plain, config.alphas, config.derotate, axis_deg)
    return plain, ranked


def span_attrs(segment: Segment, preference: PreferenceEstimate) -> dict[str, Any]:
    """A demo's kept span, its loops and its θ/ρ confidence, as the cleaned file's demo attrs
    and ``bt score --json`` name them (docs/recording-format.md)."""
    return {
        "loop_start_s": segment.start_s,
        "loop_end_s": segment.end_s,
        "cycles": segment.cycles,
        "preference_confidence": preference.confidence,
    }
