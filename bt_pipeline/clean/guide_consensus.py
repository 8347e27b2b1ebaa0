"""The consensus step of the guide fit: a lopsided loop read at the size of its unbulged side.

:func:`~bt_pipeline.clean.guide_fit.fit_guide` ends here (and
:mod:`~bt_pipeline.clean.span_fit` calls :func:`consensus_fit` on a span's plain fit). Steps 1-3
are the plain fit's (guide_fit module doc).

4. A lopsided loop (one side drawn bigger; 90 % of the points lie on average more than 0.5 % of
   the size off the fit) is fitted by consensus over half-loop refits, also with the guide
   centred on the task plane's origin (where the app draws it): of the about equally good
   modes, the smallest ρ when it is more than 6 % below the median mode's (a bulge), else the
   median mode (:func:`_consensus`; always the smallest read wobbly hands' ρ too small). A thin
   loop (principal spreads' ratio under 0.2: a back-and-forth stroke) skips this: each half of a
   near-line is fitted closely by a shorter one, and the smallest mode took half its length.
5. When that loop's fit lies near the plane's origin (within 15 % of its size) and the best
   centred fit costs at most 3 x the best free one, only the centred fits are modes: a lopsided
   arch's shifted compromise no longer outweighs them. Among the centred modes the smallest
   wins from 3 % below the median mode (they hold no shifted compromise between the two
   sides). The best demo's loop kept where that demo drew it (``LoopShape.placed``,
   :mod:`~bt_pipeline.clean.best_loop`) is centred the same way, its origin being where the
   demos turn it, within 1.5 x instead of 3 x: a drifting single loop or a wobbly hand fits
   1.5-3 x worse held there. Over several loops, their drift removed first, a departure from
   the loop that repeats every loop (its 90th percentile over 2 x the median distance of the
   path to itself one loop on, ``repeats``) is a shape the hand meant, such as a bulged side,
   and the 3 x holds (a lopsided loop fits 1.5-2.6 x worse held at the origin, and fitted free
   of it was read 10-17 % too big); a wobble does not repeat. A best demo's loop that replaced
   a guide it lies near (``LoopShape.near_guide``) takes the guide's 3 x: its demos follow it
   as they follow a guide. A single loop that closes on itself (``single``,
   :mod:`~bt_pipeline.clean.span_fit`) is held at the origin within 3 x too, and its fits are
   compared over their best 30 % instead of 40 %: a side bulged 20-35 % with a smooth edge
   leaves only a quarter to a third of the samples on the loop meant, the bulged side, drawn
   bigger, holds more, and over 40 % its fit won. What each rule gained and cost on three kinds
   of data: docs/quality.md.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import KDTree

from bt_pipeline.clean.phase_track import THIN, loop_aspect
from bt_pipeline.clean.similarity import (
    FIT_POINTS,
    GUIDE_POINTS,
    GuideFit,
    PreferenceRange,
    icp,
    transform,
)
from bt_pipeline.data.loop_shape import arc_length_resample
from bt_pipeline.data.records import FloatArray

_LOPSIDED = 0.005  # Consensus only when 90 % of the points lie this share of the size off.
_CONSENSUS_KEEP = 0.4  # Fits are compared by the mean of their 40 % smallest distances,
_SINGLE_KEEP = 0.3  # or 30 % in a single loop that closes (``single``; module doc, step 5).
_HALF_TRIM = 0.9  # Share of a half's points kept by its refit.
_CONSENSUS_TIE = 2.0  # Fits within this factor of the lowest cost are modes (see _BULGE),
_CONSENSUS_FLOOR_M = 0.0005  # or within this of it [m] (a clean loop's costs are near 0).
_BULGE = 0.06  # The smallest mode wins when its ρ is this share below the median mode's.
CENTRED_REACH = 0.15  # Centred fits alone count when the fit's centre is this share of the
_CENTRED_SLACK = 3.0  # size from the origin or nearer and they fit within this factor as well;
_PLACED_SLACK = 1.5  # Against a best demo's placed loop, this factor (module doc, step 5).
_CENTRED_BULGE = 0.03  # then the smallest mode wins when its ρ is this share below the median's.
_CENTRED_OFF = 0.05  # A close fit this share of its size off the origin is checked (see reach).


def consensus_fit(
    positions: ArrayLike,
    fit: GuideFit,
    *,
    allowed: PreferenceRange | None = None,
    theta_deg: float | None = None,
    rho: float | None = None,
    repeats: bool = False,
    single: bool = False,
    max_iterations: int = 25,
) -> GuideFit:
    """What :func:`~bt_pipeline.clean.guide_fit.fit_guide` returns from its plain fit `fit`
    (``consensus=False``) of the same `positions`: the consensus of step 4 when θ or ρ is free,
    without fitting again."""
    if theta_deg is not None and rho is not None:
        return fit
    points = arc_length_resample(np.asarray(positions, dtype=np.float64), FIT_POINTS)
    guide = fit.loop.points(GUIDE_POINTS)
    free = (theta_deg, rho, allowed or PreferenceRange(), max_iterations, repeats, single)
    return _consensus(points, guide, KDTree(guide), fit, *free)


def _trimmed_cost(points: FloatArray, tree: KDTree, fit: GuideFit, keep: int) -> float:
    """Mean of the `keep` smallest distances of the points to the fitted guide [m]."""
    local = transform(points - fit.translation, -fit.theta_deg, 1.0, np.zeros(2)) / fit.rho
    dist = np.asarray(tree.query(local)[0]) * fit.rho
    return float(np.mean(np.partition(dist, keep - 1)[:keep]))


def _consensus(
    points: FloatArray,
    guide: FloatArray,
    tree: KDTree,
    fit: GuideFit,
    theta_fixed: float | None,
    rho_fixed: float | None,
    allowed: PreferenceRange,
    max_iterations: int,
    repeats: bool = False,
    single: bool = False,
) -> GuideFit:
    """The fit that one half of the loop follows closely, when the other half is misshapen.

    A loop drawn bigger on one side (lopsided) pulls a least-squares fit (even a trimmed one)
    to a compromise that fits neither side. The guide is fitted again to each half of the
    points (left, right, upper, lower in the compromise's frame, 90 % trim), and from each
    half's fit a least-trimmed fit to all points (the 40 % that fit best) follows whichever
    part of the loop matches the guide; the same fits are also run with the guide centred on
    the plane's origin (t = 0, where the app draws it: on an arch a bulged side is nearly a
    shifted similarity of the whole guide, so free fits settle on the compromise). Each fit is
    judged by the mean of its smallest distances over 40 % of the points times √(ρ / the fits'
    median ρ) (a bigger fit is followed by more arc-length samples, which had favoured a bulged
    side's fit). The fits within max(2 x, + 0.5 mm) of the lowest cost are the modes. When the
    smallest ρ among them lies more than 6 % below the median mode's, it wins: a misshapen side
    is taken to bulge out, not to be pinched in (both are exact similarities of half the guide,
    so one demo alone cannot tell them apart; pooling a demonstrator's demos helps). Otherwise
    the median mode wins: a wobbly hand, or a robot that cuts corners, scatters the modes by a
    few % around the loop it meant. When the loop's fit lies within 15 % of its size of the
    origin and the best centred fit costs at most 3 x the best free one, the centred fits alone
    are modes, and the smallest wins from 3 % below the median (no compromise sits between the
    sides' fits any more); a loop far from the origin (an imported file's origin is the mean of
    its samples) or one that fits it far worse (a drifting single loop, a hand drawn
    off-centre) keeps every fit. A fit that 90 % of the loop follows closely skips all this
    unless it lies 5-15 % of its size off the origin (an arch's bulged side alone is followed
    that closely by a fit shifted that much). On a loop without a defect every fit lands on the
    same mode and nothing changes.
    """
    if loop_aspect(guide) < THIN:  # A thin loop keeps its plain fit.
        # A stretch of a near-line is a shorter near-line: each half of a thin stroke is fitted
        # closely by a shorter stroke, and the smallest mode took half its length (the second
        # generator's strokes, θ/ρ hidden: 1.59 x their raw error; 0.91 with the plain fit).
        return fit
    size = float(np.max(np.ptp(guide, axis=0)))
    n = points.shape[0]
    keep = max(3, int((_SINGLE_KEEP if single else _CONSENSUS_KEEP) * n))
    off = float(np.linalg.norm(fit.translation))
    # Centred fits only for a loop the demos turn about the plane's origin: a guide, drawn
    # there, or the best demo's loop kept where that demo drew it.
    anchored = fit.loop.anchored
    if (
        not repeats
        and _trimmed_cost(points, tree, fit, int(0.9 * n)) < _LOPSIDED * fit.size_m
        and not (anchored and _CENTRED_OFF * fit.size_m < off <= CENTRED_REACH * fit.size_m)
    ):
        return fit  # 90 % of the loop lies close to a fit where it is drawn: nothing misshapen.
    local = transform(points - fit.translation, -fit.theta_deg, 1.0, np.zeros(2))
    halves = [points[side * local[:, axis] > 0.0] for axis in range(2) for side in (-1.0, 1.0)]
    fits: list[tuple[GuideFit, bool]] = []  # (fit, centred on the origin)
    for centred in (False, True) if anchored else (False,):
        starts = [(fit.theta_deg, fit.rho, np.zeros(2))] if centred else []
        for half in halves:
            if half.shape[0] < 12:
                continue
            th, r, t, residual = icp(
                half,
                guide,
                tree,
                fit.theta_deg,
                fit.rho,
                np.zeros(2) if centred else np.array(fit.translation),
                max(3, int(_HALF_TRIM * half.shape[0])),
                max_iterations,
                theta_fixed,
                rho_fixed,
                allowed,
                centred,
            )
            if math.isfinite(residual):
                starts.append((th, r, t))
        for th, r, t in starts:
            # From the half's fit, the least-trimmed fit to all points (40 %): it settles on
            # whichever part of the loop follows the guide closely.
            th, r, t, residual = icp(
                points,
                guide,
                tree,
                th,
                r,
                t,
                keep,
                max_iterations,
                theta_fixed,
                rho_fixed,
                allowed,
                centred,
            )
            if math.isfinite(residual):
                fits.append((GuideFit(th, r, t, residual, r * size, fit.loop), centred))
    fits.append((fit, False))
    # About the same share of each fit's own guide (√ ρ: the full ratio read wobbly loops small).
    ref = float(np.median([f.rho for f, _ in fits]))
    found = [
        (_trimmed_cost(points, tree, f, int(min(keep * math.sqrt(f.rho / ref), 0.8 * n))), f, c)
        for f, c in fits
    ]
    loop = fit.loop
    centred_costs = [c for c, _, centred in found if centred]
    free_low = min(c for c, _, centred in found if not centred)
    if (
        off <= CENTRED_REACH * fit.size_m
        and centred_costs
        and min(centred_costs)
        <= (
            _CENTRED_SLACK
            if loop.is_guide or loop.near_guide or repeats or single
            else _PLACED_SLACK
        )
        * free_low
    ):
        # The loop is centred where the app draws the guide: only centred fits count.
        found = [f for f in found if f[2]]
        bulge = _CENTRED_BULGE
    else:
        bulge = _BULGE
    low = min(c for c, _, _ in found)
    tie = max(_CONSENSUS_TIE * low, low + _CONSENSUS_FLOOR_M)
    modes = sorted((f for c, f, _ in found if c <= tie), key=lambda f: f.rho)
    middle = modes[(len(modes) - 1) // 2]
    return modes[0] if modes[0].rho < (1.0 - bulge) * middle.rho else middle


__all__ = ["CENTRED_REACH", "consensus_fit"]
