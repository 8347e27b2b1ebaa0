"""The shape gate against a crowd that shares a bias (shape_gate: whole loops first, a steady
loop of its own).

The demos are drawn here, not by bt's generators: a bean-shaped loop with no symmetry (three-
and two-lobed terms, squashed to 0.8 in y); a steady demonstrator drawing two loops with 0.2 mm
of noise; three crowd demonstrators drawing 2.5-4 loops with 0.6 mm of noise, a 7 Hz tremor and
one shared bias: the same part of the loop (up and to the right, before θ) pushed 30 % out.
Each has its own θ/ρ (hidden), period, approach and retreat, at uneven sample times. A loop
learned from these demos leans to the crowd's bias, so the steady demo is farther from it than
the crowd; before the second rule, the crowd's demo was picked in 4 of these 6 sets.
"""

from __future__ import annotations

import math

import numpy as np

from bt_pipeline.clean.selection import select_demos
from bt_pipeline.clean.shape_gate import eligible, repeat_misfit
from bt_pipeline.data.demo import Demo, resample_uniform
from bt_pipeline.data.tasks import default_plane

_RADIUS = 0.06  # The bean's mean radius [m].


def _bean(phase: np.ndarray) -> np.ndarray:
    """The loop meant, at `phase` (loops), shape (n, 2) [m]."""
    angle = 2 * np.pi * phase
    radius = _RADIUS * (1 + 0.15 * np.cos(3 * angle + 0.4) + 0.1 * np.sin(2 * angle))
    return np.stack([radius * np.cos(angle), 0.8 * radius * np.sin(angle)], axis=1)


def _demo(rng: np.random.Generator, name: str, loops: float, crowd: bool) -> Demo:
    """One demo: steady, or (`crowd`) noisy, trembling and bulged where the crowd bulges."""
    theta, rho = np.radians(rng.uniform(-25, 25)), rng.uniform(0.8, 1.25)
    turn = rho * np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    period = rng.uniform(2.5, 4.0)
    t0, t1 = 1.2, 1.2 + period * loops
    times = np.cumsum(rng.uniform(0.012, 0.03, 3000))
    times = times[times < t1 + 1.5]
    u = np.clip((times - t0) / (t1 - t0), 0.0, 1.0)
    loop = _bean(loops * (u + 0.02 * np.sin(2 * np.pi * u * loops)) + 0.1)
    if crowd:
        pushed = 1.0 / (1.0 + np.exp(-(loop @ np.array([0.7, 0.7])) / (0.2 * _RADIUS)))
        loop = loop * (1.0 + 0.3 * pushed)[:, None]
    x = loop @ turn.T
    away = np.array([0.05, -0.06])
    s0 = np.clip((times - 0.3) / (t0 - 0.3), 0.0, 1.0)
    s1 = np.clip((times - t1) / 0.9, 0.0, 1.0)
    x += away * (1 - (3 * s0**2 - 2 * s0**3))[:, None] - away * (3 * s1**2 - 2 * s1**3)[:, None]
    if crowd:
        tremor = 0.0012 * np.sin(2 * np.pi * 7.0 * times + rng.uniform(0, 2 * np.pi))
        x += tremor[:, None] * np.array([0.6, 0.8])
    x += rng.normal(0.0, 0.0006 if crowd else 0.0002, x.shape)
    return Demo(
        resample_uniform(x, times, 200),
        "stirring",
        "drawn in the test",
        name,
        name,
        None,
        None,
        default_plane("wiping"),
        duration_s=float(times[-1] - times[0]),
        raw_positions=x,
        raw_times_s=times,
    )


def test_a_steady_demo_is_picked_over_a_crowd_that_shares_a_bias() -> None:
    """In every seed the steady demo is the best; the loop learned from the set leans to the
    crowd's bias (the steady demo is not the closest to it), so the gate's first rule alone
    would set it aside."""
    for seed in range(6):
        rng = np.random.default_rng(seed)
        demos = [_demo(rng, "steady", 2.0, crowd=False)]
        demos += [_demo(rng, f"crowd_{k}", rng.uniform(2.5, 4.0), crowd=True) for k in range(3)]
        selection = select_demos(demos)
        assert selection.scores.best_index == 0, (seed, selection.misfits)
        assert int(np.argmin(selection.misfits)) != 0, seed  # The learned loop leans.
        steady = selection.repeat_misfits[0]
        assert steady < min(selection.repeat_misfits[1:]), (seed, selection.repeat_misfits)


def test_eligibility_takes_whole_loops_first_and_steady_loops_of_their_own() -> None:
    """A part of a loop neither sets the smallest misfit nor is eligible while whole loops
    exist; a demo closer to its own loop than any demo is to the task's loop is eligible."""
    misfits = np.array([0.011, 0.015, 0.023, 0.0045])
    whole = np.array([True, True, True, False])
    assert eligible(misfits).tolist() == [False, False, False, True]
    assert eligible(misfits, whole=whole).tolist() == [True, True, False, False]
    assert eligible(misfits, whole=np.zeros(4, dtype=bool)).tolist() == eligible(misfits).tolist()
    repeat = np.array([math.nan, 0.009, 0.02, math.nan])
    misfits = np.array([0.021, 0.011, 0.019, 0.02])
    assert eligible(misfits, repeat=repeat).tolist() == [False, True, False, False]
    repeat = np.array([0.0009, 0.008, 0.015, 0.012])
    assert eligible(misfits, repeat=repeat).tolist() == [True, True, False, False]


def test_a_path_under_two_loops_has_no_repeat_misfit() -> None:
    """Read between returns only when the path holds two loops (loop_learn.REPEATS)."""
    rng = np.random.default_rng(3)
    demo = _demo(rng, "steady", 2.0, crowd=False)
    own = _bean(np.linspace(0.0, 1.0, 256, endpoint=False))
    assert math.isnan(repeat_misfit(demo, own, 1.9))
    assert math.isnan(repeat_misfit(demo, None, 3.0))
    assert repeat_misfit(demo, own, 2.0) >= 0.0
