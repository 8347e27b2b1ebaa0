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

from bt_pipeline.clean.loop_align import align, centred_complex
from bt_pipeline.clean.loop_learn import HARMONICS, REPEATS, TIE, TaskLoop
from bt_pipeline.clean.recurrence import LOOP_POINTS
from bt_pipeline.clean.segment import Segment, segment_demo
from bt_pipeline.clean.span_loop import span_loop
from bt_pipeline.data.demo import Demo
from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.exceptions import DemoError

_ALONE = 1.1  # A path of at most this many loops is the loop alone (no approach to join it).
_GUIDE_SHORT = 0.9  # A guide is replaced when less than this share of the best loop is on it.
_WHOLE = 0.95  # A best demo's span under this many loops is also sought against its own loop.


def best_demo_loop(task_loop: TaskLoop, demo: Demo, segment: Segment) -> TaskLoop | None:
    """The learned loop replaced by the best demo's own loop, in the same frame (step 6).

    The consensus of noisy demos is a rough shape; the paper's canonical shape is the best
    demo's (Sec. III-B). Once selection has picked it, its own loop, low-passed to 12
    harmonics and turned and scaled onto the consensus (so the frame stays), is the template
    the demos are measured against again: read between its returns when its path holds 2
    loops or more, or is the loop alone (at most 1.1 loops of path: no approach), and otherwise
    off its kept span (:func:`~bt_pipeline.clean.span_loop.span_loop`: a single loop with an
    approach closes at one point, where the approach may join it). A guide is replaced the same
    way when the best demo closes a loop of its own but less than 90 % of it was found on the
    guide (a loop close to the guide, but not it: an arch of another return depth). None
    otherwise, or when no loop of the best demo can be read.
    """
    loop = task_loop.own.get(demo.label)
    repeats = task_loop.repeats.get(demo.label, 0.0)
    notes = task_loop.notes
    if task_loop.source == "guide":
        if loop is None or segment.cycles >= _GUIDE_SHORT:
            return None
        notes += (
            f"{demo.label}, the best demo, closes a loop of its own but only {segment.cycles:.2f} "
            f"of it lies on the {demo.task} guide: its own loop is used instead",
        )
    elif loop is None or _ALONE < repeats < REPEATS:
        # A single loop with an approach closes where the approach may join it: read it off
        # the kept span instead, in the phase of its fit.
        if loop is not None and segment.cycles < _WHOLE:
            # Its span on the consensus leaves part of its loop: segment it against its own.
            segment = _segment_on_own(demo, loop, segment)
        loop = span_loop(*demo.raw_samples(), segment, LOOP_POINTS)
        if loop is None:
            return None
    shape = LoopShape.from_points(loop, HARMONICS)
    current = centred_complex(task_loop.loop.points(LOOP_POINTS))
    a, _, flipped, _ = align(current, centred_complex(shape.points(LOOP_POINTS)), TIE)
    shape = shape.reversed() if flipped else shape
    if demo.theta_deg is not None and demo.rho is not None:
        # Its stated θ/ρ removed: the paper's x^g = R(−θ_best)(x^d − c) / ρ_best (Sec. III-B).
        shape = shape.transformed(-demo.theta_deg, 1.0 / demo.rho)
    else:
        shape = shape.transformed(math.degrees(math.atan2(a.imag, a.real)), abs(a))
    shape = shape.transformed(translation=-shape.centre)
    label = f"{demo.task} loop of its best demo, {demo.label}"
    framed = LoopShape(shape.coefficients, label)
    return dataclasses.replace(
        task_loop, loop=framed, source="learned", best=demo.label, notes=notes
    )


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
