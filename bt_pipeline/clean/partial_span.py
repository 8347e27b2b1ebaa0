"""A span of part of a loop, continued where the hand goes on around the loop off the fit.

The segmentation keeps the samples that lie within a tolerance of the fitted loop
(:mod:`~bt_pipeline.clean.segment`, step 4). A single loop drawn by a drifting, trembling hand
is fitted to the part it lies closest to, and the rest of the loop, 15-30 mm off that fit, was
cut away: the span held half or two thirds of the loop the hand drew, and the cleaned demo lost
the rest (random wiping, seed 2, θ/ρ hidden: 0.48 of a 0.72-loop demo kept, 2.0 x its raw
shape error). A span of less than 0.95 loops is therefore continued at each end, in steps of
0.2 s, while the hand goes on around the loop: a step is kept when 80 % of its samples move
along the loop (or nearly rest), it advances the phase the span's way at ≥ 30 % of the span's
rate, and the median of its distances to the fit is at most a quarter of the loop's size. The
span stops growing at one loop. An approach or a retreat that leaves the loop, or a pause,
ends the continuation; one that runs on along the loop in its direction cannot be told from it.
The θ/ρ fit keeps the span it was read on: read over the continued part too, a drifting loop's
ρ came out 15 % off (random wiping, seed 1). Measured by ``tests/pipeline/clean/
test_partial_span.py`` (loops drawn there, not by bt's generators) and
``benchmarks/quality/bench_clean_human.py --shapes random,varied``.
"""

from __future__ import annotations

import numpy as np

from bt_pipeline.clean.guide_track import track_phase
from bt_pipeline.data.records import FloatArray

PARTIAL = 0.95  # Spans of fewer loops than this are continued.
_STEP = 10  # Samples per step (0.2 s on the 50 Hz analysis clock).
_ALONG = 0.8  # A step moves along the loop in this share of its samples,
_RATE = 0.3  # at this share of the span's phase rate or more,
_REACH = 0.25  # within this share of the loop's size of the fit.
_FULL = 1.0  # The span grows to this many loops at most.


def continued(
    clear: FloatArray,
    distance: FloatArray,
    along: np.ndarray,
    guide: FloatArray,
    a: int,
    b: int,
    phase: FloatArray,
) -> tuple[int, int]:
    """The span a..b grown at each end while the hand goes on around the loop (module doc).

    Args:
        clear: The moving part with its drift removed, shape (T, 2) [m].
        distance: Each sample's distance to the fitted loop, shape (T,) [m].
        along: Whether each sample moves along the loop (or nearly rests), shape (T,).
        guide: The fitted loop, one loop, shape (P, 2) [m].
        a: First index of the span.
        b: Last index of the span.
        phase: The span's phase track along the fitted loop (:func:`track_phase`), shape
            (b - a + 1,), in loop points.
    """
    p = guide.shape[0]
    loops = float(phase[-1] - phase[0]) / p
    if b - a < 2 * _STEP or not 0.0 < abs(loops) < PARTIAL:
        return a, b
    rate = loops / (b - a)  # Loops per sample, signed by the direction of travel.
    reach = _REACH * float(np.max(np.ptp(guide, axis=0)))
    room = _FULL - abs(loops)
    b, room = _grow(clear, distance, along, guide, b, 1, rate, reach, room)
    a, _ = _grow(clear, distance, along, guide, a, -1, rate, reach, room)
    return a, b


def _grow(
    clear: FloatArray,
    distance: FloatArray,
    along: np.ndarray,
    guide: FloatArray,
    end: int,
    way: int,
    rate: float,
    reach: float,
    room: float,
) -> tuple[int, float]:
    """The span's `end` moved outward (`way` = +1: later, -1: earlier) step by step while each
    step continues the loop; returns the new end and the loops of room left."""
    p, last = guide.shape[0], clear.shape[0] - 1
    while room > 0.0:
        nxt = end + way * _STEP
        if nxt < 0 or nxt > last:
            return end, room
        lo, hi = (end, nxt) if way > 0 else (nxt, end)
        piece = clear[lo : hi + 1]
        if (
            float(np.mean(along[lo : hi + 1])) < _ALONG
            or float(np.median(distance[lo : hi + 1])) > reach
        ):
            return end, room
        phase = track_phase(piece, guide)
        step = float(phase[-1] - phase[0]) / p  # Loops, in time order.
        if np.sign(rate) * step < _RATE * abs(rate) * _STEP:
            return end, room
        end, room = nxt, room - abs(step)
    return end, room
