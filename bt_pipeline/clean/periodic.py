"""The cleaner's view of demos as people record them: the periodic part, pooled θ/ρ, own timing.

Data flow (used by :func:`bt_pipeline.clean.pipeline.clean_demos`)::

    raw demo (T samples, own times) ──segment_demo──▶ Segment (span, cycles, guide fit)
        ├─ span resampled to N samples uniform in time ──▶ span demo (scored, Stage 1, Stage 2)
        └─ guide fit θ/ρ ──pool per demonstrator──▶ PreferenceEstimate (θ, ρ, confidence)
    Stage 1's x^g under (θ_i, ρ_i) at c ──retime (track_phase on the span demo)──▶ x_i^aligned
        at the demo's own phase: its loops, pauses and speed changes kept
    cleaned span (N samples) ──interpolated at the raw sample times inside the span──▶ output

Pooling (docs/refinement.md): a demonstrator's θ and ρ are the weighted medians of the densest
cluster of the guide fits of their demos (fits within 2.5° and 0.025 of the fit with the most
such support), each fit weighted by its quality q = min(1, cycles) / (1 + (misfit / 2 % of
size)²), with the misfit the 90th percentile of the whole span's distances to the fit (a
lopsided loop's fit follows one side closely, so its trimmed residual is small, but its bulged
side is far off) and the loop's coverage in front: a part of a loop is fitted closely by a
wrong similarity (an incomplete, drifting 0.77 loop read ρ 12 % small within 1.3 mm and
outweighed its demonstrator's four right fits). The
confidence is the share of the demonstrator's total weight that agrees with the estimate (the
cluster's support) times the best agreeing fit's q (for one demo: its q); below 0.5 an estimate
is reported as uncertain. (Before 2026-12-02 it was the mean q over all the demonstrator's demos
over a spread term: one lopsided demo among good ones flagged a right estimate uncertain, 56-72 %
of the right estimates in sets of 8, against 9-25 % now;
``benchmarks/quality/bench_preferences.py``.)
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d

from bt_pipeline.clean.guide_fit import GuideFit, PreferenceRange
from bt_pipeline.clean.guide_track import periodic_degree, periodic_drift
from bt_pipeline.clean.segment import Segment, segment_demo, span_times, track_phase
from bt_pipeline.clean.stage1.alignment import apply_preference
from bt_pipeline.data.demo import Demo, resample_uniform
from bt_pipeline.data.loop_shape import LoopShape, arc_length_resample
from bt_pipeline.data.records import FloatArray
from bt_pipeline.score.losses import DEFAULT_ALPHAS, smoothness_loss, symmetry_loss
from bt_pipeline.score.utility import RawMetrics

UNCERTAIN = 0.5
"""Confidence below which an estimated θ/ρ is reported as uncertain."""
_PHASE_SMOOTH_S = 0.06  # Gaussian σ of the tracked phase [s]: removes jitter, keeps speed.
_RESIDUAL_SMOOTH_S = 0.12  # Gaussian σ of Stage 2's residual over the reference [s].
_DRIFT_SMOOTH_S = 1.0  # Gaussian σ of the slow drift removed before the phase is read [s].
_DRIFT_PASSES = 3  # Phase tracks (2 without a periodic drift); the drift is read between them.
_PERIODIC_DRIFT_MIN_M = 0.008  # A periodic drift reaching less than this [m] is a sway, not drift.
_POOL_THETA_DEG = 2.5  # Estimates this close in θ [deg] and
_POOL_RHO = 0.025  # in ρ agree when a demonstrator's demos are pooled.
_RETIME_OVERSAMPLE = 4  # Points of the dense reference per reference sample.
_MIN_LOOPS = 0.25  # loop_smoothness counts an incomplete loop as at least this many loops.
_GAP_STEPS = 4.0  # A cycle skips phases between kept samples this many median steps apart.


@dataclass(frozen=True)
class PreferenceEstimate:
    """A demo's θ/ρ as the cleaner uses it."""

    theta_deg: float
    rho: float
    estimated: bool
    """True when not taken from the demo's metadata."""
    confidence: float
    """In [0, 1]; 1 for given values."""


