"""The phase of each training demo: the canonical oscillator a phase-conditioned learner follows.

A figure-eight crosses itself, so no field ẋ = f(x) on 2-D position can draw it: at the crossing the
same x needs two velocities. With a phase φ the state (x, cos φ, sin φ) is unique along the loop.
As in the periodic DMP (docs/algorithms.md §2), φ is driven at test time by a canonical oscillator
φ̇ = ω = 2π / T; during training it is estimated from each demo:

1. **Length of one loop.** s_i is the arc length of the demo smoothed by a Savitzky-Golay filter
   (so jitter does not inflate it). A first guess P⁰_i = s_i(1) T_i uses the spectral period T_i of
   :func:`bt_pipeline.clean.stage1.period.estimate_period`, which is only good to ±15 % on a demo
   of one loop with uneven speed. It is refined by the closest return: from points in the first
   third of the demo, the arc length L ∈ [0.6, 1.4] P⁰_i after which the demo comes back nearest
   (an interior minimum within 3 % of the demo's size, or any minimum within 0.5 %: a demo of
   exactly one loop returns at its very end); P_i is the median of those L. A demo that never
   returns (an incomplete loop, or one whose end lies off its start) is taken as one loop,
   P_i = s_i(1), when P⁰_i is at least 3/4 of it, and P⁰_i otherwise.
2. **Phase along the demo by arc length.** φ_i(t) = 2π s_i(t) / P_i. A pause holds φ still, a fast
   stretch advances it fast: the phase is the position along the loop, not the clock. The
   canonical period is T = median_i P_i / s_i(1) (normalised time per loop) and ω = 2π / T.
3. **A common origin.** Demos start anywhere on the loop; each demo's first loop, sampled at
   K = 128 phases, is matched to a template by the circular shift that minimises the mean squared
   distance, and the template is re-estimated as the mean of the shifted loops (3 rounds). All
   demos then share φ = 0 at the same place of the loop. Direction is assumed the same for every
   demo (the canonical direction of the synthetic sets and of the app's tasks).

:func:`phase_resample` then resamples each demo at uniform phase steps ω Δt, so the training pairs
(state, next state) are the steps an oscillator-driven rollout takes. A rollout starts at the phase
of the training sample nearest to its first state (:func:`nearest_phase`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import savgol_filter
from scipy.spatial import KDTree

from bt_pipeline.clean.stage1.period import estimate_period
from bt_pipeline.data.records import FloatArray

TEMPLATE_PHASES = 128
"""K, phases at which the demos' loops are compared to find their common origin."""
ALIGN_ROUNDS = 3
"""Rounds of template re-estimation."""
_ONE_LOOP = 0.75  # A demo that never returns, guessed ≥ this share of a loop, is one loop.


@dataclass(frozen=True)
class PhaseFit:
    """The estimated phase of every sample of every demo."""

    phases: FloatArray
    """Unwrapped phase of every sample, shape (M, N), in [rad]; φ = 0 is the same place of the
    loop for every demo."""
    period: float
    """T, normalised time per loop of the canonical oscillator (median over the demos)."""
    template: FloatArray
    """Mean loop at K phases 2πk/K, shape (K, 2), in [m]."""

    @property
    def omega(self) -> float:
        """ω = 2π / T [rad per unit normalised time]."""
        return 2.0 * math.pi / self.period


