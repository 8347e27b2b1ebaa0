"""Find the periodic part of a demo: trim rests, approach and retreat; count the cycles.

People record a rhythmic skill with a rest at the start, an approach from a rest pose, one or
more loops (often with pauses), a retreat and a rest at the end. The cleaner works on the loops
only (docs/refinement.md, "Demos as people record them"). For one demo, with raw samples
(T, 2) at raw times:

1. **Motion.** The path is read on a uniform 50 Hz clock and smoothed (Gaussian, σ = 0.08 s).
   The hand moves from the first sample that is more than 10 mm (or 4 × the path's sample
   noise, for a jittery hand) from where it rested (the median of the first 0.2 s) until the
   last sample as far from where it comes to rest (walked back to where it set off).
2. **Guide.** The task's guide is fitted to the moving part (:func:`fit_guide`: a trimmed
   similarity fit, so approach and retreat do not pull it).
3. **Drift.** The guide's translation is fitted again over a sliding window of about one loop
   (2-10 s, from a first phase track), from the samples within twice the tolerance below, so a
   hand that slowly drifts off keeps being recognised as on the loop while a scale or shape
   error, which repeats every loop, is not taken for drift.
4. **On the loop.** A sample is on the loop when, drift removed, it lies within
   max(8 mm, 4 × the fit's residual, 6 % of the guide's size) of the guide and moves along it
   (|cos| ≥ 0.7 between its velocity and the guide's tangent) or nearly rests (a pause). The
   tolerance is then tightened to 3 × the 90th percentile of those samples' distances (at least
   3 mm), counted over the middle 60 % of them in time: an approach or a retreat that runs
   beside the loop is not a sample of how closely this hand follows it (an expert-like demo's
   tolerance read 10.9 mm with them, 3.4 mm without, and its span took in 1 s of approach). The
   kept span runs from the start of the first run of on-loop samples lasting ≥ 0.4 s to the end
   of the last such run, extended over neighbours within twice that distance; pauses inside it
   are kept (they are the demonstrator's timing).
5. **Travel.** The span is trimmed to where the hand travels along the guide: from the first
   to the last sample whose phase speed exceeds 45 % of the span's typical (75th percentile)
   phase speed, or 20 % where the slower edge would cut more than 15 % of a loop (a hesitant
   loop). The slow end of an approach near the guide, a rest on the loop and the slow start of
   a retreat fall out; pauses between loops stay. A loop that starts or ends slowly keeps its
   ramp: the span grows back over samples within the tight tolerance that move along the
   guide's tangent (|cos| ≥ 0.9); an approach's slow end comes in from the side. A recording
   that starts (ends) with the hand already (still) moving has no approach (retreat) there: the
   part before (after) the span is kept when it travels on around the loop (80 % of it along
   the guide, in the span's direction, at ≥ 30 % of its phase rate): a bulged side or a drifted
   end of a loop drawn from the first sample to the last.
6. **Preference.** θ/ρ are read over the span on a path smoothed with σ = 0.03 s only (the
   analysis path's smoothing shrinks loops): its drift removed first, the loop fitted (a
   lopsided loop by consensus), refined over every raw sample (:mod:`~bt_pipeline.clean.span_fit`).
7. **Cycles.** A span of under 0.95 loops is first continued while the hand goes on around the
   loop off the fit (:func:`~bt_pipeline.clean.partial_span.continued`: a drifting single loop),
   after θ/ρ are read. The phase along the guide is tracked sample by sample
   (:func:`track_phase`), and cycles = |phase travelled| / one loop.
8. **Raw ends.** In a span of 1.5 loops or more, or a single loop whose middle follows the
   guide within 1 mm (a steady hand), each raw end is cut where the samples cut lie mostly off
   the final fit (:func:`trim_raw_ends`, distances to the guide at 8,192 points), and the
   cycles are counted again.

Incomplete single loops are handled (cycles < 1); a demo with no on-loop run keeps its moving
part and is reported with cycles from the same phase track.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.ndimage import gaussian_filter1d

from bt_pipeline.clean.guide_fit import GuideFit, PreferenceRange, fit_guide
from bt_pipeline.clean.guide_track import (
    along_guide,
    drift_along,
    nearest_distance,
    nearest_index,
    runs_of,
    tangential,
    track_phase,
    travel,
    trim_raw_ends,
)
from bt_pipeline.clean.partial_span import continued
from bt_pipeline.clean.span_fit import fit_span
from bt_pipeline.data.loop_shape import LoopShape, as_loop
from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import DemoError

_CLOCK_HZ = 50.0  # Analysis clock [Hz].
_SMOOTH_S = 0.08  # Gaussian σ of the analysis path [s].
_EDGE_TRIM_S = 0.04  # Span ends that meet an approach or a retreat move in by this [s].
_FIT_SMOOTH_S = 0.03  # Gaussian σ of the path θ/ρ are fitted to [s].
_REST_M = 0.010  # A hand within this of its rest pose still rests [m],
_REST_NOISE = 4.0  # or within this many times its sample noise;
_REST_WINDOW_S = 0.2  # its rest pose: the median of its first (last) this many seconds.
_LOOSE = 2.0  # The span grows over neighbours within this many tolerances.
_CONTINUE_ALONG = 0.8  # A part beyond a recording-edge span end that moves along the guide
_CONTINUE_RATE = 0.3  # this much, at this share of the span's phase rate, is loop (kept).
_MIN_RUN_S = 0.4  # Shortest run of on-loop samples that starts or ends the span [s].
_EDGE_MIN_CYCLES = 1.5  # Raw ends are trimmed (step 8) in spans of at least this many loops.
_DRIFT_MAX_DEGREE = 4  # Highest degree of the drift polynomial (one per loop beyond the first).
_TRACK_POINTS = 512  # Guide points for the distance and the phase track.
_DENSE_POINTS = 8192  # Guide points for the end trim's distances (about 0.15 mm apart).
_TIGHT = 3.0  # On-loop tolerance: this many times the 90th percentile of the on-loop distances,
_CORE_CUT = 0.2  # The tight tolerance ignores this share of the on-loop samples at each end.
_TIGHT_MIN_M = 0.003  # but at least this [m] (and at most the loose tolerance).


@dataclass(frozen=True)
class Segment:
    """The periodic part of one demo."""

    start_s: float
    """First raw sample time of the kept span, on the raw demo's time base [s]."""
    end_s: float
    """Last raw sample time of the kept span [s]."""
    cycles: float
    """Loops in the span (fractional: 2.8 is two loops and most of a third)."""
    guide: GuideFit
    """The guide fitted to the kept span with its drift removed."""
    drift_m: float = 0.0
    """How far the hand's offset from the guide wandered over the span (range of the drift
    estimate) [m]: small for a demo drawn steadily off-centre, large for a drifting one."""
    misfit_m: float = 0.0
    """90th percentile of the distances of the span's samples (on the path θ/ρ are fitted to,
    σ = 0.03 s, drift removed) to the fitted guide, every sample counted (the fit itself trims)
    [m]: small when the whole loop has the guide's shape."""

    @property
    def duration_s(self) -> float:
        """Length of the kept span [s]."""
        return self.end_s - self.start_s


