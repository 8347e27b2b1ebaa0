"""Following a demo along its fitted guide: phase track, nearest points, drift, direction.

The primitives :mod:`bt_pipeline.clean.segment` builds the kept span from, each relative to a
closed guide loop sampled once round (P points, endpoint excluded) in task coordinates [m]:

* :func:`track_phase`: the continuous phase of each sample along the loop (its own module,
  :mod:`~bt_pipeline.clean.phase_track`, re-exported here);
* :func:`nearest_index` / :func:`nearest_distance`: each sample's nearest guide point;
* :func:`drift_along`: a slow translation of the guide over time that fits the samples;
* :func:`periodic_drift` (degree from :func:`periodic_degree`): a slow translation over time
  that is not periodic in the phase, whatever the loop's shape;
* :func:`along_guide` / :func:`tangential`: whether each sample moves along the guide;
* :func:`runs_of`: runs of flagged samples;
* :func:`travel`: where a span travels along the loop (its slow ends cut);
* :func:`trim_raw_ends`: a span's raw ends moved in past samples off the guide.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.spatial import KDTree

from bt_pipeline.clean.phase_track import track_phase
from bt_pipeline.data.records import FloatArray

_DRIFT_SCALE_M = 0.003  # Cauchy scale of the drift fit's reweighting [m].
_HARMONICS = 6  # Fourier harmonics of the loop in the periodic model of the drift.
_PERIODIC_REWEIGHTS = 4  # Cauchy reweightings of the periodic model,
_PERIODIC_CAUCHY = 2.5  # at this many robust spreads of its residuals.
_LOOP_POINTS = 512  # Points of the periodic model's loop that the phase is read again against.
_PERIODIC_MAX_DEGREE = 2  # Highest degree of the span's drift (periodic_drift),
_PERIODIC_MIN_CYCLES = 1.5  # estimated in spans of at least this many loops.
_KEEPS_GOING = 0.9  # A drift whose end is this share of its farthest reach keeps its direction.
_SPEED_SMOOTH_S = 0.05  # Gaussian σ of the phase before its speed is read [s].
_TRAVEL_SHARE = 0.45  # The span travels faster than this share of its typical phase speed,
_TRAVEL_MIN_SHARE = 0.2  # or than this share where the slower edge travels more than
_TRAVEL_MAX_TRIM = 0.15  # this many loops (a hesitant loop, not an approach).
_EDGE_MEDIANS = 4.0  # A raw end sample farther off the guide than this many medians of the
_EDGE_P95S = 1.5  # span's middle distances, this many 95th percentiles
_EDGE_MIN_M = 0.0005  # and this [m] is off (trim_raw_ends),
_EDGE_MAX_SHARE = 0.25  # at most this share of the span at each end,
_EDGE_CLOSE_M = 0.001  # and in a single loop only if its middle's 95th percentile is this [m].
_REPEATS = 2.0  # A departure from the fit this many times the path's distance to itself a loop
# on repeats per loop (repeats_per_loop).


def travel(phase: FloatArray, p: int, clock_hz: float = 50.0) -> tuple[int, int]:
    """First and last index of a span's travel along the loop (segment.py, step 5).

    The phase speed (σ = 0.05 s, in the direction of travel) is compared with the span's
    typical speed (its 75th percentile, so pauses do not lower it). The span starts at the
    first sample faster than 45 % of that, unless the slower part before it already travels
    more than 15 % of a loop (a hesitant first loop, not an approach): then at the first
    sample faster than 20 %. The end likewise. The slow end of an approach that creeps onto
    the guide, a rest on the loop and the slow start of a retreat fall out; pauses between
    loops stay.
    """
    sign = 1.0 if phase[-1] >= phase[0] else -1.0
    travelled = sign * (phase - phase[0]) / p  # Loops.
    speed = np.gradient(gaussian_filter1d(travelled, _SPEED_SMOOTH_S * clock_hz))
    typical = float(np.percentile(speed, 75))
    if typical <= 0.0:
        return 0, phase.size - 1
    fast = np.flatnonzero(speed > _TRAVEL_SHARE * typical)
    moving = np.flatnonzero(speed > _TRAVEL_MIN_SHARE * typical)
    if fast.size < 2 or moving.size < 2:
        return 0, phase.size - 1
    head, tail = int(fast[0]), int(fast[-1])
    if travelled[head] - travelled[moving[0]] > _TRAVEL_MAX_TRIM:
        head = int(moving[0])
    if travelled[moving[-1]] - travelled[tail] > _TRAVEL_MAX_TRIM:
        tail = int(moving[-1])
    return head, tail


def drift_along(path: FloatArray, guide: FloatArray, on: np.ndarray, degree: int) -> FloatArray:
    """Slow drift: a smooth translation of the guide over time that best fits the samples.

    The drift is a polynomial in time of `degree` (loops − 1, at most 4; none for one loop,
    which cannot tell a drift from a shape error), fitted by
    point-to-tangent least squares: each sample pulls the guide along the normal at its nearest
    guide point, so a hand that drifts sideways is followed in every direction. Three
    reweighted passes (Cauchy weights, scale 3 mm; nearest points found again each time) make
    the samples that do not follow the loop (approach, retreat, excursions) count little, and
    only samples within twice the tolerance (`on`) take part at all.

    Returns:
        The drift of each sample, shape (T, 2), in [m].
    """
    drift = np.zeros_like(path)
    if int(on.sum()) < 8 or degree < 1:
        return drift
    u = np.linspace(-1.0, 1.0, path.shape[0])
    basis = np.polynomial.legendre.legvander(u, degree)  # (T, K)
    p = guide.shape[0]
    weight = on.astype(np.float64)
    for _ in range(3):
        nearest = nearest_index(guide, path - drift)
        tangent = guide[(nearest + 1) % p] - guide[(nearest - 1) % p]
        normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
        normal /= np.linalg.norm(normal, axis=1, keepdims=True) + 1e-15
        target = np.sum(normal * (path - guide[nearest]), axis=1)
        rows = (basis[:, :, None] * normal[:, None, :]).reshape(path.shape[0], -1)  # (T, 2K)
        w = weight / (1.0 + ((target - np.sum(normal * drift, axis=1)) / _DRIFT_SCALE_M) ** 2)
        gram = rows.T @ (w[:, None] * rows) + 1e-6 * np.eye(rows.shape[1])
        coef = np.linalg.solve(gram, rows.T @ (w * target))
        drift = basis @ coef.reshape(-1, 2)
    return drift


def periodic_degree(cycles: float) -> int:
    """The span's drift degree: none under 1.5 loops (on the second generator's single loops
    the periodic model read 20-50 mm of drift that was not there), else one per loop beyond the
    first, at most 2 (a higher degree let a span's ragged first half-loop pose as drift)."""
    if cycles < _PERIODIC_MIN_CYCLES:
        return 0
    return min(_PERIODIC_MAX_DEGREE, int(cycles + 0.5) - 1)


def periodic_drift(path: FloatArray, phase: FloatArray, degree: int) -> FloatArray:
    """Slow drift as the part of the path that does not repeat from loop to loop.

    The path is modelled as a loop of any shape, a Fourier series in the tracked phase
    (:data:`_HARMONICS` harmonics), plus a polynomial in time of `degree` without its constant
    term, solved by linear least squares with Cauchy reweighting (scale 2.5 x the residuals'
    robust spread, four passes, so spikes and a stretch of approach count little). The loop's
    shape never enters: a bulged side, a wrong θ/ρ or a corner cut the same way every loop
    repeats and is not taken for drift, which :func:`drift_along`, fitted against the guide,
    could not tell apart.

    The constant is not in the data (a loop drawn off-centre and a drift look alike), so the
    drift is anchored by its course. One that keeps its direction (its end is its farthest point
    from its start, within 10 %) is a hand wandering off from where it began, on the guide: it is
    zero at the first sample. One that turns back is a sway about the path: zero on average.
    Anchored at the mean always, hidden θ within 5° and ρ within 0.05 fell from 93 to 86 %
    (wiping) and 90 to 84 % (pick-and-place) on human-style sets; at the start always, the
    second generator's wobbly hands fell from 96-98 % to 93-96 % (docs/quality.md).

    Args:
        path: The span, shape (T, 2), in [m], on a uniform clock.
        phase: Its tracked phase in loops, shape (T,) (:func:`track_phase` / P).
        degree: Degree of the drift polynomial; 0 (or too few samples) gives no drift.

    Returns:
        The drift of each sample, shape (T, 2), in [m].
    """
    if degree < 1 or path.shape[0] < 4 * (1 + 2 * _HARMONICS + degree):
        return np.zeros_like(path)
    time = np.linspace(-1.0, 1.0, path.shape[0])
    slow = np.asarray(np.polynomial.legendre.legvander(time, degree)[:, 1:], dtype=np.float64)
    loop, drift = _loop_and_drift(path, np.asarray(phase, dtype=np.float64), slow)
    # The phase read again against the loop just found: a guide fit that is off (the moving
    # part's, on a fast figure-eight) bends the first track differently loop by loop, and a
    # steady hand read 4 mm of drift that was not there (1.5 mm after).
    points = loop.shape[0]
    loop, drift = _loop_and_drift(path, track_phase(path - drift, loop) / points, slow)
    away = np.linalg.norm(drift - drift[0], axis=1)
    keeps_going = float(away[-1]) >= _KEEPS_GOING * float(away.max())
    return drift - (drift[0] if keeps_going else drift.mean(axis=0))


def _loop_and_drift(
    path: FloatArray, phase: FloatArray, slow: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The periodic model of :func:`periodic_drift` solved once: the loop it found (512 points
    at uniform phase) and the drift (`slow` columns' part), by Cauchy-reweighted least squares."""
    harmonics = np.arange(1, _HARMONICS + 1)[None, :]

    def basis(angle: FloatArray) -> FloatArray:
        return np.concatenate(
            [
                np.ones((angle.size, 1)),
                np.cos(harmonics * angle[:, None]),
                np.sin(harmonics * angle[:, None]),
            ],
            1,
        )

    periodic = basis(2.0 * np.pi * phase)
    design = np.concatenate([periodic, slow], axis=1)
    weight = np.ones(path.shape[0])
    coef = np.zeros((design.shape[1], 2))
    for _ in range(_PERIODIC_REWEIGHTS):
        # Normal equations (17-19 unknowns; lstsq's SVD cost 6 ms a solve, this 0.1 ms).
        weighted = design * weight[:, None]
        gram = design.T @ weighted + 1e-9 * np.eye(design.shape[1])
        coef = np.linalg.solve(gram, weighted.T @ path)
        residual = np.linalg.norm(path - design @ coef, axis=1)
        scale = _PERIODIC_CAUCHY * 1.4826 * float(np.median(residual)) + 1e-12
        weight = 1.0 / (1.0 + (residual / scale) ** 2)
    columns = periodic.shape[1]
    ring = basis(2.0 * np.pi * np.arange(_LOOP_POINTS) / _LOOP_POINTS) @ coef[:columns]
    return ring, slow @ coef[columns:]


def along_guide(path: FloatArray, guide: FloatArray, nearest: np.ndarray) -> np.ndarray:
    """Whether each sample moves along the guide (|cos| ≥ 0.7 to its tangent) or nearly rests."""
    velocity = np.gradient(path, axis=0)
    p = guide.shape[0]
    tangent = guide[(nearest + 1) % p] - guide[(nearest - 1) % p]
    speed = np.linalg.norm(velocity, axis=1)
    cos = np.abs(np.sum(velocity * tangent, axis=1)) / (
        speed * np.linalg.norm(tangent, axis=1) + 1e-12
    )
    slow = speed < 0.2 * float(np.median(speed))
    return slow | (cos >= 0.7)


def tangential(path: FloatArray, guide: FloatArray) -> np.ndarray:
    """Whether each sample moves along the guide's tangent (|cos| ≥ 0.9) at more than 5 % of
    the path's median speed (a resting hand's jitter has no direction)."""
    nearest = nearest_index(guide, path)
    velocity = np.gradient(gaussian_filter1d(path, 1.0, axis=0, mode="nearest"), axis=0)
    p = guide.shape[0]
    tangent = guide[(nearest + 1) % p] - guide[(nearest - 1) % p]
    speed = np.linalg.norm(velocity, axis=1)
    cos = np.abs(np.sum(velocity * tangent, axis=1)) / (
        speed * np.linalg.norm(tangent, axis=1) + 1e-12
    )
    return (cos >= 0.9) & (speed > 0.05 * float(np.median(speed)))


def nearest_distance(ring: FloatArray, points: FloatArray) -> FloatArray:
    return KDTree(ring).query(points)[0]


def nearest_index(ring: FloatArray, points: FloatArray) -> np.ndarray:
    return np.asarray(KDTree(ring).query(points)[1], dtype=np.intp)


def runs_of(flags: np.ndarray, min_length: int) -> list[tuple[int, int]]:
    """(first, last) index of each run of True at least `min_length` long."""
    padded = np.concatenate([[False], flags, [False]]).astype(np.int8)
    edges = np.diff(padded)
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return [(int(s), int(e)) for s, e in zip(starts, ends, strict=True) if e - s + 1 >= min_length]


def loop_gap(path: FloatArray, phase: FloatArray, overlap: float = 0.0) -> float | None:
    """The path's median distance to itself one loop on [m]: its drift over a loop plus noise
    (None when it goes round less than once plus `overlap` loops).

    Args:
        path: The span, shape (T, 2), in [m].
        phase: Its tracked phase in loops, shape (T,) (either sign).
        overlap: Least phase [loops] the gap is read over.
    """
    ahead = np.asarray(phase, dtype=np.float64)
    ahead = np.maximum.accumulate(ahead if ahead[-1] >= ahead[0] else -ahead)
    looped = ahead + 1.0 <= ahead[-1]
    if not looped.any() or ahead[-1] - ahead[0] < 1.0 + overlap:
        return None
    later = np.stack([np.interp(ahead[looped] + 1.0, ahead, path[:, d]) for d in range(2)], 1)
    return float(np.median(np.linalg.norm(later - path[looped], axis=1)))


def repeats_per_loop(path: FloatArray, phase: FloatArray, distance: FloatArray) -> bool:
    """Whether a span's departure from its fit repeats every loop, as a bulged side does and a
    sway does not: the 90th percentile of its `distance` [m] to the fit is over
    :data:`_REPEATS` x the path's median distance to itself one loop on (:func:`loop_gap`;
    none without a loop).

    Args:
        path: The span, drift removed, shape (T, 2), in [m].
        phase: Its tracked phase in loops, shape (T,) (either sign).
        distance: Each point's distance to the fit, shape (T,), in [m].
    """
    itself = loop_gap(path, phase)
    return itself is not None and float(np.percentile(distance, 90)) > _REPEATS * itself


__all__ = [
    "along_guide",
    "drift_along",
    "loop_gap",
    "nearest_distance",
    "nearest_index",
    "periodic_degree",
    "periodic_drift",
    "repeats_per_loop",
    "runs_of",
    "tangential",
    "track_phase",
    "trim_raw_ends",
]


def trim_raw_ends(
    x: FloatArray,
    t: FloatArray,
    span_clock: FloatArray,
    span_drift: FloatArray,
    guide: FloatArray,
    i0: int,
    i1: int,
    single: bool = False,
) -> tuple[int, int]:
    """The raw span [i0, i1] with each end moved in past raw samples off the fitted guide.

    Step 8 of :mod:`bt_pipeline.clean.segment`.

    Each raw sample's distance to the guide (the span's drift removed) is compared with how
    closely the middle 60 % of the span follows it: end samples farther than
    max(4 x the median, 1.5 x the 95th percentile, 0.5 mm) are off. Each end is cut where the
    samples cut hold the most more off than close (none if no cut does), at most a quarter of
    the span at each end. A `single` loop (under 1.5 loops) only when its middle follows the
    guide within 1 mm (95th percentile; a steady hand): a single loop whose bulged side lies at
    its ends would lose that side (at 6-12 Hz a lopsided pick-and-place loop lost 30 % and
    scored the set's best closure).
    """
    n = i1 - i0 + 1
    if n < 20:
        return i0, i1
    shift = np.stack(
        [np.interp(t[i0 : i1 + 1], span_clock, span_drift[:, d]) for d in range(2)], axis=1
    )
    dist = nearest_distance(guide, x[i0 : i1 + 1] - shift)
    inner = dist[int(0.2 * n) : int(0.8 * n)]
    if single and float(np.percentile(inner, 95)) > _EDGE_CLOSE_M:
        return i0, i1
    threshold = max(
        _EDGE_MEDIANS * float(np.median(inner)),
        _EDGE_P95S * float(np.percentile(inner, 95)),
        _EDGE_MIN_M,
    )
    # Each end is cut where the samples cut are most often off (one off counts +1, one close
    # -1): a retreat that crosses the loop again on its way out keeps no part of its excursion.
    score = np.where(dist > threshold, 1.0, -1.0)
    limit = int(_EDGE_MAX_SHARE * n)
    lo = int(np.argmax(np.concatenate([[0.0], np.cumsum(score[:limit])])))
    hi = n - 1 - int(np.argmax(np.concatenate([[0.0], np.cumsum(score[::-1][:limit])])))
    return i0 + lo, i0 + hi
