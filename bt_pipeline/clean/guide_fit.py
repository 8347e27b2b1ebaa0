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
   as they follow a guide. What each rule gained and cost on three kinds of data:
   docs/quality.md.

Every loop is bounded (``max_iterations`` per start); a non-finite demo raises DemoError.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import KDTree

from bt_pipeline.clean.similarity import solve_similarity, transform
from bt_pipeline.data.loop_shape import LoopShape, arc_length_resample, as_loop
from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError, DemoError

_GUIDE_POINTS = 1024  # Dense guide for nearest-point pairing (< 0.4 mm spacing).
_FIT_POINTS = 240  # Arc-length resampled demo points used by the fit.
_COARSE_ITERATIONS = 4  # ICP steps from every start before the best are kept.
_SURVIVORS = 1  # Starts carried on to convergence.
_LOPSIDED = 0.005  # Consensus only when 90 % of the points lie this share of the size off.
_CONSENSUS_KEEP = 0.4  # Fits are compared by the mean of their 40 % smallest distances.
_HALF_TRIM = 0.9  # Share of a half's points kept by its refit.
_CONSENSUS_TIE = 2.0  # Fits within this factor of the lowest cost are modes (see _BULGE),
_CONSENSUS_FLOOR_M = 0.0005  # or within this of it [m] (a clean loop's costs are near 0).
_BULGE = 0.06  # The smallest mode wins when its ρ is this share below the median mode's.
CENTRED_REACH = 0.15  # Centred fits alone count when the fit's centre is this share of the
_CENTRED_SLACK = 3.0  # size from the origin or nearer and they fit within this factor as well;
_PLACED_SLACK = 1.5  # Against a best demo's placed loop, this factor (module doc, step 5).
_CENTRED_BULGE = 0.03  # then the smallest mode wins when its ρ is this share below the median's.
_SHIFT_STARTS = 0.25  # With θ and ρ known, translations this share of the size off start too.
_CENTRED_OFF = 0.05  # A close fit this share of its size off the origin is checked (see reach).
_THIN = 0.2  # A loop thinner than this (principal spreads' ratio) keeps its plain fit.


