"""A demo's loop read off its kept span: a robust Fourier series in the phase of its fit.

A demo that draws one loop between an approach and a retreat closes it at one point, where the
approach may run along the loop and join it, so its recurrence (:mod:`recurrence`) can read a
piece of the approach into the loop. Once the demo has been segmented against a template, each
sample of its kept span (read at 50 Hz, σ = 0.03 s) has a phase along the fitted template
(:func:`track_phase`), and its own loop is the closed curve z(φ) = Σ_k c_k e^{ikφ} (|k| ≤ 12)
that the samples trace in that phase:

- each sample weighs the path it moves along (a pause is not many samples of one point), and
  a clock sample inside a gap of the raw samples (:func:`bridged`) weighs nothing: the clock
  bridges a gap with a chord that cuts inside the loop, and another loop of the span, or the
  bending penalty, covers that phase instead;
- a span of fewer than two loops is read over the one loop of phase in its middle, so a bit of
  approach or retreat at its ends does not compete with the loop at the same phase (over the
  whole span when a gap falls in that loop: the robust weights then drop what runs beside it);
- least squares with a small bending penalty (10⁻⁵ Σ k⁴ |c_k|² per unit weight: it bridges a
  phase the span leaves uncovered), reweighted three times with Tukey's biweight (c = 4.685
  robust standard deviations of the residuals, at least 0.5 mm), so what runs beside the loop
  drops out;
- fitted twice, the second time with the phase tracked along the first fit resampled uniform
  in arc length (the template's own shape errors then do not bend the phase).

Used for the best demo's loop (:func:`~bt_pipeline.clean.best_loop.best_demo_loop`): the
paper takes the canonical shape from the best demo (Sec. III-B), as a periodic DMP fitted to it
in its own phase. Measured by ``tests/pipeline/clean/test_loop_learn.py`` (a single loop read
off its span against a template stretched 8 %: within 1 % of its true shape) and
``benchmarks/quality/bench_clean_human.py --shapes random`` (docs/quality.md).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.ndimage import gaussian_filter1d

from bt_pipeline.clean.guide_track import track_phase
from bt_pipeline.clean.loop_align import arc_points
from bt_pipeline.clean.segment import Segment, span_times
from bt_pipeline.data.records import FloatArray

SPAN_HARMONICS = 12  # Harmonics of the fitted loop.
_MIN_COVER = 0.9  # The span must cover this share of a loop (a gap is bridged smoothly).
_BEND = 1e-5  # Weight of the loop's bending (Σ k⁴ |c_k|²) against the fit's, per sample weight.
_ALL_LOOPS = 2.0  # Spans of fewer loops are read over the one loop of phase in their middle.
_CLOCK_HZ = 50.0  # The span is read on this clock [Hz],
_SMOOTH_S = 0.03  # smoothed with this Gaussian σ [s].
_TRACK_POINTS = 512  # Template points for the phase track.
_TUKEY = 4.685  # Tukey's biweight constant, in robust standard deviations.
_MIN_SCALE_M = 0.0005  # The residuals' robust scale is at least this [m].
_REWEIGHTS = 3  # Reweighting passes per fit.
_GAP_FACTOR = 2.5  # A gap in the raw samples: an interval this many times their median
_GAP_MIN_S = 0.1  # and at least this long [s].


def span_loop(
    positions: ArrayLike, times_s: ArrayLike, segment: Segment, points: int = 256
) -> FloatArray | None:
    """The loop one demo traces over its kept span, in its own frame (module doc).

    Args:
        positions: Raw task-plane positions, shape (T, 2) [m].
        times_s: Their times, shape (T,) [s].
        segment: The demo's kept span and the template fitted to it.
        points: Points of the returned loop.

    Returns:
        The loop at `points` phases uniform in its fit's phase (about arc length; endpoint
        excluded), shape
        (points, 2) [m], in the demo's direction of travel; None when the span covers less than
        a whole loop, or its samples are too few for the fit.
    """
    t = np.asarray(times_s, dtype=np.float64)
    inside = span_times(t, segment)
    clock = np.arange(segment.start_s, segment.end_s, 1.0 / _CLOCK_HZ)
    if segment.cycles < _MIN_COVER or clock.size < 8 * SPAN_HARMONICS:
        return None
    raw = np.asarray(positions, dtype=np.float64)[inside]
    path = np.stack([np.interp(clock, t[inside], raw[:, d]) for d in range(2)], axis=1)
    path = gaussian_filter1d(path, _SMOOTH_S * _CLOCK_HZ, axis=0, mode="nearest")
    # Each sample weighs as much path as it moves along: a pause is not many samples of a point;
    # one on a chord across a gap in the samples, nothing.
    travel = np.linalg.norm(np.gradient(path, axis=0), axis=1)
    chords = bridged(clock, t[inside], _SMOOTH_S)
    travel[chords] = 0.0
    z = path[:, 0] + 1j * path[:, 1]
    ring = segment.guide.guide(_TRACK_POINTS)
    coefficients, forward = np.zeros(0, dtype=complex), 1.0
    for _ in range(2):
        phase = 2.0 * np.pi * track_phase(path, ring) / ring.shape[0]
        turned = abs(float(phase[-1] - phase[0]))
        if turned < 2.0 * np.pi * _MIN_COVER:
            return None
        forward = 1.0 if phase[-1] > phase[0] else -1.0
        keep = np.ones(phase.shape, dtype=bool)
        if turned < 2.0 * np.pi * _ALL_LOOPS:
            # One loop, and a bit of approach or retreat: the loop of phase in the middle,
            # unless a gap leaves part of it out (the rest of the span may cover that phase).
            middle = 0.5 * (phase[0] + phase[-1])
            keep = np.abs(phase - middle) <= np.pi
            if np.any(chords[keep]):
                keep[:] = True
        coefficients = _robust_fit(z[keep], phase[keep], travel[keep])
        # Tracked again along this fit, uniform in arc length (a fit on a poor template's
        # phase runs unevenly, and the track's step bound then stops it short).
        ring = arc_points(_evaluate(coefficients, 4 * _TRACK_POINTS, 1.0))
    return _evaluate(coefficients, points, forward)


def gaps(times_s: ArrayLike) -> np.ndarray:
    """Whether each interval between raw samples is a gap (shape (T − 1,), bool): longer than
    2.5 x the median interval and than 0.1 s (a dropped stretch of samples, not a low rate)."""
    dt = np.diff(np.asarray(times_s, dtype=np.float64))
    if dt.size == 0:
        return np.zeros(0, dtype=bool)
    return dt > max(_GAP_FACTOR * float(np.median(dt)), _GAP_MIN_S)


def bridged(clock: FloatArray, times_s: ArrayLike, margin_s: float = 0.0) -> np.ndarray:
    """Whether each clock time falls inside a gap of the raw samples (:func:`gaps`), widened by
    `margin_s` on both sides (a smoothed path feels a chord that far), shape (len(clock),)."""
    t = np.asarray(times_s, dtype=np.float64)
    out = np.zeros(clock.shape, dtype=bool)
    for k in np.flatnonzero(gaps(t)):
        out |= (clock > t[k] - margin_s) & (clock < t[k + 1] + margin_s)
    return out


def _basis(phase: FloatArray) -> np.ndarray:
    k = np.arange(-SPAN_HARMONICS, SPAN_HARMONICS + 1)
    return np.exp(1j * np.outer(phase, k))


def _robust_fit(z: np.ndarray, phase: FloatArray, prior: FloatArray) -> np.ndarray:
    """Fourier coefficients of z over phase: least squares weighted by `prior`, reweighted
    with Tukey's biweight."""
    basis = _basis(phase)
    prior = prior / max(float(prior.max()), 1e-12)
    weights = prior.copy()
    coefficients = np.zeros(basis.shape[1], dtype=complex)
    k = np.arange(-SPAN_HARMONICS, SPAN_HARMONICS + 1)
    for _ in range(_REWEIGHTS + 1):
        # Weighted least squares with a little bending penalty (it bridges an uncovered gap).
        gram = (basis.conj().T * weights) @ basis
        gram += np.diag(_BEND * float(weights.sum()) * k.astype(float) ** 4)
        coefficients = np.linalg.solve(gram, (basis.conj().T * weights) @ z)
        residual = np.abs(z - basis @ coefficients)
        scale = max(1.4826 * float(np.median(residual)), _MIN_SCALE_M)
        u = residual / (_TUKEY * scale)
        weights = prior * np.where(u < 1.0, (1.0 - u**2) ** 2, 0.0)
    return coefficients


def _evaluate(coefficients: np.ndarray, points: int, forward: float) -> FloatArray:
    """The fitted loop at `points` uniform phases, travelled forward (+1) or backward (−1)."""
    phase = forward * 2.0 * np.pi * np.arange(points) / points
    z = np.asarray(_basis(phase) @ coefficients)
    return np.stack([np.real(z), np.imag(z)], axis=1)
