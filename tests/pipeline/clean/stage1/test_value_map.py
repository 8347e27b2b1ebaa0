"""Tests of the value map V_E: shape of the map, KDE equivalence, interpolation, rewards."""

from __future__ import annotations

import numpy as np
import pytest

from bt_pipeline.clean.stage1.dmp import fit_periodic_dmp
from bt_pipeline.clean.stage1.extract import canonical_reference
from bt_pipeline.clean.stage1.period import loop_size
from bt_pipeline.clean.stage1.value_map import (
    ValueMap,
    ValueMapConfig,
    build_value_map,
    rollout_states,
    value_map_from_states,
)
from bt_pipeline.exceptions import ConfigError

N = 300


def ellipse_demo() -> np.ndarray:
    phase = 0.5 + 2 * np.pi * np.linspace(0.0, 1.0, N)
    return np.array([0.3, 0.1]) + np.stack([0.1 * np.cos(phase), 0.05 * np.sin(phase)], axis=1)


@pytest.fixture(scope="module")
def fitted():
    demo = ellipse_demo()
    dmp = fit_periodic_dmp(demo)
    return dmp, canonical_reference(dmp, demo)


def test_map_is_highest_on_the_reference(fitted) -> None:
    dmp, reference = fitted
    value_map = build_value_map(dmp, reference, seed=1)
    size = loop_size(reference)
    on = value_map.mean_reward(reference)
    shifted = value_map.mean_reward(reference + np.array([0.0, size]))
    assert value_map.values.max() == pytest.approx(1.0)
    assert on > 0.5
    assert shifted < 0.1 * on
    assert value_map.mean_reward(reference + np.array([0.0, 0.3 * size])) < on


def test_binned_map_matches_the_exact_kde_on_the_grid(fitted) -> None:
    dmp, reference = fitted
    config = ValueMapConfig(n_rollouts=5, grid_size=60)
    states = rollout_states(dmp, reference, config, seed=0)
    value_map = value_map_from_states(states, config)
    x, y = np.meshgrid(value_map.x_centres, value_map.y_centres)
    nodes = np.stack([x, y], axis=-1).reshape(-1, 2)
    d2 = np.sum((nodes[:, None, :] - states[None, :, :]) ** 2, axis=-1)
    exact = np.exp(-0.5 * d2 / value_map.bandwidth**2).sum(axis=1).reshape(x.shape)
    np.testing.assert_allclose(value_map.values, exact / exact.max(), atol=0.02)


def test_rollout_states_keep_one_whole_period_per_rollout(fitted) -> None:
    dmp, reference = fitted
    config = ValueMapConfig(n_rollouts=7, samples_per_period=100)
    states = rollout_states(dmp, reference, config, seed=0)
    assert states.shape == (700, 2)
    # Transients are gone: every state lies on the loop.
    distance = np.min(np.linalg.norm(states[:, None] - reference[None], axis=-1), axis=1)
    assert distance.max() < 0.01 * loop_size(reference)


def test_same_seed_same_map(fitted) -> None:
    dmp, reference = fitted
    a = build_value_map(dmp, reference, seed=5)
    b = build_value_map(dmp, reference, seed=5)
    np.testing.assert_array_equal(a.values, b.values)


def test_bilinear_interpolation_is_exact_on_a_plane_and_zero_outside() -> None:
    x_c, y_c = np.linspace(0.0, 1.0, 11), np.linspace(-1.0, 1.0, 21)
    xx, yy = np.meshgrid(x_c, y_c)
    value_map = ValueMap(x_c, y_c, 0.25 * xx + 0.25 * yy + 0.5, bandwidth=0.1)
    points = np.random.default_rng(0).uniform([0.0, -1.0], [1.0, 1.0], size=(4, 50, 2))
    np.testing.assert_allclose(
        value_map(points), 0.25 * points[..., 0] + 0.25 * points[..., 1] + 0.5
    )
    assert value_map(np.array([[1.5, 0.0], [0.5, -1.2]])).tolist() == [0.0, 0.0]
    rewards = value_map.mean_rewards(points)
    assert rewards.shape == (4,)
    assert rewards[2] == pytest.approx(value_map.mean_reward(points[2]))


def test_value_map_is_validated_and_frozen() -> None:
    x_c = np.linspace(0.0, 1.0, 5)
    with pytest.raises(ConfigError, match="shape"):
        ValueMap(x_c, x_c, np.zeros((4, 5)), bandwidth=0.1)
    with pytest.raises(ConfigError, match=r"\[0, 1\]"):
        ValueMap(x_c, x_c, np.full((5, 5), 2.0), bandwidth=0.1)
    with pytest.raises(ConfigError, match="uniformly"):
        ValueMap(x_c**2, x_c, np.zeros((5, 5)), bandwidth=0.1)
    values = np.zeros((5, 5))
    value_map = ValueMap(x_c, x_c, values, bandwidth=0.1)
    values[0, 0] = 1.0  # The caller's array is copied.
    assert value_map.values[0, 0] == 0.0
    with pytest.raises(ValueError, match="read-only"):
        value_map.values[0, 0] = 1.0


def test_config_is_validated() -> None:
    with pytest.raises(ConfigError, match="whole period"):
        ValueMapConfig(n_periods=1, transient_periods=0.5)
    with pytest.raises(ConfigError, match="bandwidth_m"):
        ValueMapConfig(bandwidth_m=0.0)
