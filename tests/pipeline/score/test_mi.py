"""Tests of the KSG-1 mutual-information estimator (bt_pipeline.score.mi)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sklearn.feature_selection._mutual_info import _compute_mi_cc

from bt_pipeline.exceptions import ConfigError, DemoError
from bt_pipeline.score.mi import _mutual_information_bruteforce, mutual_information


def correlated_pairs(
    n: int, r: float, seed: int, dims: int = 2
) -> tuple[np.ndarray, np.ndarray, float]:
    """S, A of shape (n, dims) with corr(s_j, a_j) = r, other pairs independent; true MI [nats]."""
    rng = np.random.default_rng(seed)
    s = rng.standard_normal((n, dims))
    a = r * s + math.sqrt(1.0 - r**2) * rng.standard_normal((n, dims))
    return s, a, -0.5 * dims * math.log(1.0 - r**2)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_independent_gaussians_give_near_zero(seed: int) -> None:
    s, a, truth = correlated_pairs(300, 0.0, seed)
    assert truth == 0.0
    assert abs(mutual_information(s, a)) < 0.15


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_two_correlated_pairs_match_analytic_value(seed: int) -> None:
    s, a, truth = correlated_pairs(300, 0.5, seed)
    assert truth == pytest.approx(0.2877, abs=1e-4)
    assert mutual_information(s, a) == pytest.approx(truth, abs=0.15)


def test_bias_shrinks_with_sample_count() -> None:
    def mean_abs_error(n: int) -> float:
        errors = []
        for seed in range(3):
            s, a, truth = correlated_pairs(n, 0.9, seed)
            errors.append(abs(mutual_information(s, a) - truth))
        return float(np.mean(errors))

    small, large = mean_abs_error(300), mean_abs_error(2000)
    assert large < small
    assert large < 0.1


def test_estimate_is_not_clamped_at_zero() -> None:
    estimates = [mutual_information(*correlated_pairs(300, 0.0, seed)[:2]) for seed in range(10)]
    assert min(estimates) < 0.0


@pytest.mark.parametrize("seed", [0, 1])
def test_equals_sklearn_on_1d_data_without_jitter(seed: int) -> None:
    rng = np.random.default_rng(seed)
    x = rng.standard_normal(400)
    y = 0.8 * x + 0.6 * rng.standard_normal(400) * 3.0
    expected = _compute_mi_cc(x, y, 3)
    assert expected > 0.1  # sklearn clamps at 0: a dependent pair keeps the test meaningful
    assert mutual_information(x, y, 3, standardise=False, jitter=0.0) == pytest.approx(
        expected, abs=1e-12
    )
    # sklearn's _estimate_mi divides by the standard deviation before _compute_mi_cc.
    expected_std = _compute_mi_cc(x / np.std(x), y / np.std(y), 3)
    assert mutual_information(x, y, 3, jitter=0.0) == pytest.approx(expected_std, abs=1e-12)


@pytest.mark.parametrize(("k", "standardise", "jitter"), [(3, True, 1e-10), (1, False, 0.0)])
def test_bruteforce_reference_agrees(k: int, standardise: bool, jitter: float) -> None:
    s, a, _ = correlated_pairs(250, 0.7, seed=4)
    kwargs = {"standardise": standardise, "jitter": jitter, "seed": 3}
    fast = mutual_information(s, a, k, **kwargs)
    slow = _mutual_information_bruteforce(s, a, k, **kwargs)
    assert fast == pytest.approx(slow, abs=1e-12)


def test_standardisation_removes_coordinate_scale() -> None:
    s, a, _ = correlated_pairs(300, 0.7, seed=5)
    scaled_a = a * np.array([100.0, 0.01])
    assert mutual_information(s, scaled_a) == pytest.approx(mutual_information(s, a), abs=1e-6)
    # Without standardisation the max-norm is dominated by the large coordinate.
    raw = mutual_information(s, scaled_a, standardise=False)
    assert abs(raw - mutual_information(s, a)) > 0.05


def test_jitter_breaks_ties_of_repeated_samples() -> None:
    s, a, _ = correlated_pairs(200, 0.8, seed=6)
    # A robot at rest repeats samples; a constant coordinate must not divide by zero.
    s = np.vstack([s, np.repeat(s[:1], 40, axis=0)])
    a = np.vstack([a, np.zeros((40, 2))])
    a[:, 1] = 0.0
    value = mutual_information(s, a, seed=1)
    assert math.isfinite(value)
    assert value == mutual_information(s, a, seed=1)  # seeded
    assert value != mutual_information(s, a, seed=2)


def test_inputs_are_not_mutated() -> None:
    s, a, _ = correlated_pairs(100, 0.5, seed=7)
    s_copy, a_copy = s.copy(), a.copy()
    mutual_information(s, a)
    _mutual_information_bruteforce(s, a)
    np.testing.assert_array_equal(s, s_copy)
    np.testing.assert_array_equal(a, a_copy)


def test_invalid_inputs_raise() -> None:
    s, a, _ = correlated_pairs(50, 0.5, seed=8)
    with pytest.raises(DemoError, match="same number of samples"):
        mutual_information(s, a[:-1])
    bad = s.copy()
    bad[3, 1] = np.nan
    with pytest.raises(DemoError, match="NaN"):
        mutual_information(bad, a)
    with pytest.raises(DemoError, match="more than 3 samples"):
        mutual_information(s[:3], a[:3])
    with pytest.raises(DemoError, match="shape"):
        mutual_information(s[:, :, None], a)
    with pytest.raises(ConfigError, match="k must be"):
        mutual_information(s, a, k=0)
    with pytest.raises(ConfigError, match="jitter"):
        mutual_information(s, a, jitter=-1.0)
