"""Lopsided and wobbly hands against a learned loop kept where its demo drew it (guide_consensus,
step 5).

The demos are drawn here, not by bt's generators: an egg-shaped loop with no symmetry, a little
off the origin; one side bulged 20-35 % outward towards a random direction (not the loop's box
axes, as bt's generator bulges); three loops with a linear drift of 12 mm, a 6 Hz tremor, uneven
speed and sample times, an approach and a retreat. The wobbly demos bulge nothing and sway by
slow sines instead (as the second generator's operators do, drawn here apart from it). The
single loops run one loop and a sixth without drift, so they close on themselves. θ and ρ are
hidden.
"""

from __future__ import annotations

import numpy as np

from bt_pipeline.clean.segment import segment_demo
from bt_pipeline.data.loop_shape import LoopShape

_RADIUS = 0.07  # The egg's mean radius [m].
_CENTRE = np.array([0.006, -0.004])  # Where the egg's centre lies [m].


def _egg(phase: np.ndarray) -> np.ndarray:
    """The egg at `phase` (loops), shape (n, 2) [m]."""
    angle = 2 * np.pi * phase
    radius = _RADIUS * (1 + 0.12 * np.cos(2 * angle) + 0.08 * np.sin(3 * angle))
    return _CENTRE + np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)


def _template() -> LoopShape:
    """The egg as a best demo's loop kept where that demo drew it."""
    fitted = LoopShape.from_points(_egg(np.linspace(0, 1, 256, endpoint=False)), 8)
    return LoopShape(fitted.coefficients, "egg", placed=True)


def _demo(
    seed: int, loops: float = 3.0, wobbly: bool = False, drift_m: float = 0.012
) -> tuple[np.ndarray, np.ndarray, float]:
    """Positions (T, 2) [m], times (T,) [s] and the true ρ of one demo drifting `drift_m` [m]:
    lopsided, or (`wobbly`) not bulged but swaying by three slow sines per axis that do not
    repeat per loop."""
    rng = np.random.default_rng(seed)
    theta, rho = np.radians(rng.uniform(-20, 20)), rng.uniform(0.85, 1.2)
    heading = rng.uniform(0, 2 * np.pi)
    side = np.array([np.cos(heading), np.sin(heading)])
    gain = 0.0 if wobbly else rng.uniform(0.2, 0.35)
    drift = drift_m * np.array([np.cos(heading + 1.3), np.sin(heading + 1.3)])
    turn = rho * np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])

    def drawn(phase: np.ndarray) -> np.ndarray:
        offset = _egg(phase) - _CENTRE
        bulge = 1.0 + gain / (1.0 + np.exp(-(offset @ side) / (0.15 * _RADIUS)))
        return (_CENTRE + offset * bulge[:, None]) @ turn.T

    t0, t1 = 1.5, 1.5 + 4.0 * loops
    times = np.cumsum(rng.uniform(0.008, 0.03, 1000))
    times = times[times < t1 + 2.0]
    start, end = drawn(np.zeros(1))[0], drawn(np.array([loops]))[0]
    away = 0.08 * np.array([np.cos(heading + 2), np.sin(heading + 2)])
    x = np.empty((times.size, 2))
    for k, t in enumerate(times):
        if t < t0:
            s = float(np.clip((t - 0.5) / (t0 - 0.5), 0.0, 1.0))
            x[k] = start + away * (1.0 - (3 * s**2 - 2 * s**3))
        elif t <= t1:
            u = (t - t0) / (t1 - t0)
            phase = loops * (u + 0.03 * np.sin(2 * np.pi * u * loops))
            x[k] = drawn(np.array([phase]))[0] + drift * u
        else:
            s = float(np.clip((t - t1) / 0.8, 0.0, 1.0))
            x[k] = end + drift - away * (3 * s**2 - 2 * s**3)
    tremor = 0.0015 * np.sin(2 * np.pi * 6.0 * times + rng.uniform(0, 2 * np.pi))
    x += tremor[:, None] * np.array([0.8, 0.6]) + rng.normal(0, 0.0004, x.shape)
    if wobbly:
        for axis in range(2):
            for _ in range(3):
                hz, amp = rng.uniform(0.1, 0.6), rng.uniform(0.0015, 0.0035)
                x[:, axis] += amp * np.sin(2 * np.pi * hz * times + rng.uniform(0, 2 * np.pi))
    return x, times, rho


def test_a_lopsided_hand_is_read_at_its_unbulged_size() -> None:
    """Every seed's ρ within 6 % of the truth. Fitted free of the origin over several loops,
    three of the ten were read 11-18 % too big (the bulged side's size)."""
    for seed in range(10):
        x, t, rho = _demo(seed)
        segment = segment_demo(x, t, _template(), f"lopsided {seed}")
        assert abs(segment.guide.rho / rho - 1.0) <= 0.06, (seed, segment.guide.rho / rho)
        assert segment.cycles >= 2.8, (seed, segment.cycles)


def test_a_wobbly_hand_is_not_read_small() -> None:
    """A sway that does not repeat per loop is not a bulge: every seed's ρ within 4 % (held at
    the origin as a lopsided loop is, 4 of these 16 were read 5-6 % too small)."""
    for seed in range(16):
        x, t, rho = _demo(seed, wobbly=True)
        segment = segment_demo(x, t, _template(), f"wobbly {seed}")
        assert abs(segment.guide.rho / rho - 1.0) <= 0.04, (seed, segment.guide.rho / rho)


def test_a_lopsided_single_loop_that_closes_is_read_at_its_unbulged_size() -> None:
    """One loop and a sixth without drift: it closes on itself, so it is held at the origin and
    its fits compared over their best 30 % (span_fit, step 3). Every seed's ρ within 6 %;
    compared over 40 % and free of the origin, 5 of these 16 were read 8-32 % too big."""
    for seed in range(16):
        x, t, rho = _demo(seed, loops=1.15, drift_m=0.0)
        segment = segment_demo(x, t, _template(), f"single lopsided {seed}")
        assert abs(segment.guide.rho / rho - 1.0) <= 0.06, (seed, segment.guide.rho / rho)
        assert segment.cycles >= 1.0, (seed, segment.cycles)


def test_a_wobbly_single_loop_that_closes_is_not_read_small() -> None:
    """The same rule on a single loop that sways and closes: every seed's ρ within 7 % (before
    it, 2 of these 16 were read 10-13 % too small)."""
    for seed in range(16):
        x, t, rho = _demo(seed, loops=1.15, wobbly=True, drift_m=0.0)
        segment = segment_demo(x, t, _template(), f"single wobbly {seed}")
        assert abs(segment.guide.rho / rho - 1.0) <= 0.07, (seed, segment.guide.rho / rho)
