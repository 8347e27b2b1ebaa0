"""A demo's own loop: where its path returns to itself, with no template.

The task's loop is learned from the demos (:mod:`bt_pipeline.clean.loop_learn`), and the take
checks ask whether a take closes a loop at all, so one demo's loop must be found without any
drawing of it. For one demo's raw samples:

1. **Path.** Read on a 50 Hz clock, the rests before and after trimmed
   (:func:`~bt_pipeline.clean.segment.moving_part`), smoothed lightly (σ = 0.03 s: the
   segmentation's σ = 0.08 s pulls a single loop's ends 5 % of its size apart), then
   resampled by **arc length**: pauses
   and speed changes vanish, so a loop is the same length of path each time round.
2. **Size.** E, the larger side of the bounding box of the middle 80 % of the path's length (an
   approach from far off does not inflate it).
3. **Returns.** From each point y_k the path must first get ``2.5 x tol`` away, with
   tol = 15 % of E (a single loop that drifts 3 cm still closes; one that stops at 90 % is 30 %
   of its size short); its return is the nearest point of the first stretch that comes back
   within tol and passes these tests. A return counts when the path there runs the same way
   (cos ≥ 0.8 between the chord on which the path leaves y_k and the one on which it arrives
   at its return, each 5 % of E long: one-sided, so an approach at an angle does not bend
   them, and chords, so jitter in a pause does not turn them): an approach and a retreat
   along one line run opposite ways, and a figure-eight's crossing runs across; and when the
   stretch between them spans at least 75 % of E (a lobe of an eight closed by an approach
   that runs beside it spans half).
4. **Perimeter.** L, the median path length from a point to its return (over the points that
   return). One loop is the stretch from the point whose loop length is nearest L, among those
   nearest the middle of the path's returns, to its return; resampled to 256 points by arc
   length, closed. When that loop's ends lie more than 9 % of E farther apart than the
   best-closing loop's (its start was on an approach that joins the loop, its return on the
   loop's end: a steady single figure-eight's closed 30 mm apart, 9.5 % of E, against 0.5 mm,
   and lost the tip of a lobe), it is read among the loops that close within 1 % of E (or
   2 mm) of the best instead. From 5 % the rule also moved wobbly hands' loops, whose best
   closure can be a wobble's: the second generator's lab loops then picked a wobbly demo as
   the best in one set of 12 (θ/ρ hidden).

A demo whose path never returns (a part of a loop, a stroke that stops, a take with no loop)
``closes`` no loop. Times are only used to trim the rests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.ndimage import gaussian_filter1d

from bt_pipeline.data.loop_shape import arc_length_resample
from bt_pipeline.data.records import FloatArray

_CLOCK_HZ = 50.0  # Analysis clock [Hz] (as segment.py).
_SMOOTH_S = 0.08  # Gaussian σ of the path the rests are found on [s] (as segment.py),
_LIGHT_S = 0.03  # and of the path the loop is read on: the heavier one pulls in a loop's ends.
_MAX_POINTS = 1200  # Arc-length points of the path (at most).
_MIN_SPACING_M = 0.001  # and at least this far apart [m].
_TOLERANCE = 0.15  # A return comes back within this share of the loop's size (a loop that
# drifts 3 cm closes; one that stops at 90 % is 0.3 of its size short),
_LEAVE = 2.5  # after getting this many tolerances away.
_PARALLEL = 0.8  # Tangents at a point and its return run the same way (cos ≥ this).
_CHORD = 0.05  # The way the path runs: a chord of this share of E.
_SPAN = 0.75  # A loop spans at least this share of E.
_MIDDLE = 0.1  # E is read between these shares of the path's length from each end.
_OPEN = 0.09  # A loop closing this share of E worse than the best-closing loop is not read
_CLOSE = 0.01  # but one closing within this share of E (or _CLOSE_M) of the best is.
_CLOSE_M = 0.002
LOOP_POINTS = 256
"""Points of the loop a demo gives (uniform in arc length, endpoint excluded)."""


@dataclass(frozen=True)
class OwnLoop:
    """What one demo's path says of its own loop."""

    closes: bool
    """Whether the path returns to itself after travelling round a loop."""
    size_m: float
    """E, the larger side of the bounding box of the middle of the path [m]."""
    perimeter_m: float
    """L, the path length of one loop [m] (NaN when it does not close)."""
    loops: float
    """The moving path's length over L (0 when it does not close): about the loops drawn."""
    loop: FloatArray | None
    """One loop, shape (256, 2), uniform in arc length, endpoint excluded [m]; None if open."""
    closure_m: float
    """The gap between that loop's ends [m] (NaN when it does not close)."""


def moving_path(positions: ArrayLike, times_s: ArrayLike, name: str = "demo") -> FloatArray:
    """The moving part of a demo on the analysis clock, smoothed, shape (T', 2) [m].

    Raises:
        DemoError: Mismatched, non-finite or non-increasing input.
    """
    from bt_pipeline.clean.segment import checked_samples, moving_part

    x, t = checked_samples(positions, times_s, name)
    clock = np.arange(t[0], t[-1], 1.0 / _CLOCK_HZ)
    if clock.size < 8:
        return x
    path = np.stack([np.interp(clock, t, x[:, d]) for d in range(2)], axis=1)
    smooth = gaussian_filter1d(path, _SMOOTH_S * _CLOCK_HZ, axis=0, mode="nearest")
    first, last = moving_part(smooth, path)
    light = gaussian_filter1d(path, _LIGHT_S * _CLOCK_HZ, axis=0, mode="nearest")
    if last - first < 8:
        return light
    return light[first : last + 1]


