"""The shared centre of the demonstrators' preferences, read off the demos (stage1/pivot.py).

The demos here are built from a D-shaped loop turned and scaled about a known point; the
method is given only each demo's preference and its samples, never that point."""

from __future__ import annotations

import numpy as np
import pytest

from bt_pipeline.clean.stage1.pivot import pivot_shift, placement_offset, similarity_matrix


def _d_shape(n: int = 400) -> np.ndarray:
    """A D: a half-ellipse and a chord, its box centre away from its area centroid [m]."""
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    x = np.where(t < np.pi, 0.08 * np.sin(t), 0.0)
    y = np.where(t < np.pi, 0.06 * np.cos(t), 0.06 * (t - 1.5 * np.pi) / (0.5 * np.pi))
    return np.column_stack([x, y])


def _offsets(pivot: np.ndarray, wrong: np.ndarray, prefs, rng) -> np.ndarray:
    """Each demo drawn about `pivot`, its reference built about `wrong`: the offsets."""
    loop = _d_shape()
    out = []
    for theta, rho in prefs:
        a = similarity_matrix(theta, rho)
        demo = pivot + (loop - pivot) @ a.T + rng.normal(0.0, 3e-4, loop.shape)
        reference = wrong + (loop - wrong) @ a.T
        out.append(placement_offset(demo[::3], reference))
    return np.array(out)


PREFS = [(0.0, 1.0), (25.0, 0.8), (-20.0, 1.25), (10.0, 1.1)]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_centre_the_demos_share_is_found(seed: int) -> None:
    rng = np.random.default_rng(seed)
    pivot = rng.uniform(-0.03, 0.03, 2)
    wrong = pivot + rng.uniform(-0.02, 0.02, 2)
    offsets = _offsets(pivot, wrong, PREFS, rng)
    shift = pivot_shift([p[0] for p in PREFS], [p[1] for p in PREFS], offsets, 0)
    assert np.linalg.norm(wrong + shift - pivot) < 1e-3


def test_one_demo_placed_elsewhere_does_not_carry_the_centre() -> None:
    """A drifting demo's offset is not its placement: the two that agree win."""
    rng = np.random.default_rng(3)
    pivot, wrong = np.array([0.01, -0.02]), np.array([0.0, 0.0])
    offsets = _offsets(pivot, wrong, PREFS, rng)
    offsets[1] += np.array([0.012, -0.009])  # demo 1 drifted 15 mm
    shift = pivot_shift([p[0] for p in PREFS], [p[1] for p in PREFS], offsets, 0)
    assert np.linalg.norm(wrong + shift - pivot) < 1e-3


def test_demos_that_do_not_agree_keep_the_centre() -> None:
    """Offsets no single Δc explains (each demo placed anywhere) leave c where it was."""
    rng = np.random.default_rng(4)
    offsets = rng.uniform(-0.02, 0.02, (4, 2))
    offsets[0] = 0.0
    shift = pivot_shift([p[0] for p in PREFS], [p[1] for p in PREFS], offsets, 0)
    assert not shift.any()


def test_demos_sharing_the_best_preference_say_nothing_of_the_centre() -> None:
    same = [(5.0, 1.1)] * 4
    offsets = np.full((4, 2), 0.004)
    offsets[0] = 0.0
    assert not pivot_shift([p[0] for p in same], [p[1] for p in same], offsets, 0).any()


def test_the_placement_fit_ignores_an_approach_and_a_missing_part() -> None:
    rng = np.random.default_rng(5)
    loop = _d_shape()
    t_true = np.array([0.004, -0.003])
    demo = loop[:330] + t_true + rng.normal(0.0, 2e-4, (330, 2))  # 18 % of the loop missing
    approach = np.linspace([0.2, 0.2], loop[0] + t_true, 40)
    found = placement_offset(np.vstack([approach, demo]), loop)
    assert np.linalg.norm(found - t_true) < 0.5e-3
