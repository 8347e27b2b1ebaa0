"""The continuous phase of a path along a closed loop (:func:`track_phase`).

Each sample takes the nearest loop point near the last sample's, so a track stays on its
branch where a figure-eight crosses itself. On a **thin loop** (a back-and-forth stroke: its
principal spreads' ratio under 0.2) the two strands lie a few mm apart, and where the hand
turns at the stroke's end the nearest point near the last one is still on the strand it came
along: the track then ran back down that strand while the hand went along the other, and the
phase swung to and fro (random strokes, θ/ρ hidden, seeds 24-35: an expert-like demo of one
loop counted 0.17 of a loop, and its kept span took in 2 s of approach). There, a loop point
whose direction along the loop, in the track's sense of travel, runs against the sample's own
velocity is also that far off: its distance counts with (width · (1 − cos))² added, the width
being the loop's (4 × its minor principal spread), for samples that move (over a fifth of the
path's median speed). The loop is tracked in both senses and the track that runs nearest to
the samples wins, as between a crossing's branches.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from bt_pipeline.data.records import FloatArray

_MAX_PHASE_STEP = 0.05  # Most phase change per tracked sample, in loops.
THIN = 0.2
"""A loop whose principal spreads' ratio is under this is thin (a back-and-forth stroke)."""
_MOVING = 0.2  # A sample moves when its speed is over this share of the path's median speed.


def loop_aspect(points: ArrayLike) -> float:
    """A loop's thickness: the ratio of its principal spreads (1 round, 0 a line)."""
    minor, major = _spreads(points)
    return minor / max(major, 1e-150)


def _spreads(points: ArrayLike) -> tuple[float, float]:
    """A loop's principal spreads (standard deviations, minor then major) [m]."""
    p = np.asarray(points, dtype=np.float64)
    variance = np.linalg.eigvalsh(np.cov((p - p.mean(axis=0)).T))
    return float(np.sqrt(max(variance[0], 0.0))), float(np.sqrt(max(variance[1], 0.0)))


def track_phase(
    points: ArrayLike,
    loop: ArrayLike,
    max_step: float = _MAX_PHASE_STEP,
    steps: ArrayLike | None = None,
) -> FloatArray:
    """Continuous phase of each point along a closed loop, by nearest point near the last one.

    The first point takes its nearest loop point; each next point the nearest within
    ±`max_step` loops of the previous phase, so where a loop crosses itself (a figure-eight)
    the track stays on its branch. A first point about as near to several branches (up to 3
    local minima of its distance within max(its nearest distance, 5 % of the loop's extent) of
    it: a figure-eight's crossing) starts a track on each, and the track that runs nearest to
    the points wins: from the crossing the nearest point picked a branch at random, and a
    weaving demo's reference ran 12 cm off its path for 1.6 s. Bounded by 3 passes; a thin
    loop is tracked in each sense of travel too (module doc).

    Args:
        points: Path, shape (T, 2), in [m].
        loop: Closed loop sampled once round (endpoint excluded), shape (P, 2), in [m].
        max_step: Most phase change between consecutive points, in loops.
        steps: How many typical sample intervals lie before each point, shape (T,) (≥ 1; the
            first is unused): the reach grows with them, so a track resumes after a gap in the
            samples. None: one each.

    Returns:
        Unwrapped phase, shape (T,), in loop samples (P per loop; the sign follows the
        direction of travel).
    """
    x = np.asarray(points, dtype=np.float64)
    ring = np.asarray(loop, dtype=np.float64)
    p = ring.shape[0]
    reach = max(1, int(max_step * p))
    scale = np.ones(x.shape[0]) if steps is None else np.maximum(np.asarray(steps, float), 1.0)
    half = np.minimum((reach * scale).astype(np.int64), p // 2)
    half = np.where(half <= reach, reach, half)  # the window's half-width at each point
    # The loop laid out twice (and one more point), so each window, even round the loop's
    # seam, is one slice; the first minimum in the window's order wins, as np.argmin over the
    # candidates ``current + arange(-w, w + 1)`` (mod P) did: the same phase, bit for bit.
    twice = np.concatenate([ring, ring, ring[:1]])
    ring_u, ring_v = twice[:, 0].copy(), twice[:, 1].copy()
    widths, us, vs = half.tolist(), x[:, 0].tolist(), x[:, 1].tolist()
    minor, major = _spreads(ring)
    thin = x.shape[0] > 2 and minor < THIN * major
    along, heading, moving = np.zeros((1, 2)), np.zeros((1, 2)), np.zeros(1, bool)
    width = 4.0 * minor
    if thin:
        along = np.roll(ring, -1, axis=0) - np.roll(ring, 1, axis=0)
        along /= np.maximum(np.linalg.norm(along, axis=1, keepdims=True), 1e-12)
        along = np.concatenate([along, along, along[:1]])
        velocity = np.gradient(x, axis=0)
        speed = np.linalg.norm(velocity, axis=1)
        moving = speed > _MOVING * float(np.median(speed))
        heading = velocity / np.maximum(speed, 1e-12)[:, None]

    def follow(current: int, sense: float = 0.0) -> FloatArray:
        phase = np.empty(x.shape[0])
        phase[0] = current
        for k in range(1, x.shape[0]):
            w = widths[k]
            start = (current - w) % p
            du = ring_u[start : start + 2 * w + 1] - us[k]
            dv = ring_v[start : start + 2 * w + 1] - vs[k]
            cost = du * du + dv * dv
            if sense and moving[k]:
                cos = along[start : start + 2 * w + 1] @ heading[k]
                cost = cost + (width * (1.0 - sense * cos)) ** 2
            current += int(cost.argmin()) - w
            phase[k] = current
        return phase

    senses = (1.0, -1.0) if thin else (0.0,)
    tracks = [follow(start, sense) for start in _branch_starts(ring, x[0]) for sense in senses]
    if len(tracks) == 1:
        return tracks[0]
    return min(
        tracks, key=lambda ph: float(np.mean(np.sum((ring[ph.astype(int) % p] - x) ** 2, 1)))
    )


def _branch_starts(ring: FloatArray, first: FloatArray) -> list[int]:
    """Loop points where a track from `first` may start: its nearest, then up to two more local
    minima of the distance about as near (track_phase)."""
    d = np.sqrt(np.sum((ring - first) ** 2, axis=1))
    nearest = int(np.argmin(d))
    near = d <= d[nearest] + max(float(d[nearest]), 0.05 * float(np.max(np.ptp(ring, axis=0))))
    minima = np.flatnonzero(near & (d <= np.roll(d, 1)) & (d < np.roll(d, -1)))
    others = [int(i) for i in minima[np.argsort(d[minima])] if i != nearest]
    return [nearest, *others[:2]]


__all__ = ["THIN", "loop_aspect", "track_phase"]
