"""A demo's θ/ρ from its kept span: drift first, then the fit (:mod:`segment` step 6).

    kept span (path σ = 0.03 s) ──periodic_drift──▶ span − drift
        ──fit_guide (every start, plain)──▶ plain fit ──repeats_per_loop──▶ repeats?
        ──consensus_fit──▶ ──fit_guide (from it)──▶ ──refine_fit (raw samples)──▶ GuideFit

1. **Drift.** What does not repeat from loop to loop (:func:`periodic_drift`: a Fourier loop in
   the phase plus a slow polynomial, degree one per loop beyond the first, at most 2, none
   under 1.5 loops) is the hand's drift, and is removed before any fit.
2. **Plain fit.** The loop is fitted to the span from every start, without the lopsided-loop
   consensus (:func:`fit_guide` with ``consensus=False``).
3. **Repeats.** Over several loops, whether the span's departure from that fit repeats every
   loop (:func:`repeats_per_loop`: a bulged side does, a sway does not), read once on the plain
   fit (guide_consensus, step 5). A single loop (no drift removed) that **closes** on itself,
   its path one loop on within 1.5 % of its size of where it was over at least 5 % of a loop
   (:func:`loop_gap`), has not drifted: its departure is a shape the hand meant too, and its
   fits are compared over the 30 % of it they follow best (guide_consensus, step 5). A gap
   read over less than that is a few samples where the span's ends were cut: on the app's
   wobbly takes of one loop (1.01 loops) it let a sway be read 6-7 % small. A drifting or
   incomplete single loop keeps the rules of before.
4. **Consensus.** The lopsided-loop consensus (:func:`consensus_fit`, guide_consensus steps 4-5)
   from the plain fit, then a refit from its result.
5. **Refined** over the raw samples of the span, their drift read off the span's, with robust
   weights (:func:`refine_fit`).
"""

from __future__ import annotations

import numpy as np

from bt_pipeline.clean.guide_fit import GuideFit, PreferenceRange, consensus_fit, fit_guide
from bt_pipeline.clean.guide_refine import refine_fit
from bt_pipeline.clean.guide_track import (
    loop_gap,
    nearest_distance,
    periodic_degree,
    periodic_drift,
    repeats_per_loop,
    track_phase,
)
from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.data.records import FloatArray

_TRACK_POINTS = 512  # Loop points for the distances of the repeat test.
_CLOSES = 0.015  # A single loop closes when one loop on it is this share of its size off,
_OVERLAP = 0.05  # read over at least this share of a loop.


def fit_span(
    span: FloatArray,
    span_clock: FloatArray,
    analysis_drift: FloatArray,
    samples: tuple[FloatArray, FloatArray],
    loop: LoopShape,
    guide: FloatArray,
    name: str,
    *,
    cycles: float,
    allowed: PreferenceRange | None,
    theta_deg: float | None,
    rho: float | None,
    hint: GuideFit | None,
) -> tuple[GuideFit, FloatArray]:
    """The span's fit and its drift (module doc).

    Args:
        span: The kept span on the analysis clock, lightly smoothed, shape (S, 2) [m].
        span_clock: Its clock times, shape (S,) [s].
        analysis_drift: The drift segmentation read against its first fit, shape (S, 2) [m]:
            the phase is tracked with it removed.
        samples: The demo's raw positions (T, 2) [m] and times (T,) [s].
        loop: The task's loop, the template.
        guide: That loop under the first fit, dense points (N, 2) [m], for the phase track.
        name: Label for messages.
        cycles: Loops in the span.
        allowed: Allowed θ/ρ when estimated.
        theta_deg: Known θ [deg], or None.
        rho: Known ρ, or None.
        hint: A fit to start from as well (the demo's own loop aligned to the task's).

    Returns:
        The refined fit, and the span's drift, shape (S, 2) [m].
    """
    span_phase = track_phase(span - analysis_drift, guide) / guide.shape[0]
    drifts = periodic_degree(cycles)
    span_drift = periodic_drift(span, span_phase, drifts)
    clear = span - span_drift
    known = {"allowed": allowed, "theta_deg": theta_deg, "rho": rho}
    fit = fit_guide(clear, loop, name, hint=hint, consensus=False, **known)
    if drifts > 0:
        off = nearest_distance(fit.guide(_TRACK_POINTS), clear)
        held = {"repeats": repeats_per_loop(clear, span_phase, off), "single": False}
    else:  # A single loop that closes on itself has not drifted (step 3).
        gap = loop_gap(clear, span_phase, _OVERLAP)
        closes = gap is not None and gap <= _CLOSES * fit.size_m
        held = {"repeats": False, "single": closes}
    fit = consensus_fit(clear, fit, **held, **known)
    fit = fit_guide(clear, loop, name, initial=fit, **held, **known)
    # Refined over the raw samples in the span (not the clock's, which bridge gaps in the
    # samples with chords that cut inside the loop), their drift read off the span's.
    x, t = samples
    inside = (t >= span_clock[0]) & (t <= span_clock[-1])
    raw_drift = np.stack([np.interp(t[inside], span_clock, span_drift[:, d]) for d in range(2)], 1)
    return refine_fit(x[inside] - raw_drift, fit, allowed, theta_deg, rho), span_drift


__all__ = ["fit_span"]