def segment_demo(
    positions: ArrayLike,
    times_s: ArrayLike,
    loop: LoopShape | str,
    name: str = "demo",
    *,
    theta_deg: float | None = None,
    rho: float | None = None,
    allowed: PreferenceRange | None = None,
    hint: GuideFit | None = None,
) -> Segment:
    """The kept span and cycle count of one demo (module doc).

    Args:
        positions: Raw task-plane positions, shape (T, 2), in [m].
        times_s: Their strictly increasing times, shape (T,), in [s] (any origin).
        loop: The task's loop, the template (a task name: its guide).
        name: Label for messages.
        theta_deg: Known θ [deg] of the demo, or None.
        rho: Known ρ, or None.
        allowed: Allowed θ/ρ when estimated.
        hint: A fit to start from as well as the usual starts: the demo's own loop aligned to
            the task's loop (:attr:`~bt_pipeline.clean.loop_learn.TaskLoop.hints`).

    Raises:
        DemoError: Mismatched or non-finite input, times not increasing, or no motion.
    """
    loop = as_loop(loop)
    x, t = checked_samples(positions, times_s, name)
    clock = np.arange(t[0], t[-1], 1.0 / _CLOCK_HZ)
    if clock.size < 8:
        raise DemoError(f"{name} lasts {t[-1] - t[0]:.3f} s; at least 0.08 s is needed")
    path = np.stack([np.interp(clock, t, x[:, d]) for d in range(2)], axis=1)
    smooth = gaussian_filter1d(path, _SMOOTH_S * _CLOCK_HZ, axis=0, mode="nearest")

    first, last = moving_part(smooth, path)
    if last - first < 8:
        raise DemoError(f"{name} does not move more than {1e3 * _REST_M:.0f} mm from its rest pose")
    moving = smooth[first : last + 1]
    fit = fit_guide(moving, loop, name, allowed=allowed, theta_deg=theta_deg, rho=rho, hint=hint)
    guide = fit.guide(_TRACK_POINTS)

    # Distance to the guide with a slow drift removed (a running median of the offsets).
    nearest = nearest_index(guide, moving)
    offset = moving - guide[nearest]
    tolerance = max(0.008, 4.0 * fit.residual_m, 0.06 * fit.size_m)
    # The drift may change by one degree per loop, so a scale or shape error (periodic) is not
    # mistaken for drift (slow): loops in the moving part from a first phase track.
    loops = abs(float(np.ptp(track_phase(moving, guide)))) / guide.shape[0]
    near = np.linalg.norm(offset, axis=1) <= 2.0 * tolerance
    drift = drift_along(moving, guide, near, min(_DRIFT_MAX_DEGREE, int(loops + 0.5) - 1))
    clear = moving - drift
    nearest = nearest_index(guide, clear)
    distance = np.linalg.norm(clear - guide[nearest], axis=1)
    along = along_guide(moving, guide, nearest)
    on = (distance <= tolerance) & along
    at_start, at_end = first == 0, last == smooth.shape[0] - 1
    # Tighten the tolerance to how closely this hand follows the guide on its loops, read over
    # the middle of the on-loop samples: a steady hand's approach that runs beside the loop is
    # then not taken for it. θ/ρ are fitted over the span the tolerance read over all of them
    # finds, when that is longer: the trimmed fit is not pulled by a bit of approach, and more of
    # the loop constrains it (a partial arc fits a wrong θ/ρ closely).
    tight = wide = tolerance
    if on.any():
        found = np.flatnonzero(on)
        core = found[int(_CORE_CUT * found.size) : max(1, int((1.0 - _CORE_CUT) * found.size))]
        tight, wide = (
            float(np.clip(_TIGHT * np.percentile(distance[k], 90), _TIGHT_MIN_M, tolerance))
            for k in (core, found)
        )
    a, b = _kept_span(clear, distance, along, tight, guide, at_start, at_end)
    fa, fb = (a, b)
    if wide > tight:
        fa, fb = _kept_span(clear, distance, along, wide, guide, at_start, at_end)
    # θ/ρ from the kept span alone (step 6), on a lightly smoothed path (σ = 0.03 s): the
    # analysis path's smoothing shrinks a loop (1 % at a 3 s period, 5-9 % on fast eights).
    fa, fb = min(a, fa), max(b, fb)
    # Part of a loop grows on around it (step 7); θ/ρ stay read over fa..fb (partial_span.py).
    phase = track_phase(clear[a : b + 1], guide)
    ca, cb = continued(clear, distance, along, guide, a, b, phase)
    if (ca, cb) != (a, b):
        a, b, phase = ca, cb, track_phase(clear[ca : cb + 1], guide)
    cycles = abs(float(phase[-1] - phase[0])) / guide.shape[0]
    light = gaussian_filter1d(path, _FIT_SMOOTH_S * _CLOCK_HZ, axis=0, mode="nearest")
    lspan = light[first + fa : first + fb + 1]
    followed = (distance[fa : fb + 1] <= 2.0 * tight) & along[fa : fb + 1]
    degree = min(_DRIFT_MAX_DEGREE, int(cycles + 0.5) - 1)
    # Drift first, then the fit, refined over the span's raw samples (step 6, span_fit.py).
    span_clock = clock[first + fa : first + fb + 1]
    fit, span_drift = fit_span(
        lspan,
        span_clock,
        drift[fa : fb + 1],
        (x, t),
        loop,
        guide,
        name,
        cycles=cycles,
        allowed=allowed,
        theta_deg=theta_deg,
        rho=rho,
        hint=hint,
    )
    fitted = lspan - span_drift  # The misfit is read on this path, not the analysis path (its
    # smoothing, σ = 0.08 s, shrinks a fast loop, so a right ρ read as a misfit of several mm).
    # Snap the span to raw sample times: the first and last raw sample inside it.
    i0 = min(int(np.searchsorted(t, clock[first + a] - 1e-9)), t.size - 2)
    i1 = max(int(np.searchsorted(t, clock[first + b] + 1e-9)) - 1, i0 + 1)
    if first + b == clock.size - 1:
        i1 = t.size - 1  # The span runs to the recording's end (the clock stops short of it).
    guide = fit.guide(_TRACK_POINTS)
    # The end trim reads distances of a millimetre or less: to a dense guide (512 vertices are
    # 2-3 mm apart), with the drift against the final fit (docs/refinement.md, step 8).
    end_drift = drift_along(lspan, guide, followed, degree)
    dense = fit.guide(_DENSE_POINTS)
    j0, j1 = trim_raw_ends(
        x, t, span_clock, end_drift, dense, i0, i1, single=cycles < _EDGE_MIN_CYCLES
    )
    if (j0, j1) != (i0, i1):
        i0, i1 = j0, j1
        a = max(a, int(np.searchsorted(clock, t[i0])) - first)
        b = min(b, int(np.searchsorted(clock, t[i1], side="right")) - 1 - first)
        phase = track_phase(clear[a : b + 1], guide)
        cycles = abs(float(phase[-1] - phase[0])) / guide.shape[0]
    return Segment(
        start_s=float(t[i0]),
        end_s=float(t[i1]),
        cycles=round(cycles, 2),
        guide=fit,
        drift_m=float(np.max(np.ptp(drift[a : b + 1], axis=0))),
        misfit_m=float(
            np.percentile(
                nearest_distance(fit.guide(_TRACK_POINTS), fitted[max(a, fa) - fa : b - fa + 1]), 90
            )
        ),
    )


