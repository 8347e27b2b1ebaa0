"""Period of a rhythmic demo: a zero-padded FFT peak, refined (docs/algorithms.md §2.4)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import DemoError

_PAD_FACTOR = 16  # Zero padding of the period estimate's FFT (docs/algorithms.md §2.4).


def loop_size(positions: FloatArray) -> float:
    """Size of a path, shape (N, 2) [m]: the larger side of its bounding box, in [m]."""
    by_axis = np.ascontiguousarray(np.asarray(positions, dtype=np.float64).T)
    return float(np.max(by_axis.max(axis=1) - by_axis.min(axis=1)))


def estimate_period(positions: ArrayLike, name: str = "demo") -> float:
    """Period of a repeating path from its spectrum (docs/algorithms.md §2.4).

    Zero-padded (×16) Hann-window rFFT of the mean-removed coordinates, power summed over the
    axes, with parabolic interpolation of the log-magnitude peak. A peak whose half, third or
    quarter frequency also carries a clear peak (≥ 20% of its magnitude) is taken as a harmonic
    of that lower frequency, so a figure-eight is not read at twice its rate. T is then refined
    within ±20% by minimising Σ_k ‖x(t_k) − x(t_k + T)‖² over the overlap (docs/algorithms.md
    §2.4), which removes the window's bias at few cycles.

    Args:
        positions: Samples uniform in normalised time t ∈ [0, 1], shape (N, 2), in [m].
        name: The demo's label for error messages.

    Returns:
        Period T in normalised time (1 / T cycles in the demo). No spectral method resolves T
        better than about ±5% when the demo holds one cycle or less.

    Raises:
        DemoError: Non-finite positions or a spectrum without a finite peak (naming the demo).
    """
    x = np.asarray(positions, dtype=np.float64)
    if not np.all(np.isfinite(x)):
        raise DemoError(f"{name} has NaN or infinite positions; no period can be read")
    n = x.shape[0]
    window = np.hanning(n)[:, None]
    n_fft = _PAD_FACTOR * n
    with np.errstate(over="ignore", invalid="ignore"):  # huge values: the DemoError below
        spectrum = np.fft.rfft((x - x.mean(axis=0)) * window, n_fft, axis=0)
        power = np.sum(np.abs(spectrum) ** 2, axis=1)
    magnitude = np.sqrt(power)
    if not np.all(np.isfinite(magnitude)) or float(np.max(magnitude)) <= 0.0:
        raise DemoError(
            f"{name}: its spectrum is flat or not finite (no motion, or values that overflow)"
        )
    lowest = _PAD_FACTOR // 2  # Below half a cycle per window the window itself dominates.
    peak = lowest + int(np.argmax(magnitude[lowest:]))
    for divisor in (4, 3, 2):
        k = round(peak / divisor)
        if k < lowest:
            continue
        lo, hi = max(lowest, k - _PAD_FACTOR // 2), k + _PAD_FACTOR // 2 + 1
        j = lo + int(np.argmax(magnitude[lo:hi]))
        is_local_peak = magnitude[j] >= magnitude[j - 1] and magnitude[j] >= magnitude[j + 1]
        if is_local_peak and magnitude[j] >= 0.2 * magnitude[peak]:
            peak = j
            break
    bin_f = float(peak)
    if 0 < peak < magnitude.size - 1:
        a, b, c = np.log(magnitude[peak - 1 : peak + 2] + 1e-300)
        denom = a - 2 * b + c
        if denom < 0:
            bin_f += 0.5 * (a - c) / denom
    cycles_per_unit = bin_f * (n - 1) / n_fft  # Sample spacing is 1 / (N − 1).
    return _refine_period(x, 1.0 / cycles_per_unit)


def _refine_period(x: FloatArray, period: float) -> float:
    """Refine T within ±20% by minimising the mean of ‖x(t) − x(t + T)‖² over the overlap.

    Left as it is when the overlap would be under 20% of the demo (fewer than 1.25 cycles).
    """
    n = x.shape[0]
    t = np.linspace(0.0, 1.0, n)
    candidates = period * np.linspace(0.8, 1.2, 161)
    candidates = candidates[candidates <= 0.8]
    if candidates.size < 3:
        return period
    cost = np.empty(candidates.size)
    for j, shift in enumerate(candidates):
        inside = t + shift <= 1.0
        moved = np.stack([np.interp(t[inside] + shift, t, x[:, d]) for d in range(2)], axis=1)
        cost[j] = np.mean(np.sum((x[inside] - moved) ** 2, axis=1))
    if not np.all(np.isfinite(cost)):
        return period  # Overflowing costs: keep the spectral estimate.
    j = int(np.argmin(cost))
    if not 0 < j < candidates.size - 1:
        return period  # No interior minimum: keep the spectral estimate.
    a, b, c = cost[j - 1 : j + 2]
    denom = a - 2 * b + c
    offset = 0.5 * (a - c) / denom if denom > 0 else 0.0
    return float(candidates[j] + offset * (candidates[1] - candidates[0]))