def segment_all(
    demos: Sequence[Demo],
    allowed: PreferenceRange | None = None,
    loop: LoopShape | None = None,
    hints: dict[str, GuideFit] | None = None,
) -> tuple[Segment, ...]:
    """The periodic part of every demo (θ/ρ fixed where the demo states them), measured against
    `loop` (None: each demo's task guide), with a fit to start from per demo label (`hints`)."""
    segments = []
    for demo in demos:
        positions, times = demo.raw_samples()
        segments.append(
            segment_demo(
                positions,
                times,
                loop if loop is not None else demo.task,
                demo.label,
                theta_deg=demo.theta_deg if demo.rho is not None else None,
                rho=demo.rho if demo.theta_deg is not None else None,
                allowed=allowed,
                hint=(hints or {}).get(demo.label),
            )
        )
    return tuple(segments)


def pool_preferences(
    demos: Sequence[Demo], segments: Sequence[Segment]
) -> tuple[PreferenceEstimate, ...]:
    """θ/ρ of every demo: given ones kept, missing ones pooled per demonstrator (module doc)."""
    quality = np.array([fit_quality(s) for s in segments])
    pooled: dict[str, PreferenceEstimate] = {}
    for who in {d.demonstrator for d in demos}:
        idx = [i for i, d in enumerate(demos) if d.demonstrator == who]
        thetas = np.array([segments[i].guide.theta_deg for i in idx])
        rhos = np.array([segments[i].guide.rho for i in idx])
        weights = quality[idx]
        # The densest cluster of the demonstrator's estimates (a misshapen demo's fit scatters;
        # the good ones agree): its weighted medians.
        near = (np.abs(thetas[:, None] - thetas[None, :]) <= _POOL_THETA_DEG) & (
            np.abs(rhos[:, None] - rhos[None, :]) <= _POOL_RHO
        )
        support = near @ weights
        centre = min(np.flatnonzero(support >= support.max() - 1e-9), key=lambda k: rhos[k])
        members = near[centre]
        theta = _weighted_median(thetas[members], weights[members])
        rho = _weighted_median(rhos[members], weights[members])
        # How much of the demonstrator's evidence agrees, times the best agreeing fit's quality.
        agree = float(support[centre]) / max(float(weights.sum()), 1e-12)
        confidence = agree * float(weights[members].max())
        pooled[who] = PreferenceEstimate(theta, rho, True, confidence)
    out = []
    for demo in demos:
        if demo.theta_deg is not None and demo.rho is not None:
            out.append(PreferenceEstimate(demo.theta_deg, demo.rho, False, 1.0))
        else:
            out.append(pooled[demo.demonstrator])
    return tuple(out)


def fit_quality(segment: Segment) -> float:
    """q, how far a demo's guide fit is trusted: the pooling's weight (module doc)."""
    misfit = segment.misfit_m / (0.02 * segment.guide.size_m)
    return min(1.0, segment.cycles) / (1.0 + misfit**2)


def span_demo(demo: Demo, segment: Segment, n_samples: int, preference: PreferenceEstimate) -> Demo:
    """The kept span of a demo, N samples uniform in time, with the θ/ρ the cleaner uses."""
    positions, times = demo.raw_samples()
    inside = span_times(times, segment)
    t, x = times[inside], positions[inside]
    if t.size < 2:
        t, x = times, positions
    return Demo(
        positions=resample_uniform(x, t, n_samples),
        task=demo.task,
        file=demo.file,
        name=demo.name,
        demonstrator=demo.demonstrator,
        theta_deg=preference.theta_deg,
        rho=preference.rho,
        plane=demo.plane,
        duration_s=float(t[-1] - t[0]),
        raw_positions=x,
        raw_times_s=t,
        created=demo.created,
    )


