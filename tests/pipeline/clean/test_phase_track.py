"""The phase along a thin loop (a back-and-forth stroke) follows the strand the hand is on.

The strokes are drawn here: a bent ellipse of aspect 0.05-0.1 (its strands 5-12 mm apart over
12-20 cm), travelled either way at an uneven speed that slows to a near stop at each turn, with
0.3 mm of noise and a 6 Hz tremor, sampled at uneven times, read as segmentation reads a path
(50 Hz, σ = 0.08 s: the turns' corners are cut). Tracked nearest-point-near-the-last-one alone,
the phase ran back down the strand the hand came along and counted 0.3-0.4 of the 1.5-3.3 loops
drawn, in all six seeds.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d

from bt_pipeline.clean.phase_track import THIN, loop_aspect, track_phase


def _stroke(rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """The stroke's loop, 512 points once round (endpoint excluded), and its length [m]."""
    length, aspect = rng.uniform(0.12, 0.2), rng.uniform(0.05, 0.1)
    a = np.linspace(0.0, 2.0 * np.pi, 512, endpoint=False)
    x = 0.5 * length * np.cos(a)
    y = 0.5 * length * aspect * np.sin(a) + 0.02 * (x / (0.5 * length)) ** 2  # bent a little
    turn = rng.uniform(0.0, np.pi)
    c, s = np.cos(turn), np.sin(turn)
    return np.stack([c * x - s * y, s * x + c * y], axis=1), length


@pytest.mark.parametrize("seed", range(6))
def test_a_stroke_drawn_back_and_forth_counts_its_loops(seed: int) -> None:
    rng = np.random.default_rng(seed)
    ring, _ = _stroke(rng)
    assert loop_aspect(ring) < THIN
    loops, sense = rng.uniform(1.5, 3.5), rng.choice([-1.0, 1.0])
    times = np.cumsum(rng.uniform(0.01, 0.03, 2000))
    times = times[times < 3.0 * loops]
    u = times / times[-1]
    # Slow at the turns (phase 0 and 0.5 of each loop are the stroke's ends).
    phase = loops * u + 0.06 * np.sin(4 * np.pi * loops * u)
    index = (sense * phase * ring.shape[0]) % ring.shape[0]
    lo = np.floor(index).astype(int)
    frac = (index - lo)[:, None]
    path = (1 - frac) * ring[lo] + frac * ring[(lo + 1) % ring.shape[0]]
    path += rng.normal(0.0, 0.0003, path.shape)
    tremor = 0.0015 * np.sin(2 * np.pi * 6.0 * times + rng.uniform(0, 2 * np.pi))
    path += tremor[:, None] * np.array([np.cos(seed), np.sin(seed)])
    # Read as segmentation reads a path: on a 50 Hz clock, smoothed with σ = 0.08 s.
    clock = np.arange(times[0], times[-1], 0.02)
    path = np.stack([np.interp(clock, times, path[:, d]) for d in range(2)], axis=1)
    path = gaussian_filter1d(path, 4.0, axis=0, mode="nearest")
    meant = np.interp(clock, times, phase)
    tracked = sense * track_phase(path, ring) / ring.shape[0]
    # Within 0.15 loop: the smoothing pulls each end in by up to 0.15 s (0.05 loop).
    assert abs((tracked[-1] - tracked[0]) - (meant[-1] - meant[0])) < 0.15, (tracked[-1], meant[-1])
    # The track does not swing to and fro: never 0.05 of a loop behind its farthest so far.
    assert float(np.max(np.maximum.accumulate(tracked) - tracked)) < 0.05


def test_a_round_loop_is_tracked_as_before() -> None:
    """Only thin loops take the direction of travel: a circle's track is the nearest point's."""
    a = np.linspace(0.0, 2.0 * np.pi, 256, endpoint=False)
    ring = 0.05 * np.stack([np.cos(a), np.sin(a)], axis=1)
    assert loop_aspect(ring) > THIN
    b = np.linspace(0.0, 4.0 * np.pi, 400)
    path = 0.051 * np.stack([np.cos(b), np.sin(b)], axis=1)
    tracked = track_phase(path, ring)
    nearest = np.argmin(np.linalg.norm(path[:, None, :] - ring[None], axis=2), axis=1)
    assert np.array_equal(tracked.astype(int) % 256, nearest)
    assert abs(tracked[-1] - tracked[0] - 512) <= 1
