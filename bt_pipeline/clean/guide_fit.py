"""Fit the task's guide shape to a demo: a similarity x ≈ ρ R(θ) g(φ) + t, bounded and robust.

The guide g is the task's canonical shape (:mod:`bt_pipeline.data.shapes`, the shape the app
draws as the guide); θ and ρ are the demonstrator's preference (paper Sec. III-A) relative to it.
The fit is a trimmed iterative-closest-point similarity fit:

1. The demo is resampled by arc length (so pauses do not weigh more than motion).
2. From each of several starting rotations spread over the allowed θ range, and a scale and
   translation from the points' spread and median, it pairs every point with the nearest point
   of the (densely sampled) guide under the current fit, keeps the `trim` share of pairs that
   fit best (approach, retreat and spikes fall out), and re-solves θ, ρ, t by least squares
   along the guide's normals (point-to-tangent, so points slide along the loop and the fit
   converges in a few steps), clipped to the allowed ranges (default θ ∈ [−45°, 45°],
   ρ ∈ [0.5, 2]).
   With θ and ρ both known only the translation is free, and eight more starts lie around the
   points' median, 25 % of the loop's size off (a part of a loop between an approach and a
   retreat has its median off the loop's centre, and one start settled on the retreat).
3. The start with the smallest trimmed residual wins. Within the range the near-symmetric
   shapes' twins (wiping and weaving look the same turned by 180°) are outside the range, so
   the smallest rotation is the one kept.
4. A lopsided loop is then fitted by consensus over half-loop refits, also with the loop held
   at the task plane's origin (:mod:`~bt_pipeline.clean.guide_consensus`, its steps 4-5).

Every loop is bounded (``max_iterations`` per start); a non-finite demo raises DemoError.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import KDTree

from bt_pipeline.clean.guide_consensus import CENTRED_REACH, consensus_fit
from bt_pipeline.clean.similarity import (
    FIT_POINTS,
    GUIDE_POINTS,
    GuideFit,
    PreferenceRange,
    icp,
)
from bt_pipeline.data.loop_shape import LoopShape, arc_length_resample, as_loop
from bt_pipeline.exceptions import DemoError

_COARSE_ITERATIONS = 4  # ICP steps from every start before the best are kept.
_SURVIVORS = 1  # Starts carried on to convergence.
_SHIFT_STARTS = 0.25  # With θ and ρ known, translations this share of the size off start too.


def fit_guide(
    positions: ArrayLike,
    loop: LoopShape | str,
    name: str = "demo",
    *,
    allowed: PreferenceRange | None = None,
    theta_deg: float | None = None,
    rho: float | None = None,
    trim: float = 0.6,
    max_iterations: int = 25,
    initial: GuideFit | None = None,
    consensus: bool = True,
    hint: GuideFit | None = None,
    repeats: bool = False,
    single: bool = False,
) -> GuideFit:
    """Fit the task's guide to a demo by a trimmed similarity ICP (module doc).

    Args:
        positions: The demo (or its loop part), shape (T, 2), in task coordinates [m].
        loop: The loop fitted (a task name: its guide).
        name: The demo's label for error messages.
        allowed: Allowed θ/ρ; defaults to PreferenceRange().
        theta_deg: Known θ [deg]: held fixed.
        rho: Known ρ: held fixed.
        trim: Share of the points kept in each refit (the best-fitting ones).
        max_iterations: Most ICP iterations per start.
        initial: Start from this fit only (a refit of a similar demo).
        hint: Also start from this fit (the demo's own loop aligned to the task's loop).
        consensus: Resolve a lopsided loop by consensus over half-loop refits (step 4).
        repeats: The points are several loops, drift removed, whose departure from the loop
            repeats every loop (:func:`~bt_pipeline.clean.guide_track.repeats_per_loop`).
        single: The points are a single loop that closes on itself
            (:mod:`~bt_pipeline.clean.span_fit`, step 3): held as `repeats` is, and judged
            over the fits' best 30 %.

    Raises:
        DemoError: Non-finite positions or no motion.
    """
    allowed = allowed or PreferenceRange()
    x = np.asarray(positions, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 2 or x.shape[0] < 3:
        raise DemoError(f"{name}: positions must have shape (T >= 3, 2); got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise DemoError(f"{name} has NaN or infinite positions")
    points = arc_length_resample(x, FIT_POINTS)
    if float(np.max(np.ptp(points, axis=0))) < 1e-3:
        raise DemoError(f"{name} does not move (extent under 1 mm); nothing to fit")
    loop = as_loop(loop)
    guide = loop.points(GUIDE_POINTS)
    tree = KDTree(guide)
    guide_rms = float(np.sqrt(np.mean(np.sum(guide**2, axis=1))))
    centre0 = np.median(points, axis=0)
    spread = float(np.sqrt(np.mean(np.sum((points - centre0) ** 2, axis=1))))
    rho0 = (
        rho
        if rho is not None
        else float(np.clip(spread / guide_rms, allowed.rho_min, allowed.rho_max))
    )
    if theta_deg is not None:
        starts = [float(theta_deg)]
    else:
        span = allowed.theta_max_deg
        starts = list(np.linspace(-span, span, max(3, int(2 * span // 22.5) + 1)))
    keep = max(3, int(trim * points.shape[0]))
    candidates = [(float(start), float(rho0), centre0.copy()) for start in starts]
    if theta_deg is not None and rho is not None:
        # Only the translation is free: start from around the points' median too (a part of a
        # loop between an approach and a retreat has its median off the loop's centre).
        reach = _SHIFT_STARTS * rho * float(np.max(np.ptp(guide, axis=0)))
        candidates += [
            (float(theta_deg), float(rho), centre0 + reach * np.array([math.cos(a), math.sin(a)]))
            for a in np.arange(8) * math.pi / 4.0
        ]
    if initial is not None:
        candidates = [(initial.theta_deg, initial.rho, np.array(initial.translation))]
    elif hint is not None:
        th0 = float(np.clip(hint.theta_deg, -allowed.theta_max_deg, allowed.theta_max_deg))
        r0 = float(np.clip(hint.rho, allowed.rho_min, allowed.rho_max))
        candidates.append(
            (
                th0 if theta_deg is None else float(theta_deg),
                r0 if rho is None else float(rho),
                np.array(hint.translation),
            )
        )
    best: GuideFit | None = None
    # Every start for a few iterations, then the two best to convergence (bounded).
    for budget, survivors in ((_COARSE_ITERATIONS, _SURVIVORS), (max_iterations, 1)):
        fits = []
        for th, r, t in candidates:
            th, r, t, residual = icp(
                points, guide, tree, th, r, t, keep, budget, theta_deg, rho, allowed
            )
            if not math.isfinite(residual):
                raise DemoError(f"{name}: the guide fit diverged (non-finite residual)")
            fits.append((residual + 1e-9 * abs(th), th, r, t, residual))
        fits.sort(key=lambda f: f[0])
        candidates = [(th, r, t) for _, th, r, t, _ in fits[:survivors]]
        _, th, r, t, residual = fits[0]
        best = GuideFit(th, r, t, residual, r * float(np.max(np.ptp(guide, axis=0))), loop)
    assert best is not None  # starts is never empty
    if consensus:  # Resamples the points and rebuilds the tree: cheap next to its fits.
        fixed = {"allowed": allowed, "theta_deg": theta_deg, "rho": rho}
        held = {"repeats": repeats, "single": single}
        best = consensus_fit(x, best, **held, max_iterations=max_iterations, **fixed)
    return best


__all__ = ["CENTRED_REACH", "GuideFit", "PreferenceRange", "consensus_fit", "fit_guide"]