def retime_reference(
    global_shape: FloatArray,
    theta_deg: float,
    rho: float,
    centre: FloatArray,
    demo: Demo,
) -> FloatArray:
    """x_i^aligned at the demo's own phase: the reference point the demo means at each sample.

    The closed reference ρ R(θ) x^g + c is tracked along the (span) demo sample by sample
    (:func:`track_phase`); the phase is smoothed (σ = 0.06 s) and the reference read there, so
    the result has the demo's loops, pauses and speed changes but not its noise. A slow drift of
    the hand is removed and the phase read again, so drift does not shift the phase. In a demo
    of 1.5 loops or more, first the part of its path that does not repeat loop to loop
    (:func:`periodic_drift`, both components: a drift along the loop moves the nearest point
    with it, so the offset off the reference, which lies across the loop, missed it), then,
    read again, what is left of its offset off the reference smoothed over σ = 1 s (a hand's
    slow sway that a polynomial in time does not follow). Otherwise only the smoothed offset,
    and the phase read again once: in a shorter demo, which cannot tell a drift from its shape
    (a second time moved single loops' timing ratio 0.37 → 0.39 on random weaving), and where
    the periodic drift reaches less than 8 mm (a wobbly hand's slow sway of a few mm, read as
    drift, took the second generator's wobbly operators' timing ratio 0.68 → 0.71).

    Returns:
        Shape (N, 2), in [m].
    """
    loop = apply_preference(global_shape, theta_deg, rho, centre)[:-1]
    p = loop.shape[0]
    fine = np.arange(p * _RETIME_OVERSAMPLE) / _RETIME_OVERSAMPLE
    closed = np.concatenate([loop, loop[:1]])
    dense = np.stack([np.interp(fine, np.arange(p + 1), closed[:, d]) for d in range(2)], axis=1)
    x = demo.positions
    sigma = _PHASE_SMOOTH_S * (x.shape[0] - 1) / max(demo.duration_s, 1e-9)
    smooth_x = gaussian_filter1d(x, max(sigma / 2.0, 0.5), axis=0, mode="nearest")
    drift_sigma = _DRIFT_SMOOTH_S * (x.shape[0] - 1) / max(demo.duration_s, 1e-9)
    drift = np.zeros_like(x)
    target = x
    seen, steps = _sampled(demo)
    grid = np.arange(x.shape[0], dtype=np.float64)
    periodic = False
    for track in range(_DRIFT_PASSES):  # Track, estimate the slow drift, re-track.
        tracked = track_phase((smooth_x - drift)[seen], dense, steps=steps) / _RETIME_OVERSAMPLE
        phase = np.interp(grid, grid[seen], tracked)  # Reference samples.
        phase = gaussian_filter1d(phase, max(sigma, 0.5), mode="nearest")
        target = _read(closed, np.mod(phase, p))
        if track == 0:
            loops = phase / p
            degree = periodic_degree(abs(float(loops[-1] - loops[0])))
            drift = periodic_drift(smooth_x, loops, degree)
            periodic = float(np.max(np.linalg.norm(drift, axis=1))) >= _PERIODIC_DRIFT_MIN_M
            if not periodic:
                drift = gaussian_filter1d(x - target, drift_sigma, axis=0, mode="nearest")
        elif periodic and track < _DRIFT_PASSES - 1:
            # What is left off the reference, slow: a sway the polynomial does not follow.
            drift = drift + gaussian_filter1d(
                x - drift - target, drift_sigma, axis=0, mode="nearest"
            )
        else:
            break
    return target


def _sampled(demo: Demo) -> tuple[np.ndarray, FloatArray]:
    """Which of a span demo's N samples lie near a raw sample, and the grid steps between them.

    Inside a gap in the raw samples (more than 2 typical intervals, and 2 grid steps, from the
    nearest raw sample) the N-sample path is the resampling's bridge, not the hand: a chord across
    a figure-eight set the phase track off on the wrong branch for 0.4 s after a 0.6 s gap. The
    phase is tracked on the other samples, with a reach that grows with the gap, and interpolated
    across it.
    """
    n = demo.positions.shape[0]
    raw_t = demo.raw_times_s
    everything = np.ones(n, dtype=bool)
    if raw_t is None or raw_t.size < 3:
        return everything, np.ones(n)
    grid_t = np.linspace(raw_t[0], raw_t[-1], n)
    after = np.clip(np.searchsorted(raw_t, grid_t), 1, raw_t.size - 1)
    near = np.minimum(grid_t - raw_t[after - 1], raw_t[after] - grid_t)
    spacing = max(2.0 * float(np.median(np.diff(raw_t))), 2.0 * float(grid_t[1] - grid_t[0]))
    seen = near <= spacing
    seen[0] = seen[-1] = True
    if seen.all():
        return everything, np.ones(n)
    index = np.flatnonzero(seen)
    return seen, np.concatenate([[1.0], np.diff(index).astype(np.float64)])


def _read(closed: FloatArray, phase: FloatArray) -> FloatArray:
    """The closed polyline (P + 1, 2) read at fractional sample positions in [0, P)."""
    index = np.arange(closed.shape[0])
    return np.stack([np.interp(phase, index, closed[:, d]) for d in range(2)], axis=1)