@dataclass(frozen=True)
class PreferenceRange:
    """Allowed demonstrator preferences for estimation (``bt clean`` flags)."""

    theta_max_deg: float = 45.0
    """|θ| ≤ this [deg]."""
    rho_min: float = 0.5
    """Smallest ρ."""
    rho_max: float = 2.0
    """Largest ρ."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.theta_max_deg) and 0.0 <= self.theta_max_deg <= 180.0):
            raise ConfigError(f"theta range must be in [0, 180] deg; got {self.theta_max_deg}")
        if not (0.0 < self.rho_min <= self.rho_max < math.inf):
            raise ConfigError(
                f"rho range must satisfy 0 < min <= max; got {self.rho_min}..{self.rho_max}"
            )


@dataclass(frozen=True)
class GuideFit:
    """A similarity fit of the guide to a demo."""

    theta_deg: float
    """θ [deg], counter-clockwise, within the allowed range."""
    rho: float
    """ρ, within the allowed range."""
    translation: FloatArray
    """t, shape (2,), in [m]: where the guide's centre sits."""
    residual_m: float
    """Mean distance of the kept (trimmed) points to the fitted guide [m]."""
    size_m: float
    """The fitted guide's size, the larger side of its bounding box [m]."""
    loop: LoopShape
    """The loop fitted: the task's guide or the loop learned from the task's demos."""

    def guide(self, n: int = _GUIDE_POINTS) -> FloatArray:
        """The fitted loop, `n` points of one loop, shape (n, 2), in [m]."""
        return transform(self.loop.points(n), self.theta_deg, self.rho, self.translation)


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

    Raises:
        DemoError: Non-finite positions or no motion.
    """
    allowed = allowed or PreferenceRange()
    x = np.asarray(positions, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 2 or x.shape[0] < 3:
        raise DemoError(f"{name}: positions must have shape (T >= 3, 2); got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise DemoError(f"{name} has NaN or infinite positions")
    points = arc_length_resample(x, _FIT_POINTS)
    if float(np.max(np.ptp(points, axis=0))) < 1e-3:
        raise DemoError(f"{name} does not move (extent under 1 mm); nothing to fit")
    loop = as_loop(loop)
    guide = loop.points(_GUIDE_POINTS)
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
            th, r, t, residual = _icp(
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
        best = consensus_fit(x, best, repeats=repeats, max_iterations=max_iterations, **fixed)
    return best


def consensus_fit(
    positions: ArrayLike,
    fit: GuideFit,
    *,
    allowed: PreferenceRange | None = None,
    theta_deg: float | None = None,
    rho: float | None = None,
    repeats: bool = False,
    max_iterations: int = 25,
) -> GuideFit:
    """What :func:`fit_guide` returns from its plain fit `fit` (``consensus=False``) of the
    same `positions`: the consensus of step 4 when θ or ρ is free, without fitting again."""
    if theta_deg is not None and rho is not None:
        return fit
    points = arc_length_resample(np.asarray(positions, dtype=np.float64), _FIT_POINTS)
    guide = fit.loop.points(_GUIDE_POINTS)
    free = (theta_deg, rho, allowed or PreferenceRange(), max_iterations, repeats)
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
    if _aspect(guide) < _THIN:
        # A stretch of a near-line is a shorter near-line: each half of a thin stroke is fitted
        # closely by a shorter stroke, and the smallest mode took half its length (the second
        # generator's strokes, θ/ρ hidden: 1.59 x their raw error; 0.91 with the plain fit).
        return fit
    size = float(np.max(np.ptp(guide, axis=0)))
    n = points.shape[0]
    keep = max(3, int(_CONSENSUS_KEEP * n))
    off = float(np.linalg.norm(fit.translation))
    # Centred fits only for a loop the demos turn about the plane's origin: a guide, drawn
    # there, or the best demo's loop kept where that demo drew it.
    anchored = fit.loop.anchored
    if _trimmed_cost(points, tree, fit, int(0.9 * n)) < _LOPSIDED * fit.size_m and not (
        anchored and _CENTRED_OFF * fit.size_m < off <= CENTRED_REACH * fit.size_m
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
            th, r, t, residual = _icp(
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
            th, r, t, residual = _icp(
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
        <= (_CENTRED_SLACK if loop.is_guide or loop.near_guide or repeats else _PLACED_SLACK)
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


def _aspect(points: FloatArray) -> float:
    """The loop's thickness: the ratio of its principal spreads (1 round, 0 a line)."""
    spread = np.linalg.eigvalsh(np.cov((points - points.mean(axis=0)).T))
    return float(np.sqrt(max(spread[0], 0.0) / max(spread[1], 1e-300)))


def _icp(
    points: FloatArray,
    guide: FloatArray,
    tree: KDTree,
    th: float,
    r: float,
    t: FloatArray,
    keep: int,
    iterations: int,
    theta_fixed: float | None,
    rho_fixed: float | None,
    allowed: PreferenceRange,
    centred: bool = False,
) -> tuple[float, float, FloatArray, float]:
    """At most `iterations` trimmed ICP steps from (θ, ρ, t); returns the fit and its residual.

    With `centred`, t is held at 0 (the guide's centre on the task plane's origin).
    """
    residual = math.inf
    for _ in range(iterations):
        local = transform(points - t, -th, 1.0, np.zeros(2)) / r  # R(−θ)(p − t)/ρ
        dist, found = tree.query(local)
        dist, index = np.asarray(dist, dtype=np.float64), np.asarray(found, dtype=np.intp)
        order = np.argpartition(dist, keep - 1)[:keep]
        residual = float(np.mean(dist[order]) * r)
        g = index[order]
        tangent = guide[(g + 1) % guide.shape[0]] - guide[(g - 1) % guide.shape[0]]
        normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
        normal /= np.linalg.norm(normal, axis=1, keepdims=True) + 1e-15
        th_new, r_new, t_new = solve_similarity(
            points[order], guide[g], normal, th, r, theta_fixed, rho_fixed, allowed, centred
        )
        moved = abs(th_new - th) / 90.0 + abs(r_new - r) + float(np.linalg.norm(t_new - t))
        th, r, t = th_new, r_new, t_new
        if moved < 1e-6 or not math.isfinite(residual):
            break
    return th, r, t, residual
