"""Tests of the demo utility score (bt_pipeline.score.utility)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bt_pipeline.data.demo import Demo
from bt_pipeline.data.tasks import Task, default_plane
from bt_pipeline.exceptions import ConfigError, DemoError
from bt_pipeline.score.mi import mutual_information
from bt_pipeline.score.normalise import METRIC_NAMES, Normaliser, RawMetrics, minmax_normalise
from bt_pipeline.score.utility import (
    ScoreConfig,
    normalised_utility,
    raw_metrics,
    score_demos,
    select_best,
    set_utilities,
    utilities_against,
    utility_terms,
)

N = 300


def loop(n: int = N, stop: float = 1.0, lopsided: float = 1.0) -> np.ndarray:
    """A figure-like loop mirror-symmetric about x = 0 (right half stretched by `lopsided`) [m].

    `stop` < 1 leaves the loop open; the samples are uniform in t over [0, stop].
    """
    t = np.linspace(0.0, stop, n)
    x = 0.1 * np.sin(2 * np.pi * t)
    x = np.where(x > 0.0, lopsided * x, x)
    y = 0.05 * np.cos(4 * np.pi * t) + 0.02 * np.cos(2 * np.pi * t)
    return np.column_stack([x, y])


def make_demo(
    positions: np.ndarray, name: str, task: Task = "wiping", theta_deg: float | None = None
) -> Demo:
    return Demo(
        positions=positions,
        task=task,
        file="",
        name=name,
        demonstrator="tester",
        theta_deg=theta_deg,
        rho=None,
        plane=default_plane(task),
    )


def rotate(points: np.ndarray, angle_deg: float) -> np.ndarray:
    a = math.radians(angle_deg)
    rotation = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    return points @ rotation.T


def mixed_set() -> list[Demo]:
    """Noisy, open, clean and lopsided demos of one task; the clean one is at index 2."""
    rng = np.random.default_rng(0)
    return [
        make_demo(loop() + rng.normal(0.0, 0.003, (N, 2)), "noisy"),
        make_demo(loop(stop=0.8), "open"),
        make_demo(loop(), "clean"),
        make_demo(loop(lopsided=1.5) + rng.normal(0.0, 0.0005, (N, 2)), "lopsided"),
    ]


def test_config_defaults_and_validation() -> None:
    config = ScoreConfig()
    assert (config.k, config.beta, config.delta, config.derotate) == (3, 0.5, 1e-12, True)
    assert sum(config.weights) == pytest.approx(1.0)
    assert config.alphas == (0.2, 0.3, 0.5)
    assert ScoreConfig(weights=[0.5, 0.25, 0.25]).weights == (0.5, 0.25, 0.25)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="sum to 1"):
        ScoreConfig(weights=(0.5, 0.5, 0.5))
    with pytest.raises(ConfigError, match=r"\[0, 1\]"):
        ScoreConfig(weights=(1.5, -0.25, -0.25))
    with pytest.raises(ConfigError, match="3 values"):
        ScoreConfig(weights=(0.5, 0.5))  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="beta"):
        ScoreConfig(beta=1.2)
    with pytest.raises(ConfigError, match="k must"):
        ScoreConfig(k=0)
    with pytest.raises(ConfigError, match="delta"):
        ScoreConfig(delta=-1.0)
    with pytest.raises(ConfigError, match="α1"):
        ScoreConfig(alphas=(0.2, 0.3, -0.5))


def test_minmax_normalise_and_delta_guard() -> None:  # Eq. (7)
    np.testing.assert_allclose(minmax_normalise([2.0, 4.0, 3.0, 6.0]), [0.0, 0.5, 0.25, 1.0])
    np.testing.assert_array_equal(minmax_normalise([1.5, 1.5, 1.5]), [0.0, 0.0, 0.0])
    # A range at or below δ normalises to 0; just above it does not.
    np.testing.assert_array_equal(minmax_normalise([1.0, 1.0 + 1e-13], delta=1e-12), [0.0, 0.0])
    np.testing.assert_allclose(minmax_normalise([1.0, 1.0 + 1e-11], delta=1e-12), [0.0, 1.0])
    np.testing.assert_array_equal(minmax_normalise([0.0, 0.5], delta=0.5), [0.0, 0.0])
    with pytest.raises(ConfigError, match=r"\(M,\)"):
        minmax_normalise(np.zeros((2, 2)))
    with pytest.raises(DemoError, match="NaN"):
        minmax_normalise([1.0, np.nan])


def test_normalised_utility_hand_computed() -> None:  # Eq. (8)
    mi_norm = [1.0, 0.0, 0.5]
    loss_norms = [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.5, 0.0, 1.0]]
    weights = (0.5, 0.25, 0.25)
    # Task scores Σ w (1 - L̃): 1, 0, 0.5 * 0.5 + 0.25 * 1 + 0.25 * 0 = 0.5.
    np.testing.assert_allclose(
        normalised_utility(mi_norm, loss_norms, weights, 0.4), [1.0, 0.0, 0.6 * 0.5 + 0.4 * 0.5]
    )
    np.testing.assert_allclose(
        normalised_utility([0.2, 0.8, 0.5], loss_norms, weights, [0.0, 1.0, 0.25]),
        [0.2, 0.0, 0.75 * 0.5 + 0.25 * 0.5],
    )
    with pytest.raises(ConfigError, match="beta"):
        normalised_utility(mi_norm, loss_norms, weights, 1.5)
    with pytest.raises(ConfigError, match="shape"):
        normalised_utility(mi_norm, loss_norms, weights, [0.5, 0.5])
    with pytest.raises(ConfigError, match="sum to 1"):
        normalised_utility(mi_norm, loss_norms, (0.5, 0.5, 0.5), 0.5)
    with pytest.raises(ConfigError, match="J = 2"):
        normalised_utility(mi_norm, loss_norms, (0.5, 0.5), 0.5)


def test_normaliser_freezes_min_and_max() -> None:
    values = np.array([[1.0, 0.0, 5.0], [3.0, 2.0, 5.0], [2.0, 4.0, 5.0]])
    normaliser = Normaliser.from_values(values, names=("a", "b", "c"))
    np.testing.assert_array_equal(normaliser.min, [1.0, 0.0, 5.0])
    np.testing.assert_array_equal(normaliser.max, [3.0, 4.0, 5.0])
    normalised = normaliser.normalise(values)
    for j in range(3):
        np.testing.assert_array_equal(normalised[:, j], minmax_normalise(values[:, j]))
    # New values are mapped by the frozen range and may leave [0, 1] unless clipped.
    new = np.array([5.0, -2.0, 7.0])
    np.testing.assert_allclose(normaliser.normalise(new), [2.0, -0.5, 0.0])
    np.testing.assert_allclose(normaliser.normalise(new, clip=True), [1.0, 0.0, 0.0])
    np.testing.assert_allclose(normaliser.normalise_metric("b", [2.0, 6.0]), [0.5, 1.5])
    offset, scale = normaliser.affine("b")
    assert (offset, scale) == (0.0, 0.25)
    assert normaliser.affine("c") == (5.0, 0.0)
    with pytest.raises(ConfigError, match="unknown metric"):
        normaliser.index("shape")
    with pytest.raises(ConfigError, match=r"\(\.\.\., 3\)"):
        normaliser.normalise(np.zeros(2))
    with pytest.raises(ConfigError, match="min ≤ max"):
        Normaliser(names=("a",), min=np.array([1.0]), max=np.array([0.0]))


def test_raw_metrics_match_the_metric_functions() -> None:
    demo = mixed_set()[0]
    metrics = raw_metrics(demo.positions, demo.actions, None, ScoreConfig(k=4))
    assert metrics.mutual_information == mutual_information(demo.positions, demo.actions, k=4)
    assert metrics.closure == pytest.approx(
        float(np.linalg.norm(demo.positions[0] - demo.positions[-1]))
    )
    assert metrics.as_array().shape == (len(METRIC_NAMES),)
    assert isinstance(metrics, RawMetrics)


def test_clean_demo_beats_noisy_open_and_lopsided_ones() -> None:
    demos = mixed_set()
    result = score_demos(demos)
    assert result.task == "wiping"
    assert [s.demo.name for s in result.scores] == ["noisy", "open", "clean", "lopsided"]
    assert result.best_index == 2
    assert result.best.demo.name == "clean"
    assert result.best.rank == 1
    assert sorted(s.rank for s in result.scores) == [1, 2, 3, 4]
    utilities = np.array([s.utility for s in result.scores])
    assert np.all((utilities >= 0.0) & (utilities <= 1.0))
    assert utilities[2] - np.max(np.delete(utilities, 2)) > 0.2
    # Each defect shows in its own metric.
    noisy, open_, clean, lopsided = result.scores
    assert noisy.smoothness > 10 * clean.smoothness
    assert noisy.mutual_information < clean.mutual_information - 1.0
    assert open_.closure > 0.05 > clean.closure
    assert lopsided.symmetry > 5 * clean.symmetry
    # The utilities follow Eq. (8) from the frozen normaliser.
    normalised = result.normalised_metrics()
    expected = normalised_utility(normalised[:, 0], normalised[:, 1:], (1 / 3,) * 3, 0.5)
    np.testing.assert_allclose(utilities, expected)
    assert select_best(demos) == 2


def test_derotation_uses_the_demo_theta() -> None:
    turned = rotate(loop(), 20.0)
    demos = [make_demo(turned, "known", theta_deg=20.0), make_demo(turned, "unknown")]
    scores = score_demos(demos).scores
    assert scores[0].symmetry < 1e-9
    assert scores[1].symmetry > 1e-3
    off = score_demos(demos, ScoreConfig(derotate=False)).scores
    assert off[0].symmetry == pytest.approx(off[1].symmetry)


def test_single_demo_is_best_with_utility_beta() -> None:
    result = score_demos([make_demo(loop(), "only")], ScoreConfig(beta=0.3))
    assert result.best_index == 0
    assert result.best.rank == 1
    # Every range is 0 ≤ δ, so Ĩ = L̃_j = 0 and Ũ = (1 - β)·0 + β·Σ w_j = β.
    assert result.best.utility == pytest.approx(0.3)


def test_ties_go_to_the_lower_index() -> None:
    demos = [make_demo(loop(stop=0.9), "a"), make_demo(loop(), "b"), make_demo(loop(), "c")]
    result = score_demos(demos)
    assert result.best_index == 1
    assert [s.rank for s in result.scores] == [3, 1, 2]


def test_one_task_at_a_time() -> None:
    demos = [make_demo(loop(), "w"), make_demo(loop(), "x", task="weaving")]
    with pytest.raises(ConfigError, match=r"one task at a time.*wiping, weaving"):
        score_demos(demos)
    with pytest.raises(DemoError, match="no demos"):
        score_demos([])


def test_demo_positions_are_not_mutated() -> None:
    demos = mixed_set()
    copies = [d.positions.copy() for d in demos]
    score_demos(demos)
    for demo, copy in zip(demos, copies, strict=True):
        np.testing.assert_array_equal(demo.positions, copy)


def test_demos_scored_against_a_set_read_on_its_scale() -> None:
    """The one Ũ: a set's own demos read the same against its frozen normaliser as over the set;
    a copy of member k reads member k's Ũ; a demo better than every member in every metric
    reads 1 (clipped to the set's range, never above); the four terms sum to Ũ."""
    rng = np.random.default_rng(7)
    config = ScoreConfig(beta=0.4)
    members = [RawMetrics(*(float(v) for v in rng.uniform(0.1, 1.0, 4))) for _ in range(6)]
    utility, normaliser = set_utilities(members, config)
    np.testing.assert_array_equal(utilities_against(normaliser, members, config), utility)
    values = np.stack([m.as_array() for m in members])
    better = RawMetrics(values[:, 0].max() + 1.0, *(values[:, 1:].min(axis=0) / 2))
    worse = RawMetrics(values[:, 0].min() / 2, *(values[:, 1:].max(axis=0) + 1.0))
    others = utilities_against(normaliser, [members[3], better, worse], config)
    assert others[0] == utility[3]
    assert others[1] == pytest.approx(1.0) and others[2] == pytest.approx(0.0)
    terms = utility_terms(normaliser, [*members, better], config)
    np.testing.assert_allclose(terms.sum(axis=1), [*utility, others[1]], atol=1e-12)
    assert terms[:, 0].max() <= 1.0 - config.beta + 1e-12  # (1 - β) Ĩ with Ĩ ≤ 1