def checked_samples(
    positions: ArrayLike, times_s: ArrayLike, name: str
) -> tuple[FloatArray, FloatArray]:
    """A demo's raw samples as float arrays, checked: (T >= 4, 2) finite positions and (T,)
    finite, strictly increasing times.

    Raises:
        DemoError: Mismatched shapes, NaN or infinite values, or times not increasing.
    """
    x = np.asarray(positions, dtype=np.float64)
    t = np.asarray(times_s, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 2 or t.shape != (x.shape[0],) or x.shape[0] < 4:
        raise DemoError(
            f"{name}: need positions (T >= 4, 2) and times (T,); got {x.shape} and {t.shape}"
        )
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(t))):
        raise DemoError(f"{name} has NaN or infinite positions or times")
    if np.any(np.diff(t) <= 0):
        raise DemoError(f"{name}: timestamps must increase strictly")
    return x, t


def _kept_span(
    clear: FloatArray,
    distance: FloatArray,
    along: np.ndarray,
    tolerance: float,
    guide: FloatArray,
    at_start: bool,
    at_end: bool,
) -> tuple[int, int]:
    """First and last index of the kept span in the moving part (steps 4-5 of the module doc).

    Args:
        clear: The moving part with its drift removed, shape (T, 2) [m].
        distance: Each sample's distance to the guide, drift removed, shape (T,) [m].
        along: Whether each sample moves along the guide (or nearly rests), shape (T,).
        tolerance: The on-loop tolerance [m].
        guide: The fitted guide, one loop, shape (P, 2) [m].
        at_start: The moving part starts at the recording's first sample (no rest before it).
        at_end: The moving part ends at the recording's last sample (no rest after it).
    """
    last = clear.shape[0] - 1
    runs = runs_of((distance <= tolerance) & along, int(_MIN_RUN_S * _CLOCK_HZ))
    a, b = (runs[0][0], runs[-1][1]) if runs else (0, last)
    if runs:
        # Extend over neighbours within twice the tolerance (a drift the polynomial still
        # lags); the travel test below drops what does not move along the loop.
        loose = distance <= _LOOSE * tolerance
        while a > 0 and loose[a - 1]:
            a -= 1
        while b < last and loose[b + 1]:
            b += 1
    span = clear[a : b + 1]
    head, tail = travel(track_phase(span, guide), guide.shape[0])
    # A loop that starts (or ends) slowly on the guide keeps that ramp: walk back over samples
    # that lie within the tight tolerance and move along the guide's tangent (an approach's
    # slow end comes in from the side).
    ramp = (distance[a : b + 1] <= tolerance) & tangential(span, guide)
    while head > 0 and ramp[head - 1]:
        head -= 1
    while tail < span.shape[0] - 1 and ramp[tail + 1]:
        tail += 1
    if tail > head:
        a, b = a + head, a + tail
    # A recording that starts (ends) with the hand already (still) moving has no rest there, so
    # no approach (retreat) either: a part before (after) the span that travels on around the
    # loop is the loop drawn off the guide (a bulged side, a drifted end), and is kept.
    if (at_start and a > 0) or (at_end and b < last):
        phase = track_phase(clear[a : b + 1], guide)  # Once, for both ends.
        rate = float(phase[-1] - phase[0]) / (guide.shape[0] * phase.size)  # Loops per sample.
        if at_start and a > 0 and _continues(clear[: a + 1], along[:a], guide, rate):
            a = 0
        if at_end and b < last and _continues(clear[b:], along[b + 1 :], guide, rate):
            b = last
    # The span was found on the path smoothed with σ = 0.08 s, which blurs where the hand joins
    # and leaves the loop: it reaches into the approach and the retreat (median 0.09 s at each
    # end on benchmarks/quality/bench_segment.py). An end that is not the recording's own moves in
    # by _EDGE_TRIM_S (0.04 s: the median error halves; a full σ cost the naive demos' ratios).
    trim = round(_EDGE_TRIM_S * _CLOCK_HZ)
    if b - a > 4 * trim:
        a += trim if (a > 0 or not at_start) else 0
        b -= trim if (b < last or not at_end) else 0
    return a, b