def own_loop(positions: ArrayLike, times_s: ArrayLike, name: str = "demo") -> OwnLoop:
    """One demo's own loop, from where its path returns to itself (module doc).

    Args:
        positions: Raw task-plane positions, shape (T, 2) [m].
        times_s: Their strictly increasing times, shape (T,) [s].
        name: Label for messages.

    Raises:
        DemoError: Mismatched, non-finite or non-increasing input.
    """
    return loop_of_path(moving_path(positions, times_s, name))


def loop_of_path(path: FloatArray) -> OwnLoop:
    """:func:`own_loop` on a path already smoothed and trimmed to its motion, shape (T, 2) [m]."""
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    length = float(np.sum(steps))
    open_loop = OwnLoop(False, 0.0, math.nan, 0.0, None, math.nan)
    if length <= 10 * _MIN_SPACING_M:
        return open_loop
    n = int(min(_MAX_POINTS, max(16, length / _MIN_SPACING_M)))
    y = arc_length_resample(path, n)
    h = length / (n - 1)
    middle = y[int(_MIDDLE * n) : max(int((1.0 - _MIDDLE) * n), int(_MIDDLE * n) + 2)]
    size = float(np.max(np.ptp(middle, axis=0)))
    if size <= 10 * _MIN_SPACING_M:
        return OwnLoop(False, size, math.nan, 0.0, None, math.nan)
    tol = _TOLERANCE * size
    distance = np.sqrt(np.sum((y[:, None, :] - y[None, :, :]) ** 2, axis=2))
    returns = np.full(n, -1, dtype=np.intp)
    for k in range(n - 2):
        row = distance[k, k + 1 :]
        away = np.flatnonzero(row > _LEAVE * tol)
        if away.size == 0:
            break  # Nor will any later point get away and back (the path ends).
        offset = k + 1 + int(away[0])
        # Each stretch that comes back within tol, in turn, until one closes a loop (an eight
        # passes its crossing half way round).
        for a, b in _runs(row[away[0] :] < tol):
            j = offset + a + int(np.argmin(row[away[0] + a : away[0] + b]))
            if _same_way(y, distance, k, j, _CHORD * size) and _spans(y[k : j + 1], size):
                returns[k] = j
                break
    found = np.flatnonzero(returns >= 0)
    if found.size == 0:
        return OwnLoop(False, size, math.nan, 0.0, None, math.nan)
    lags = (returns[found] - found) * h
    perimeter = float(np.median(lags))
    typical = found[np.abs(lags - perimeter) <= 0.1 * perimeter]
    if typical.size == 0:
        typical = found
    # The loop nearest the middle of the returns (a loop well inside the demo), then the one
    # whose length is nearest L among its neighbours.
    mid = typical + 0.5 * (returns[typical] - typical)
    centre = float(np.median(mid))

    def chosen(starts: np.ndarray, middles: np.ndarray) -> int:
        near = starts[np.argsort(np.abs(middles - centre))[: max(3, starts.size // 10)]]
        return int(near[np.argmin(np.abs((returns[near] - near) * h - perimeter))])

    k = chosen(typical, mid)
    closure = distance[typical, returns[typical]]
    if distance[k, returns[k]] > float(closure.min()) + _OPEN * size:
        # That loop closes far worse than another does: it was read from an approach that
        # joins the loop, across to the loop's end. The loops that close best are read instead.
        keep = closure <= float(closure.min()) + max(_CLOSE * size, _CLOSE_M)
        k = chosen(typical[keep], mid[keep])
    j = int(returns[k])
    loop = arc_length_resample(np.concatenate([y[k:j], y[k : k + 1]]), LOOP_POINTS + 1)[:-1]
    return OwnLoop(
        closes=True,
        size_m=size,
        perimeter_m=perimeter,
        loops=length / perimeter,
        loop=loop,
        closure_m=float(distance[k, j]),
    )


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """Half-open index ranges [a, b) of the runs of True in `flags`."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], flags.astype(np.int8), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def _same_way(y: FloatArray, distance: FloatArray, k: int, j: int, chord: float) -> bool:
    """Whether the path leaves y_k the way it arrives at y_j: cos ≥ 0.8 between the chords from
    y_k to the first point `chord` away after it and to y_j from the last point `chord` away
    before it (one-sided, so an approach or a retreat at an angle does not bend them; chords,
    so jitter in a pause does not turn them)."""
    ahead = np.flatnonzero(distance[k, k + 1 : j + 1] >= chord)
    behind = np.flatnonzero(distance[j, k:j] >= chord)
    if ahead.size == 0 or behind.size == 0:
        return False
    leaving = y[k + 1 + int(ahead[0])] - y[k]
    arriving = y[j] - y[k + int(behind[-1])]
    norm = float(np.linalg.norm(leaving) * np.linalg.norm(arriving))
    return norm > 0.0 and float(leaving @ arriving) / norm >= _PARALLEL


def _spans(stretch: FloatArray, size: float) -> bool:
    """Whether a closed stretch spans about the whole path (a lobe of an eight, or a loop cut
    off by an approach that runs beside the path, spans half of it)."""
    return float(np.max(np.ptp(stretch, axis=0))) >= _SPAN * size


__all__ = ["LOOP_POINTS", "OwnLoop", "loop_of_path", "moving_path", "own_loop"]