def phase_loop(demo: Demo, segment: Segment) -> tuple[Demo, bool]:
    """One loop of the demo averaged over all its cycles by phase: the DMP's training demo.

    The DMP fits one period in time; a demo whose loops differ in speed or hold pauses would
    have misaligned cycles. Each sample's phase along the fitted guide is tracked
    (:func:`track_phase`); every cycle is read (interpolated along the demo) at the same N − 1
    phases and the cycles are averaged, so every cycle counts. Samples more than
    max(8 mm, 6 % of its size) off the guide (an excursion) are left out, and so are the
    N-sample path's bridges across gaps in the raw samples (:func:`_sampled`); a cycle does not
    cover the phases across such a gap (kept samples more than 4 median steps apart with a
    bridge between them), where it would only add a chord (a steady figure-eight's 0.1-0.5 s
    gaps bent its canonical loop's lobe in by 2-3 cm: docs/quality.md). A demo that stops
    within a few sampling steps of where it started (one whole loop, sampled up to the step
    before its start: ``bt synth``'s single loops, the bundled examples) is closed across that
    last step, as between any two samples. Phases no cycle covers (an incomplete loop) take the
    fitted guide's point at that phase. The loop starts at the demo's first phase and is
    closed (N samples).

    Returns:
        The loop as a demo of N samples, and whether any bin was filled from the guide.
    """
    guide = segment.guide.guide(4 * demo.n_samples)
    x = demo.positions
    n = x.shape[0]
    phase = track_phase(gaussian_filter1d(x, 1.0, axis=0, mode="nearest"), guide)
    sign = 1.0 if phase[-1] >= phase[0] else -1.0
    loops = sign * (phase - phase[0]) / guide.shape[0]  # Loops travelled since the first sample.
    bins = n - 1
    # Samples far off the guide (an excursion inside the span) do not shape the loop.
    off = np.linalg.norm(x - guide[np.round(phase).astype(int) % guide.shape[0]], axis=1)
    tolerance = max(0.008, 0.06 * segment.guide.size_m)
    mono = np.maximum.accumulate(loops)
    # Left out: samples off the guide, the resampling's bridges across gaps in the raw samples,
    # and the hand at rest.
    seen = _sampled(demo)[0]
    keep = (off <= tolerance) & seen & np.concatenate([[True], np.diff(mono) > 1e-9])
    if keep.sum() < 2:
        keep[:] = np.concatenate([[True], np.diff(mono) > 1e-9])
    kept_loops, kept_x = mono[keep], x[keep]
    # A loop that ends within a few steps of a whole one (the next sample would be the first
    # again): the step from its last sample back to its first is a step like any other, not
    # a missing part for the guide to fill.
    closing = kept_loops[0] + 1.0 - kept_loops[-1]
    if kept_loops.size >= 3 and 0.0 < closing <= _GAP_STEPS * float(np.median(np.diff(kept_loops))):
        kept_loops = np.append(kept_loops, kept_loops[0] + 1.0)
        kept_x = np.concatenate([kept_x, kept_x[:1]])
    # Each cycle read at the same N − 1 phases (interpolated along the demo), then averaged.
    cycle = np.arange(math.floor(mono[0]), math.ceil(max(mono[-1], kept_loops[-1])))[:, None]
    grid = cycle + (np.arange(bins) + 0.5) / bins  # (cycles, bins), in loops
    covered = (grid >= kept_loops[0]) & (grid <= kept_loops[-1])
    # A cycle does not cover the phases across a gap in the raw samples: kept samples with a
    # bridge between them, more than 4 median steps apart (the interpolation would draw the
    # chord). The other cycles, or the guide, fill them. A hand that only moves fast, or one
    # sample off the guide, keeps its phases.
    index = np.flatnonzero(keep)
    if index.size >= 3:
        kept = mono[index]
        bridged = np.cumsum(~seen)
        gap = (bridged[index[1:]] > bridged[index[:-1]]) & (
            np.diff(kept) > _GAP_STEPS * float(np.median(np.diff(kept)))
        )
        covered &= ~gap[np.clip(np.searchsorted(kept, grid), 1, kept.size - 1) - 1]
    values = np.stack([np.interp(grid, kept_loops, kept_x[:, d]) for d in range(2)], axis=-1)
    counts = covered.sum(axis=0)
    sums = np.einsum("cb,cbd->bd", covered.astype(np.float64), values)
    # Guide points at each bin's phase, in the demo's direction of travel.
    guide_index = (phase[0] + sign * (np.arange(bins) + 0.5) / bins * guide.shape[0]).astype(int)
    loop = guide[guide_index % guide.shape[0]].copy()
    filled = counts > 0
    loop[filled] = sums[filled] / counts[filled, None]
    closed = np.concatenate([loop, loop[:1]])
    return demo.with_positions(closed), bool(not filled.all())