def _continues(piece: FloatArray, along: np.ndarray, guide: FloatArray, rate: float) -> bool:
    """Whether `piece` (samples before or after the span, in time order) travels on around the
    loop: it moves along the guide (80 % of its samples) in the span's direction, at least 30 %
    as fast in phase as the span does on average (`rate`: the span's loops per sample, signed by
    its direction). A piece within the edge trim (0.04 s) is too short to test, and is kept."""
    if piece.shape[0] <= round(_EDGE_TRIM_S * _CLOCK_HZ) + 1:
        return True
    if along.size == 0 or float(np.mean(along)) < _CONTINUE_ALONG:
        return False
    phase = track_phase(piece, guide)
    piece_rate = float(phase[-1] - phase[0]) / (guide.shape[0] * piece.shape[0])
    return (1.0 if rate >= 0.0 else -1.0) * piece_rate >= _CONTINUE_RATE * abs(rate)


def moving_part(smooth: FloatArray, path: FloatArray) -> tuple[int, int]:
    """First and last index of the motion between the rests (step 1 of the module doc)."""
    # Where it rests: the median of its first (last) 0.2 s; how far counts as away from it:
    # 10 mm, or 4 x the path's sample noise (a jittery hand's rest wanders further).
    edge = max(1, round(_REST_WINDOW_S * _CLOCK_HZ))
    noise = 1.4826 * float(np.median(np.abs(path - smooth))) * math.sqrt(2.0)
    away_m = max(_REST_M, _REST_NOISE * noise)
    from_start = np.linalg.norm(smooth - np.median(smooth[:edge], axis=0), axis=1)
    from_end = np.linalg.norm(smooth - np.median(smooth[-edge:], axis=0), axis=1)
    away = np.flatnonzero(from_start > away_m)
    back = np.flatnonzero(from_end > away_m)
    if away.size == 0 or back.size == 0:
        return 0, 0
    first, last = int(away[0]), int(back[-1])
    speed = np.linalg.norm(np.gradient(smooth, axis=0), axis=1) * _CLOCK_HZ
    moving = 0.1 * float(np.median(speed[first : last + 1]))
    # Walk back to where it set off: until the speed drops to 3x the rest's own (noise) speed.
    lead = _rest_speed(speed[: first + 1], moving)
    tail = _rest_speed(speed[last:], moving)
    while first > 0 and speed[first - 1] > max(0.003, moving, lead):
        first -= 1
    while last < smooth.shape[0] - 1 and speed[last + 1] > max(0.003, moving, tail):
        last += 1
    return first, last


def _rest_speed(speed: FloatArray, moving: float) -> float:
    """3x the median speed of a rest, or 0 when the hand never rested there (it set off at once)."""
    rest = float(np.median(speed))
    return 3.0 * rest if rest < 3.0 * moving else 0.0


def span_times(times_s: ArrayLike, segment: Segment) -> np.ndarray:
    """Mask of the raw samples inside the kept span, shape (T,) (bool)."""
    t = np.asarray(times_s, dtype=np.float64)
    return (t >= segment.start_s - 1e-9) & (t <= segment.end_s + 1e-9)


__all__ = [
    "Segment",
    "checked_samples",
    "moving_part",
    "segment_demo",
    "span_times",
    "track_phase",
]