def _smooth(x: FloatArray) -> FloatArray:
    """x (N, 2) smoothed by a cubic Savitzky-Golay filter over ~N/30 samples."""
    n = x.shape[0]
    window = min(max(5, (n // 30) | 1), n if n % 2 else n - 1)
    return np.asarray(savgol_filter(x, window, 3, axis=0), dtype=np.float64) if window > 3 else x


def _arc_length(smooth: FloatArray) -> FloatArray:
    """Cumulative arc length of a curve (N, 2), shape (N,), strictly rising."""
    n = smooth.shape[0]
    steps = np.linalg.norm(np.diff(smooth, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(steps)])
    return s + 1e-9 * (s[-1] + 1e-9) * np.arange(n) / n  # strictly increasing for np.interp


def _loop_length(smooth: FloatArray, s: FloatArray, guess: float) -> float:
    """Arc length of one loop by the closest return (module doc, step 1), in [m]."""
    size = float(np.ptp(smooth, axis=0).max())
    lags = np.linspace(0.6, 1.4, 161) * guess
    found = []
    for s0 in np.linspace(0.0, s[-1] / 3.0, 12):
        reach = lags[s0 + lags < s[-1]]
        if lags[0] <= s[-1] - s0 <= lags[-1]:
            reach = np.append(reach, s[-1] - s0)  # the demo's own end
        if reach.size < 3:
            continue
        here = np.array([np.interp(s0, s, smooth[:, j]) for j in range(2)])
        there = np.stack([np.interp(s0 + reach, s, smooth[:, j]) for j in range(2)], axis=1)
        gaps = np.linalg.norm(there - here, axis=1)
        k = int(np.argmin(gaps))
        interior = 0 < k < reach.size - 1
        if (interior and gaps[k] < 0.03 * size) or gaps[k] < 0.005 * size:
            found.append(reach[k])
    if found:
        return float(np.median(found))
    # No return: the demo holds about one loop or less (a loop stopped short, or one whose end
    # was moved off its start). Its whole length is then nearer one loop than the spectral guess
    # (clipped to it), which took a cleaned figure-eight 2.3 % short of a loop for 1.07 loops, so
    # the phase 2π landed 95 mm from the start (docs/evaluation.md).
    return s[-1] if guess >= _ONE_LOOP * s[-1] else guess


def _loop_at(x: FloatArray, phase: FloatArray, grid: FloatArray) -> FloatArray:
    """x (N, 2) at phases `grid` (K,), linearly interpolated (held at the demo's ends)."""
    return np.stack([np.interp(grid, phase, x[:, j]) for j in range(2)], axis=1)


def estimate_phases(demos: FloatArray) -> PhaseFit:
    """Phase of every sample of demos (M, N, 2) [m], uniform on t ∈ [0, 1] (module doc).

    Args:
        demos: Positions, shape (M, N, 2), in [m]; finite, N ≥ 8.

    Returns:
        The phases, the canonical period and the template loop.
    """
    m, n, _ = demos.shape
    periods = np.empty(m)
    phases = np.empty((m, n))
    for i, x in enumerate(demos):
        smooth = _smooth(x)
        s = _arc_length(smooth)
        guess = max(s[-1] * min(estimate_period(x), 1.0), 1e-12)
        # at least 8 samples per loop, at most one loop per demo: a still or jittering demo
        # cannot blow the phase up
        periods[i] = np.clip(_loop_length(smooth, s, guess) / max(s[-1], 1e-12), 8.0 / n, 1.0)
        phases[i] = 2.0 * math.pi * s / max(s[-1] * periods[i], 1e-12)
    grid = 2.0 * math.pi * np.arange(TEMPLATE_PHASES) / TEMPLATE_PHASES
    loops = np.stack([_loop_at(x, p, grid) for x, p in zip(demos, phases, strict=True)])
    template = loops[0]
    shifts = np.zeros(m, dtype=np.int64)
    for _ in range(ALIGN_ROUNDS):
        for i in range(m):
            costs = [
                np.mean(np.sum((loops[i] - np.roll(template, -c, axis=0)) ** 2, axis=1))
                for c in range(TEMPLATE_PHASES)
            ]
            shifts[i] = int(np.argmin(costs))  # loops[i][k] ≈ template[k + c]
        template = np.mean([np.roll(loops[i], shifts[i], axis=0) for i in range(m)], axis=0)
    phases = phases + (2.0 * math.pi / TEMPLATE_PHASES) * shifts[:, None]
    return PhaseFit(phases=phases, period=float(np.median(periods)), template=template)


def phase_resample(demos: FloatArray, fit: PhaseFit, dt: float) -> list[FloatArray]:
    """Each demo resampled at uniform phase steps ω Δt: a list of (n_i, 3) arrays [x, y, φ].

    n_i is the number of oscillator steps the demo's phase span holds (≥ 2).
    """
    step = fit.omega * dt
    out = []
    for x, phase in zip(demos, fit.phases, strict=True):
        count = max(2, int((phase[-1] - phase[0]) / step) + 1)
        grid = phase[0] + step * np.arange(count)
        out.append(np.column_stack([_loop_at(x, phase, grid), grid]))
    return out


def nearest_phase(points: FloatArray, anchors: FloatArray, anchor_phases: FloatArray) -> FloatArray:
    """Phase [rad] of the anchor nearest to each point (R, 2) [m]: shape (R,), in [0, 2π)."""
    _, index = KDTree(anchors).query(points)
    return np.mod(anchor_phases[index], 2.0 * math.pi)


__all__ = ["PhaseFit", "estimate_phases", "nearest_phase", "phase_resample"]