def smooth_residual(refined: FloatArray, aligned: FloatArray, demos: Sequence[Demo]) -> FloatArray:
    """x̂_i = x_i^aligned + G_σ(x̂_i − x_i^aligned): the refinement's slow corrections are kept,
    its sample-to-sample jitter (which lengthened stop-and-go app demos by 60 %) is not.

    σ = 0.12 s in each demo's own samples.

    Args:
        refined: Stage 2's output, shape (M, N, 2), in [m].
        aligned: The re-timed references, shape (M, N, 2), in [m].
        demos: The span demos (their durations set σ).
    """
    out = np.array(refined, dtype=np.float64)
    for i, demo in enumerate(demos):
        sigma = _RESIDUAL_SMOOTH_S * (demo.n_samples - 1) / max(demo.duration_s, 1e-9)
        residual = gaussian_filter1d(out[i] - aligned[i], max(sigma, 0.5), axis=0, mode="nearest")
        out[i] = aligned[i] + residual
    return out


def output_on_raw_times(demo: Demo, cleaned: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The cleaned span at the raw sample times inside it: (times (K,) [s], positions (K, 2))."""
    _, times = demo.raw_samples()
    grid = np.linspace(times[0], times[-1], cleaned.shape[0])
    return times, np.stack([np.interp(times, grid, cleaned[:, d]) for d in range(2)], axis=1)


def _weighted_median(values: FloatArray, weights: FloatArray) -> float:
    order = np.argsort(values)
    cumulative = np.cumsum(weights[order])
    return float(values[order][int(np.searchsorted(cumulative, 0.5 * cumulative[-1]))])


def loop_smoothness(demo: Demo, loops: float, alphas: Sequence[float] = DEFAULT_ALPHAS) -> float:
    """L3 (Eq. 6) per loop: read on the demo resampled to N samples a loop, then divided by its
    loops.

    Eq. (6) sums raw sample differences over N samples, so a demo of c loops read at N samples
    moves c times as far per sample and its k-th differences grow as c^k: three loops score
    9, 81 and 729 times a single loop's L3 terms, and a steady hand that draws several loops
    ranks below a wobbly single loop (bench_app_takes.py, pick-and-place). Read at N samples a
    loop (from the demo's own samples, `Demo.raw_samples`) and averaged over its loops, every
    demo is judged at the same step along its loop. Incomplete loops count as at least a
    quarter.
    """
    x, t = demo.raw_samples()
    per_loop = max(float(loops), _MIN_LOOPS)
    n = max(4, round(demo.n_samples * per_loop))
    return smoothness_loss(resample_uniform(x, t, n), alphas) / per_loop


def path_symmetry(demo: Demo, loops: float, theta_deg: float | None) -> float:
    """L1 (Eq. 4) read along the path: on the span's samples resampled by arc length (N a loop).

    Eq. (4) mirrors the samples about the vertical line through their centroid. Samples uniform
    in time gather where the hand is slow, which moves that centroid: a steady pick-and-place
    take drawn slower on its left read L1 = 0.019 (its centroid 2 cm left of the arch's axis)
    against 0.006 for a wobbly single loop, which the ranking then preferred
    (bench_app_takes.py). Along the path the centroid is the shape's: 0.0006 and 0.0058.
    """
    x, t = demo.raw_samples()
    n = max(4, round(demo.n_samples * max(float(loops), 1.0)))
    return symmetry_loss(arc_length_resample(resample_uniform(x, t, n), n), theta_deg)


def ranking_metrics(
    demo: Demo,
    loops: float,
    plain: RawMetrics,
    alphas: Sequence[float],
    derotate: bool,
    axis_deg: float = 0.0,
) -> RawMetrics:
    """The metrics the cleaner ranks a demo by: `plain` (:func:`raw_metrics` on its N samples,
    MI kept) with L1 read along the path, L3 per loop and L1-L3 at ρ = 1 (docs/refinement.md).
    L1 mirrors about the task loop's axis, `axis_deg` from the vertical of the loop's frame.

    ρ is the demonstrator's preference, not a quality: L1 and L2 [m] grow as ρ and L3 as ρ², so
    a loop drawn small would otherwise rank as the cleaner one.
    """
    rho = demo.rho if demo.rho is not None and demo.rho > 0.0 else 1.0
    theta = demo.theta_deg
    return dataclasses.replace(
        plain,
        symmetry=path_symmetry(
            demo, loops, theta + axis_deg if derotate and theta is not None else None
        )
        / rho,
        closure=plain.closure / rho,
        smoothness=loop_smoothness(demo, loops, alphas) / rho**2,
    )
