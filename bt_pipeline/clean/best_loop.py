"""The best demo's own loop replaces the loop learned from every demo (loop_learn step 6), and
its span is closed where its path returns to itself.

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
from scipy.ndimage import gaussian_filter1d
from scipy.spatial import KDTree

from bt_pipeline.clean.guide_fit import CENTRED_REACH
from bt_pipeline.clean.guide_track import track_phase
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
from bt_pipeline.clean.span_loop import gaps, span_loop
from bt_pipeline.data.demo import Demo
from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.exceptions import DemoError

_ALONE = 1.1  # A path of at most this many loops is the loop alone (no approach to join it).
_GUIDE_SHORT = 0.9  # A guide is replaced when less than this share of the best loop is on it.
_STEADY_OFF = 0.02  # A best loop this share of its RMS radius off the guide replaces it when
_STEADY = 3.0  # that gap is this many times its samples' scatter about it (90th percentile).
_DENSE = 4096  # Points of the best loop its samples' scatter is read against.
_WHOLE = 0.95  # A best demo's span under this many loops is also sought against its own loop.
_OPEN = (0.5, _WHOLE)  # A best demo's span of this many loops is closed where its path returns,
_RETURN = 0.05  # within this share of the loop's size (at least 3 mm), running the same way,
_OVER = (1.05, 1.35)  # A span of this many loops holds one loop and a stretch of approach or
# retreat that runs along it: it is trimmed to the closest return between its two ends.
_REACH = 0.15  # at most the missing part of a loop plus this share of one away from the span,
_ON_LOOP = 0.08  # the part added lying within this share of the size of its fitted loop (9 in 10
_ON_SHARE = 0.9  # samples: a retreat that passes the span's start on its way out does not).
_TANGENT_TIE = 0.02  # Closing pairs whose tangents agree within this cosine of the best tie.
_CLOCK_HZ = 50.0  # The path is read on this clock,
_LIGHT_S = 0.03  # smoothed this lightly [s] (as the loop is read: recurrence.py).


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
        if own is not None and segment.cycles < _WHOLE:
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


def closed_span(demo: Demo, segment: Segment) -> Segment:
    """The best demo's span of a single loop, closed where its path returns to itself.

    The best demo passes through the cleaner as it is, on its kept span, so a span that leaves
    out part of its loop loses that part of the output. A loop that starts slowly after the
    approach pauses where it joins is cut by the segmentation's travel test (it starts at a
    fraction of its later speed: 0.58 s of a random oval's 6.3 s loop), and an end can be cut
    the same way; a thin stroke's phase track can jump between its strands (a pick-and-place
    stroke's expert kept 0.56 of its loop). Where the span holds 0.5-0.95 of a loop, its one
    loop ends where the path comes back to where it began: the span starts at the last sample
    before it, within the missing part of a loop, that lies within 5 % of the loop's size (3 mm
    at least) of the span's end and leaves it the way the end arrives (cos ≥ 0.5), or ends at
    the first sample after it that returns to the span's start; the nearer return wins. The
    part added must lie on the span's fitted loop (9 in 10 of its samples within 8 % of its
    size): a retreat that passes the span's start on its way out is no return. No return: as
    it was.

    A span of 1.05-1.35 loops holds one loop and an approach or a retreat that runs along it
    (the approach converges on the loop where it begins, the retreat leaves it where it ends):
    it is trimmed to the pair of samples, one in each end's extra part of a loop (plus 0.1,
    counted in loops along the fitted loop), that lie closest (within the same 5 %), running the
    same way. Of the pairs within 1 mm of the closest, grouped by start (within 0.1 s), the group
    whose end arrives most nearly the way its start leaves wins, and in it the last start: a
    retreat that leaves where the loop began and crosses its first arc closes a loop too, 0.5 s
    later and at an angle (random weaving, θ/ρ hidden, seed 11: the expert's span held 0.96 s
    of retreat, 2.32 x its raw shape error; 1.02 when closed where the loop began).
    """
    low, high = _OPEN
    if not (low <= segment.cycles < high or _OVER[0] <= segment.cycles <= _OVER[1]):
        return segment
    x, t = demo.raw_samples()
    clock = np.arange(t[0], t[-1], 1.0 / _CLOCK_HZ)
    if clock.size < 16:
        return segment
    path = np.stack([np.interp(clock, t, x[:, d]) for d in range(2)], axis=1)
    path = gaussian_filter1d(path, _LIGHT_S * _CLOCK_HZ, axis=0, mode="nearest")
    i0 = int(np.clip(np.searchsorted(clock, segment.start_s), 0, clock.size - 1))
    i1 = int(np.clip(np.searchsorted(clock, segment.end_s) - 1, i0, clock.size - 1))
    reach = int((1.0 - segment.cycles + _REACH) * (i1 - i0) / segment.cycles)
    tolerance = max(0.003, _RETURN * segment.guide.size_m)
    step = max(2, round(0.1 * _CLOCK_HZ))
    if segment.cycles >= _OVER[0]:
        return _trimmed(segment, path, clock, t, i0, i1, tolerance, step)
    # The start earlier: the path before the span passes the span's end (the last such
    # sample); or the end later: the path after the span returns to its start (the first).
    found: list[tuple[float, float, float]] = []
    back = _return_to(path, i1, max(0, i0 - reach), i0, tolerance, step, last=True)
    if back is not None:
        found.append((back[0], float(clock[back[1]]), segment.end_s))
    ahead = _return_to(
        path, i0, i1 + 1, min(clock.size, i1 + 1 + reach), tolerance, step, last=False
    )
    if ahead is not None:
        found.append((ahead[0], segment.start_s, float(clock[ahead[1]])))
    ring = segment.guide.guide()
    on_loop = max(0.008, _ON_LOOP * segment.guide.size_m)
    found = [f for f in found if _on_loop(path, clock, f[1:], segment, ring, on_loop)]
    if not found:
        return segment
    _, start, end = min(found)
    return _snapped(segment, t, start, end)


def _return_to(
    path: np.ndarray, j: int, a: int, b: int, tolerance: float, step: int, *, last: bool
) -> tuple[float, int] | None:
    """Where the path over samples a..b-1 comes back to sample j (:func:`closed_span`): the last
    (`last`, before j) or first (after j) sample within 1 mm of the nearest one, when that is
    within `tolerance` and the path runs on there the way it runs at j. Returns (distance, k)."""
    near = np.linalg.norm(path[a:b] - path[j], axis=1)
    if not near.size or near.min() > tolerance:
        return None
    hits = np.flatnonzero(near <= near.min() + 0.001)
    k = a + int(hits[-1] if last else hits[0])
    if last:  # The loop arrives at j and leaves k.
        same = _same_way(_arriving(path, j, step), _leaving(path, k, step))
    else:  # It leaves j and arrives at k.
        same = _same_way(_leaving(path, j, step), _arriving(path, k, step))
    return (float(near.min()), k) if same else None


def _leaving(path: np.ndarray, i: int, step: int) -> np.ndarray:
    return path[min(i + step, path.shape[0] - 1)] - path[i]


def _arriving(path: np.ndarray, i: int, step: int) -> np.ndarray:
    return path[i] - path[max(0, i - step)]


def _snapped(segment: Segment, t: np.ndarray, start: float, end: float) -> Segment:
    """`segment` from `start` to `end` [s] snapped to raw sample times, holding one loop."""
    start = float(t[min(int(np.searchsorted(t, start - 1e-9)), t.size - 1)])
    end = float(t[max(int(np.searchsorted(t, end + 1e-9)) - 1, 0)])
    return dataclasses.replace(segment, start_s=start, end_s=end, cycles=1.0)


def _trimmed(
    segment: Segment,
    path: np.ndarray,
    clock: np.ndarray,
    t: np.ndarray,
    i0: int,
    i1: int,
    tolerance: float,
    step: int,
) -> Segment:
    """`segment` of more than one loop trimmed to its closest return (:func:`closed_span`).

    Each end's extra part of a loop (plus 0.1) is counted in loops along the fitted loop, not
    in time: an approach that creeps along the loop takes longer than its share of a loop (a
    rest pose on the loop itself, random weaving seed 3: a 2 s chord of 0.1 loop; counted in
    time the start's part ended before the loop began, and the closest return ran through the
    chord)."""
    extra = segment.cycles - 1.0 + 0.1
    ring = segment.guide.guide()
    phase = track_phase(path[i0 : i1 + 1], ring) / ring.shape[0]
    travelled = np.maximum.accumulate(np.abs(phase - phase[0]))
    head_n = int(np.searchsorted(travelled, extra, side="right"))
    tail_n = i1 - i0 + 1 - int(np.searchsorted(travelled, travelled[-1] - extra, side="left"))
    if travelled[-1] < 1.0:  # The track lost the loop: the parts in time, as a share of the span.
        head_n = tail_n = int(extra / segment.cycles * (i1 - i0))
    tail_0 = i1 + 1 - tail_n  # The tail part is path[tail_0 : i1 + 1].
    if min(head_n, tail_n) < 2 or tail_0 <= i0 + head_n:
        return segment
    head, tail = path[i0 : i0 + head_n], path[tail_0 : i1 + 1]
    gaps = np.linalg.norm(head[:, None, :] - tail[None, :, :], axis=2)
    # Of the about closest pairs (within 1 mm), grouped where their starts lie within 0.1 s of
    # each other: the group whose end arrives most nearly the way its start leaves (a retreat
    # that crosses the loop's first arc closes it too, at an angle; groups within 0.02 of the
    # best cosine tie and the later wins), and in it the last start (a pause where the loop
    # begins is one point, and the loop leaves it at the pause's end).
    starts = [int(a) for a in np.flatnonzero((gaps <= gaps.min() + 0.001).any(axis=1))]
    groups = np.split(np.array(starts), np.flatnonzero(np.diff(starts) > step) + 1)
    turn = [
        max(
            _cosine(
                _arriving(path, tail_0 + int(np.argmin(gaps[a])), step),
                _leaving(path, i0 + int(a), step),
            )
            for a in group
        )
        for group in groups
    ]
    chosen = [g for g, c in zip(groups, turn, strict=True) if c >= max(turn) - _TANGENT_TIE][-1]
    s = int(chosen[-1])
    e = int(np.argmin(gaps[s]))
    k0, k1 = i0 + s, tail_0 + e
    if float(gaps[s, e]) > tolerance:
        return segment
    if not _same_way(_arriving(path, k1, step), _leaving(path, k0, step)):
        return segment
    return _snapped(segment, t, float(clock[k0]), float(clock[k1]))


def _on_loop(
    path: np.ndarray,
    clock: np.ndarray,
    span: tuple[float, float],
    segment: Segment,
    ring: np.ndarray,
    tolerance: float,
) -> bool:
    """Whether the part `span` adds to `segment` lies on the loop `ring` (9 in 10 samples)."""
    added = ((clock >= span[0]) & (clock < segment.start_s)) | (
        (clock > segment.end_s) & (clock <= span[1])
    )
    if not added.any():
        return True
    gaps = np.min(np.linalg.norm(path[added][:, None, :] - ring[None, :, :], axis=2), axis=1)
    return float(np.mean(gaps <= tolerance)) >= _ON_SHARE


def _cosine(a: np.ndarray, b: np.ndarray) -> float:
    """The cosine between two moves, −1 when either is no move."""
    norm = float(np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.dot(a, b)) / norm if norm > 0.0 else -1.0


def _same_way(a: np.ndarray, b: np.ndarray) -> bool:
    return _cosine(a, b) >= 0.5


__all__ = ["best_demo_loop", "closed_span"]
