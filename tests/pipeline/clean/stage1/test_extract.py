"""Tests of Stage 1 end to end on a small synthetic set with known preferences and shapes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial import KDTree

from bt_pipeline.clean.stage1.alignment import apply_preference
from bt_pipeline.clean.stage1.extract import Stage1Config, loop_centre, run_stage1
from bt_pipeline.data.demo import Demo
from bt_pipeline.data.tasks import default_plane
from bt_pipeline.exceptions import ConfigError, DemoError

N = 300
THETAS = (5.0, -5.0, 10.0, -10.0)
RHOS = (1.0, 1.1, 1.2, 1.3)
TASK_CENTRE = np.array([0.5, 0.05])


def _raw_egg(phase: np.ndarray) -> np.ndarray:
    r = 1.0 + 0.3 * np.cos(phase) + 0.1 * np.sin(2 * phase)
    return 0.1 * np.stack([r * np.cos(phase), 0.6 * r * np.sin(phase)], axis=-1)


_DENSE = _raw_egg(2 * np.pi * np.arange(4000) / 4000)
_BOX_CENTRE = 0.5 * (_DENSE.min(axis=0) + _DENSE.max(axis=0))


def egg(phase: np.ndarray) -> np.ndarray:
    """An asymmetric loop whose bounding box is centred at the origin."""
    return _raw_egg(phase) - _BOX_CENTRE


def truth(i: int) -> np.ndarray:
    """Demo i's true shape, dense."""
    return apply_preference(
        egg(2 * np.pi * np.arange(1200) / 1200), THETAS[i], RHOS[i], TASK_CENTRE
    )


def make_demos(seed: int = 0, noise: float = 0.004) -> list[Demo]:
    """Demo 0 is expert-like; the others are noisy. Random start phases; demo 2 runs backwards."""
    rng = np.random.default_rng(seed)
    demos = []
    for i in range(4):
        sign = -1.0 if i == 2 else 1.0
        phase = rng.uniform(0, 2 * np.pi) + sign * 2 * np.pi * np.linspace(0.0, 1.0, N)
        positions = apply_preference(egg(phase), THETAS[i], RHOS[i], TASK_CENTRE)
        positions += rng.normal(0.0, 0.0003 if i == 0 else noise, size=positions.shape)
        demos.append(
            Demo(
                positions=positions,
                task="wiping",
                file="",
                name=f"demo_{i}",
                demonstrator=f"teacher_{i}",
                theta_deg=THETAS[i],
                rho=RHOS[i],
                plane=default_plane("wiping"),
            )
        )
    return demos


def curve_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric mean nearest-point distance between two point sets [m]."""
    return 0.5 * (KDTree(b).query(a)[0].mean() + KDTree(a).query(b)[0].mean())


@pytest.fixture(scope="module")
def demos() -> list[Demo]:
    return make_demos()


@pytest.fixture(scope="module")
def result(demos):
    return run_stage1(demos, best_index=0)


def test_aligned_references_are_close_to_the_truth(demos, result) -> None:
    assert result.aligned.shape == (4, N, 2)
    for i in range(1, 4):
        raw = curve_distance(demos[i].positions, truth(i))
        cleaned = curve_distance(result.aligned[i], truth(i))
        assert cleaned < 0.25 * raw
        assert cleaned < 0.001


def test_given_preferences_are_used(result) -> None:
    np.testing.assert_array_equal(result.thetas, THETAS)
    np.testing.assert_array_equal(result.rhos, RHOS)
    assert not result.estimated.any()
    np.testing.assert_allclose(result.centre, TASK_CENTRE, atol=5e-4)


def test_references_are_phase_aligned_to_their_demos(demos, result) -> None:
    assert result.reversed.tolist() == [False, False, True, False]
    for i, demo in enumerate(demos):
        gap = np.linalg.norm(result.aligned[i] - demo.positions, axis=1).mean()
        assert gap == pytest.approx(result.shape_losses[i])
    assert result.shape_losses[0] < 0.001  # The expert against its own DMP reproduction.
    assert np.all(result.shape_losses[1:] < 0.01)


def test_global_shape_is_the_unbiased_shape(result) -> None:
    assert curve_distance(result.global_shape, egg(2 * np.pi * np.arange(1200) / 1200)) < 5e-4


def test_rewards_are_computed_in_each_demos_own_frame(demos, result) -> None:
    truths = np.stack([truth(i)[::4] for i in range(4)])
    np.testing.assert_allclose(result.to_best_frame(3, truths[3]), truths[0], atol=1e-3)
    own_frame = result.rewards(truths)
    best_frame = result.value_map.mean_rewards(truths)
    assert np.all(own_frame > 0.5)
    assert best_frame[3] < 0.5 * own_frame[3]


def test_missing_preferences_are_estimated_relative_to_the_best(demos) -> None:
    unknown = [dataclasses.replace(d, theta_deg=None, rho=None) for d in demos]
    result = run_stage1(unknown, best_index=0)
    assert result.estimated.all()
    np.testing.assert_allclose(result.thetas, np.subtract(THETAS, THETAS[0]), atol=1.0)
    np.testing.assert_allclose(result.rhos, np.divide(RHOS, RHOS[0]), rtol=0.02)
    for i in range(1, 4):
        assert curve_distance(result.aligned[i], truth(i)) < 0.5 * curve_distance(
            demos[i].positions, truth(i)
        )


def test_only_missing_preferences_are_estimated(demos) -> None:
    partial = [*demos[:3], dataclasses.replace(demos[3], rho=None)]
    result = run_stage1(partial, best_index=0)
    assert result.estimated.tolist() == [False, False, False, True]
    assert result.thetas[3] == THETAS[3]
    assert result.rhos[3] == pytest.approx(RHOS[3], rel=0.02)
    forced = run_stage1(demos, best_index=0, config=Stage1Config(preferences="estimate"))
    assert forced.estimated.all()


def test_loop_centre_rules() -> None:
    loop = apply_preference(egg(2 * np.pi * np.arange(N) / (N - 1)), 25.0, 1.2, TASK_CENTRE)
    np.testing.assert_allclose(loop_centre(loop, 25.0, "box"), TASK_CENTRE, atol=1e-4)
    circle = np.stack([np.cos(np.linspace(0, 2 * np.pi, N)), np.sin(np.linspace(0, 2 * np.pi, N))])
    np.testing.assert_allclose(loop_centre(circle.T + 2.0, 0.0, "arc_length"), [2.0, 2.0])
    np.testing.assert_allclose(loop_centre(loop, 0.0, "anchor", anchor=[1.0, 2.0]), [1.0, 2.0])
    with pytest.raises(ConfigError, match="centre"):
        Stage1Config(centre="middle")  # type: ignore[arg-type]  # Wrong on purpose.


def test_invalid_sets_are_rejected(demos) -> None:
    short = demos[2].with_positions(demos[2].positions[:200])
    with pytest.raises(DemoError, match="demo_2"):
        run_stage1([*demos[:2], short], best_index=0)
    with pytest.raises(ConfigError, match="best_index"):
        run_stage1(demos, best_index=4)
    line = demos[1].with_positions(np.linspace([0.0, 0.0], [0.2, 0.1], N))
    with pytest.raises(DemoError, match="demo_1"):
        run_stage1([demos[0], line], best_index=1)
