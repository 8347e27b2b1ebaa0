"""The last step of estimating θ/ρ: a robust least-squares similarity over every sample of the span.

:func:`bt_pipeline.clean.guide_fit.fit_guide` finds the demonstrator's preference (paper
Sec. III-A: rotation θ and scale ρ of the guide) by a trimmed ICP: each refit keeps the 60 % of
the points that lie closest. That makes it robust (an approach, a retreat, spikes and a bulged
side fall out), but on a careful hand with a slow wobble of a few mm the kept 60 % are a biased
share of the loop: the stretches the wobble happened to push outward drop out together, and the
fit follows the rest. On the second generator's wobbly operators (``benchmarks/quality/
bench_operator_sets.py --oracle``) bt's ρ was 2-3 × farther from the truth than the
least-squares similarity with the true correspondences.

:func:`refine_fit` starts from that fit and solves for the similarity over **every** raw
sample of the span (drift removed), pairing each with its nearest point of the fitted guide, in
closed form (x ≈ a q + b in complex numbers, a = ρ e^{iθ}), with Cauchy weights of scale 2.5 ×
the residuals' robust spread (1.4826 × median): a wobble of a few mm keeps its full weight, a
spike or a stretch of approach left in the span counts little. Three pairings, three
reweightings each; bounded, and any non-finite step keeps the fit it started from. The raw
samples, not the analysis clock's: the clock bridges a gap in the samples with a chord that cuts
inside the loop, and the path the ICP fits is lightly smoothed (σ = 0.03 s), which shrinks it.

A lopsided loop's bulge is within that scale too, so an untrimmed fit would be pulled back to the
compromise that the fit's consensus step (:func:`bt_pipeline.clean.guide_consensus._consensus`)
avoided: a refinement that moves θ by more than 3° or ρ by more than 3 % has left the fit's basin
and is not taken. Measured on held-apart seeds (8-23; ``benchmarks/quality/bench_guide_fits.py
--first-seed 8 --seeds 16 --refine-both``), median |Δρ| without → with (wiping, weaving,
pick-and-place): wobbly operators 0.0117 → 0.0077, 0.0139 → 0.0067, 0.0090 → 0.0077; the steady
operator 0.0014 → 0.0003, 0.0028 → 0.0003, 0.0027 → 0.0003; human-style demos that are not
lopsided 0.0014 → 0.0004, 0.0022 → 0.0008, 0.0013 → 0.0007; lopsided ones unchanged. On the
analysis clock's samples instead, and with a hard 60 % trim instead of the weights, it gained
less (docs/quality.md).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import KDTree

from bt_pipeline.clean.guide_fit import GuideFit, PreferenceRange
from bt_pipeline.data.records import FloatArray

_POINTS = 1024  # Guide points for the pairing (< 0.4 mm apart at ρ = 1).
_PAIRINGS = 3  # Nearest-point pairings, each followed by a weighted solve.
_REWEIGHTS = 3  # Cauchy reweightings per pairing.
_CAUCHY = 2.5  # Cauchy scale in robust spreads of the residuals.
_MAX_TURN_DEG = 3.0  # A refinement that turns θ by more than this [deg]
_MAX_SCALE = 0.03  # or changes ρ by more than this share has left the fit's basin.
_KEEP = 0.6  # The refined fit's residual: mean of this share of smallest distances (as ICP's).


def refine_fit(
    positions: FloatArray,
    fit: GuideFit,
    allowed: PreferenceRange | None = None,
    theta_deg: float | None = None,
    rho: float | None = None,
) -> GuideFit:
    """The similarity fitted to every sample with robust weights, from `fit` (module doc).

    Args:
        positions: The span's raw samples, drift removed, shape (T, 2), task coordinates [m].
        fit: The guide fit to start from (the trimmed ICP's).
        allowed: Allowed θ/ρ; defaults to PreferenceRange().
        theta_deg: Known θ [deg]: held fixed.
        rho: Known ρ: held fixed.

    Returns:
        The refined fit, or `fit` itself when both θ and ρ are known, the samples are too few,
        a step is not finite, or the refinement moved θ or ρ beyond the basin bounds.
    """
    allowed = allowed or PreferenceRange()
    y = np.asarray(positions, dtype=np.float64)
    if (theta_deg is not None and rho is not None) or y.ndim != 2 or y.shape[0] < 8:
        return fit
    if not np.all(np.isfinite(y)):
        return fit
    canonical = fit.loop.points(_POINTS)
    zy = y[:, 0] + 1j * y[:, 1]
    th, r, t = fit.theta_deg, fit.rho, np.asarray(fit.translation, dtype=np.float64)
    for _ in range(_PAIRINGS):
        guide = GuideFit(th, r, t, fit.residual_m, fit.size_m, fit.loop).guide(_POINTS)
        nearest = np.asarray(KDTree(guide).query(y)[1], dtype=np.intp)
        zq = canonical[nearest, 0] + 1j * canonical[nearest, 1]
        step = _weighted_similarity(zq, zy, allowed, theta_deg, rho)
        if step is None:
            return fit
        th, r, t = step
    if abs(th - fit.theta_deg) > _MAX_TURN_DEG or abs(r / fit.rho - 1.0) > _MAX_SCALE:
        return fit
    refined = GuideFit(th, r, t, 0.0, fit.size_m * r / fit.rho, fit.loop)
    distance = np.asarray(KDTree(refined.guide(_POINTS)).query(y)[0])
    keep = max(1, int(_KEEP * distance.size))
    residual = float(np.mean(np.partition(distance, keep - 1)[:keep]))
    return GuideFit(th, r, t, residual, refined.size_m, fit.loop)


def _weighted_similarity(
    zq: np.ndarray,
    zy: np.ndarray,
    allowed: PreferenceRange,
    theta_fixed: float | None,
    rho_fixed: float | None,
) -> tuple[float, float, FloatArray] | None:
    """θ [deg], ρ and t of zy ≈ ρ e^{iθ} zq + t by Cauchy-reweighted least squares, clipped to
    the allowed range (or held fixed); None when a step is not finite."""
    weight = np.ones(zq.size)
    th = r = 0.0
    shift = 0j
    for _ in range(_REWEIGHTS):
        total = float(weight.sum())
        if not total > 0.0:
            return None
        mq, my = np.sum(weight * zq) / total, np.sum(weight * zy) / total
        dq, dy = zq - mq, zy - my
        cross = complex(np.sum(weight * np.conj(dq) * dy))
        power = float(np.sum(weight * np.abs(dq) ** 2))
        if not (power > 0.0 and math.isfinite(cross.real) and math.isfinite(cross.imag)):
            return None
        th = (
            theta_fixed
            if theta_fixed is not None
            else math.degrees(math.atan2(cross.imag, cross.real))
        )
        th = float(np.clip(th, -allowed.theta_max_deg, allowed.theta_max_deg))
        turn = complex(math.cos(math.radians(th)), math.sin(math.radians(th)))
        if rho_fixed is not None:
            r = float(rho_fixed)
        else:
            r = float(np.clip((cross / turn).real / power, allowed.rho_min, allowed.rho_max))
        a = r * turn
        shift = complex(my - a * mq)
        residual = np.abs(zy - a * zq - shift)
        scale = _CAUCHY * 1.4826 * float(np.median(residual)) + 1e-9
        weight = 1.0 / (1.0 + (residual / scale) ** 2)
    if not (math.isfinite(th) and math.isfinite(r) and math.isfinite(shift.real)):
        return None
    return th, r, np.array([shift.real, shift.imag])
