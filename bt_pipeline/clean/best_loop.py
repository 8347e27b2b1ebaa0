"""The best demo's own loop replaces the loop learned from every demo (loop_learn step 6).

The paper takes the canonical shape from the best demo (Sec. III-B). The loop learned from the
demos (:mod:`bt_pipeline.clean.loop_learn`) is what selection measures the demos against; once
it has picked the best demo, that demo's own loop, low-passed and turned and scaled onto the
learned loop (so the frame stays), becomes the template the demos are segmented and scored
against again (:func:`bt_pipeline.clean.selection.select_demos`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.spatial import KDTree

from bt_pipeline.clean.guide_fit import CENTRED_REACH
from bt_pipeline.clean.loop_align import align, centred_complex
from bt_pipeline.clean.loop_learn import (
    GUIDE_FOLLOWED,
    HARMONICS,
    REPEATS,
    TIE,
    TaskLoop,
    guide_distance,
)
from bt_pipeline.clean.recurrence import LOOP_POINTS
from bt_pipeline.clean.segment import Segment, segment_demo, span_times
from bt_pipeline.clean.span_close import WHOLE, closed_span
from bt_pipeline.clean.span_loop import gaps, span_loop
from bt_pipeline.data.demo import Demo
from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.exceptions import DemoError

_ALONE = 1.1  # A path of at most this many loops is the loop alone (no approach to join it).
_GUIDE_SHORT = 0.9  # A guide is replaced when less than this share of the best loop is on it.
_STEADY_OFF = 0.02  # A best loop this share of its RMS radius off the guide replaces it when
_STEADY = 3.0  # that gap is this many times its samples' scatter about it (90th percentile).
_DENSE = 4096  # Points of the best loop its samples' scatter is read against.


def best_demo_loop(task_loop: TaskLoop, demo: Demo, segment: Segment) -> TaskLoop | None:
    """The learned loop replaced by the best demo's own loop, in the same frame (step 6).

    The consensus of noisy demos is a rough shape; the paper's canonical shape is the best
    demo's (Sec. III-B). Once selection has picked it, its own loop, low-passed to 12
    harmonics and turned and scaled onto the consensus (so the frame stays), is the template
    the demos are measured against again: read between its returns when its path holds 2
    loops or more (unless its span has gaps in its samples: dropped frames, bridged by chords
    on the analysis clock) or is the loop alone (at most 1.1 loops of path: no approach), and
    otherwise off its kept span (:func:`~bt_pipeline.clean.span_loop.span_loop`: a single loop
    with an approach closes at one point, where the approach may join it). A guide is replaced
    the same way when the best demo closes a loop of its own but less than 90 % of it was found
    on the guide (a loop close to the guide, but not it: an arch of another return depth), or
    whose own loop lies off the guide more than 4 % of its RMS radius, or more than 2 % and
    over 3 x its samples' scatter about that loop (:func:`_steadily_off`). None otherwise, or
    when no loop of the best demo can be read. The loop keeps the place the best
    demo drew it at (:attr:`~bt_pipeline.data.loop_shape.LoopShape.placed`) when that lies
    near the plane's origin (docs/refinement.md, step 6).
    """
    own = task_loop.own.get(demo.label)
    near = False  # Whether a loop drawn near the guide replaces it (:func:`_steadily_off`).
    notes = task_loop.notes
    if task_loop.source == "guide":
        if own is None:
            return None
        if segment.cycles < _GUIDE_SHORT:
            loop: np.ndarray | None = own
            notes += (
                f"{demo.label}, the best demo, closes a loop of its own but only "
                f"{segment.cycles:.2f} of it lies on the {demo.task} guide: its own loop is used "
                "instead",
            )
        else:
            # Read as a learned loop's best demo is: a single loop's returns can take in a
            # piece of its approach (pick-and-place seed 27's expert-like demo, on the guide,
            # read 4.6 % off it that way, 0.3 % off its span).
            loop = _read_loop(task_loop, demo, segment, own)
            off = math.inf if loop is None else guide_distance(loop, demo)
            if loop is None or (
                off <= GUIDE_FOLLOWED and not _steadily_off(loop, demo, segment, off)
            ):
                return None
            near = off <= GUIDE_FOLLOWED  # Drawn near the guide: fitted against as a guide is.
            notes += (
                f"{demo.label}, the best demo, closes a loop of its own {100 * off:.1f} % of its "
                f"size off the {demo.task} guide: its own loop is used instead",
            )
    else:
        loop = _read_loop(task_loop, demo, segment, own)
    if loop is None:
        return None
    shape = LoopShape.from_points(loop, HARMONICS)
    current = centred_complex(task_loop.loop.points(LOOP_POINTS))
    flipped = align(current, centred_complex(shape.points(LOOP_POINTS)), TIE)[2]
    shape = shape.reversed() if flipped else shape
    if demo.theta_deg is not None and demo.rho is not None:
        # Its stated θ/ρ removed: the paper's x^g = R(−θ_best)(x^d − c) / ρ_best (Sec. III-B).
        shape = shape.transformed(-demo.theta_deg, 1.0 / demo.rho)
    else:
        # Hidden: the θ/ρ its fit to the learned loop read removed, so it keeps the place in
        # the set's frame that the other demos were read against. Aligning the shapes instead
        # turns it by 180° where the consensus is nearly its own twin: an eight of unequal
        # lobes onto a consensus of lopsided demos, whose fits then matched one lobe (varied
        # weaving, seed 4: naive demos 1.8-2.6 x their raw error).
        shape = shape.transformed(-segment.guide.theta_deg, 1.0 / segment.guide.rho)
    # It stays where the best demo drew it, turned and scaled back about the plane's origin:
    # the point the demos turn it about, which a box's centre is not on a loop without central
    # symmetry (docs/quality.md). A loop drawn far from the origin (an imported file's) is
    # centred on its box instead.
    placed = bool(np.linalg.norm(shape.centre) <= CENTRED_REACH * shape.size_m)
    if not placed:
        shape = shape.transformed(translation=-shape.centre)
    label = f"{demo.task} loop of its best demo, {demo.label}"
    framed = LoopShape(shape.coefficients, label, placed=placed, near_guide=placed and near)
    return dataclasses.replace(
        task_loop, loop=framed, source="learned", best=demo.label, notes=notes
    )


def _read_loop(
    task_loop: TaskLoop, demo: Demo, segment: Segment, own: np.ndarray | None
) -> np.ndarray | None:
    """The best demo's loop (256 points): between its returns (`own`) when its path repeats it
    or is the loop alone, else off its kept span (:func:`best_demo_loop`); None when neither
    can be read."""
    repeats = task_loop.repeats.get(demo.label, 0.0)
    if own is None or _ALONE < repeats < REPEATS:
        # A single loop with an approach closes where the approach may join it: read it off
        # the kept span instead, in the phase of its fit.
        # A span under a whole loop is also sought against its own loop.
        if own is not None and segment.cycles < WHOLE:
            # Its span on the consensus leaves part of its loop: segment it against its own.
            segment = _segment_on_own(demo, own, segment)
        # Its one loop, where the path returns to itself: a span that runs on along an
        # approach beside the loop (varied weaving seed 11: 1.12 loops) bent the loop read off
        # it there, and the span found against that loop lost a lobe's tip (8 x its raw error).
        segment = closed_span(demo, segment)
        return span_loop(*demo.raw_samples(), segment, LOOP_POINTS)
    if _gapped(demo, segment):
        # Read between its returns on a clock that bridges a gap in its samples with a chord
        # (dropped frames: 0.2-0.6 s of a 2.7 s loop cut 5 mm inside it): off its span instead,
        # over every loop, the chords left out, so another loop covers the phase a gap skips.
        read = span_loop(*demo.raw_samples(), _segment_on_own(demo, own, segment), LOOP_POINTS)
        return own if read is None else read
    return own


def _steadily_off(loop: np.ndarray, demo: Demo, segment: Segment, off: float) -> bool:
    """Whether the best demo draws a loop of its own steadily, not the guide loosely: its own
    loop lies more than 2 % of its RMS radius off the guide, and that gap is more than 3 x
    the 90th percentile of its span's samples' distances to its own loop.

    On guide sets the best demo's loop lies at most 1.5 % off the guide (12 seeds per task,
    θ/ρ hidden); on varied guides (an arch 2.5-3.5 % off) the steady expert-like demo lies
    4-7 x its scatter off, and cleaning towards the guide took careful naive demos from 1.2 to
    2.9 mm off their truth. The app's careful browser take that is the best of its folder lies
    3.9 % off the guide at 2.6 x its scatter: a hand that traces the guide loosely, and the
    guide is kept for it. The loop that replaces the guide is fitted against as the guide was
    (``LoopShape.near_guide``): with the learned loop's tighter centred fits, lopsided demos
    were read 11-15 % too big and held-out varied sets cleaned worse than with the guide
    (docs/refinement.md, step 6)."""
    if off <= _STEADY_OFF:
        return False
    dense = LoopShape.from_points(loop, HARMONICS).points(_DENSE)
    x, t = demo.raw_samples()
    scatter = float(np.percentile(KDTree(dense).query(x[span_times(t, segment)])[0], 90))
    radius = float(np.sqrt(np.mean(np.abs(centred_complex(loop)) ** 2)))
    return off * radius > _STEADY * scatter


def _gapped(demo: Demo, segment: Segment) -> bool:
    """Whether the raw samples of the demo's kept span have a gap (:func:`span_loop.gaps`)."""
    times = demo.raw_samples()[1]
    return bool(np.any(gaps(times[span_times(times, segment)])))


def _segment_on_own(demo: Demo, own: np.ndarray, segment: Segment) -> Segment:
    """The best demo's span found against its own loop, when that covers more of a loop than
    its span on the consensus (step 6). A consensus that leans to lopsided demos leaves one
    side of an expert's single loop outside the tolerance (0.7 of it was kept, and the rest of
    the canonical loop came from the consensus: 46 x the expert's raw error). Its own loop is
    where its path returns to itself; segmented against that (only the placement free) the span
    covers the loop, and the loop is read off the span as usual, so what an approach brings
    into the returns' loop drops out."""
    positions, times = demo.raw_samples()
    template = LoopShape.from_points(own, HARMONICS)
    try:
        again = segment_demo(positions, times, template, demo.label, theta_deg=0.0, rho=1.0)
    except DemoError:
        return segment
    return again if again.cycles > segment.cycles else segment


__all__ = ["best_demo_loop"]
