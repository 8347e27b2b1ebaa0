"""Tests of the rhythmic DMP: fit, exact rollout, limit cycle, period estimation, bad demos."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from bt_pipeline.clean.stage1.dmp import DmpConfig, fit_periodic_dmp
from bt_pipeline.clean.stage1.extract import canonical_reference
from bt_pipeline.clean.stage1.period import estimate_period, loop_size
from bt_pipeline.data.shapes import canonical_shape, similarity_transform
from bt_pipeline.data.tasks import TASKS
from bt_pipeline.exceptions import ConfigError, DemoError

N = 300
CENTRE = np.array([0.4, -0.1])


def ellipse(phase: np.ndarray) -> np.ndarray:
    return CENTRE + np.stack([0.12 * np.cos(phase), 0.06 * np.sin(phase)], axis=-1)


def figure_eight(phase: np.ndarray) -> np.ndarray:
    return CENTRE + np.stack([0.15 * np.sin(phase), 0.075 * np.sin(2 * phase)], axis=-1)


def one_loop(shape, start: float = 0.7, n: int = N) -> np.ndarray:
    """One closed loop on t ∈ [0, 1], last sample equal to the first."""
    return shape(start + 2 * np.pi * np.linspace(0.0, 1.0, n))


@pytest.mark.parametrize("shape", [ellipse, figure_eight])
def test_canonical_reference_reproduces_a_periodic_demo(shape) -> None:
    demo = one_loop(shape)
    dmp = fit_periodic_dmp(demo)
    x_d = canonical_reference(dmp, demo)
    assert x_d.shape == (N, 2)
    np.testing.assert_allclose(x_d[-1], x_d[0])
    error = np.linalg.norm(x_d - demo, axis=1)
    assert error.mean() < 0.01 * loop_size(demo)
    assert dmp.period == pytest.approx(1.0)
    np.testing.assert_allclose(dmp.anchor, CENTRE, atol=1e-3 * loop_size(demo))


def test_more_basis_functions_blur_less() -> None:
    demo = one_loop(figure_eight)
    errors = [
        np.linalg.norm(
            canonical_reference(fit_periodic_dmp(demo, config=cfg), demo) - demo, axis=1
        ).mean()
        for cfg in (DmpConfig(n_basis=30), DmpConfig(n_basis=120))
    ]
    assert errors[1] < 0.5 * errors[0]


@pytest.mark.parametrize("task", TASKS)
def test_the_default_reproduces_each_task_shape_within_half_a_millimetre(task) -> None:
    """The default's blur stays below the expert's own noise (120 bases: 0.5-1.1 mm)."""
    phase = 0.7 + 2 * np.pi * np.arange(N) / (N - 1)
    demo = similarity_transform(canonical_shape(task, phase), 10.0, 1.2)
    reproduced = canonical_reference(fit_periodic_dmp(demo), demo)
    assert np.linalg.norm(reproduced - demo, axis=1).mean() < 0.0004


def test_rollout_matches_numerical_integration() -> None:
    demo = one_loop(figure_eight)
    dmp = fit_periodic_dmp(demo)
    y0, z0 = demo[0] + [0.02, -0.01], np.array([0.05, 0.0])

    def rhs(s: float, u: np.ndarray) -> np.ndarray:  # Elapsed phase s, state (e, z).
        e, z = u[:2], u[2:]
        return np.concatenate([z, dmp.alpha_z * (-dmp.beta_z * e - z) + dmp.forcing(np.array(s))])

    s_eval = 2 * np.pi * np.arange(400) / 200
    solution = solve_ivp(
        rhs,
        (0.0, s_eval[-1]),
        np.concatenate([y0 - dmp.anchor, z0]),
        t_eval=s_eval,
        rtol=1e-10,
        atol=1e-12,
        max_step=0.01,
    )
    rollout = dmp.rollout(y0, z0, n_periods=2, samples_per_period=200)
    np.testing.assert_allclose(rollout, solution.y[:2].T + dmp.anchor, atol=1e-8)


def test_perturbed_rollouts_converge_to_the_limit_cycle() -> None:
    demo = one_loop(ellipse)
    dmp = fit_periodic_dmp(demo)
    rng = np.random.default_rng(3)
    y0 = demo[0] + rng.normal(0.0, 0.05, size=(16, 2))
    z0 = rng.normal(0.0, 0.1, size=(16, 2))
    paths = dmp.rollout(y0, z0, n_periods=3, samples_per_period=100, phase0=0.0)
    cycle, _ = dmp.limit_cycle(100)
    assert paths.shape == (16, 300, 2)
    start_gap = np.linalg.norm(paths[:, 0] - cycle[0], axis=-1)
    end_gap = np.linalg.norm(paths[:, -100:] - cycle, axis=-1)
    assert start_gap.min() > 1e-3
    assert end_gap.max() < 1e-9


def test_limit_cycle_at_a_phase_offset_is_the_shifted_cycle() -> None:
    dmp = fit_periodic_dmp(one_loop(figure_eight))
    cycle, z = dmp.limit_cycle(240)
    shifted, z_shifted = dmp.limit_cycle(240, phase0=2 * np.pi * 30 / 240)
    np.testing.assert_allclose(shifted, np.roll(cycle, -30, axis=0), atol=1e-12)
    np.testing.assert_allclose(z_shifted, np.roll(z, -30, axis=0), atol=1e-12)
    assert dmp.phase_of(cycle[60]) == pytest.approx(2 * np.pi * 60 / 240, abs=2e-3)


@pytest.mark.parametrize("cycles", [1.5, 2.5, 4.0])
@pytest.mark.parametrize("shape", [ellipse, figure_eight])
def test_estimate_period(cycles: float, shape) -> None:
    t = np.linspace(0.0, 1.0, N)
    positions = shape(0.4 + 2 * np.pi * cycles * t)
    positions += np.random.default_rng(0).normal(0.0, 0.002, size=positions.shape)
    assert 1.0 / estimate_period(positions) == pytest.approx(cycles, rel=0.02)


def test_repeating_demo_is_fitted_with_its_period() -> None:
    t = np.linspace(0.0, 1.0, N)
    demo = ellipse(2 * np.pi * 2.5 * t)
    dmp = fit_periodic_dmp(demo)
    assert dmp.period == pytest.approx(0.4, rel=0.01)
    cycle, _ = dmp.limit_cycle(200)
    truth = ellipse(2 * np.pi * np.arange(200) / 200)
    distance = np.min(np.linalg.norm(cycle[:, None] - truth[None], axis=-1), axis=1)
    assert distance.mean() < 0.01 * loop_size(demo)


def test_incomplete_loop_is_fitted_as_one_loop() -> None:
    demo = ellipse(0.3 + 2 * np.pi * 0.85 * np.linspace(0.0, 1.0, N))
    dmp = fit_periodic_dmp(demo)
    assert dmp.period == pytest.approx(1.0)


def test_closed_motion_along_a_line_is_periodic() -> None:
    s = np.sin(2 * np.pi * np.linspace(0.0, 1.0, N))
    demo = CENTRE + np.stack([0.1 * s, 0.05 * s], axis=1)
    x_d = canonical_reference(fit_periodic_dmp(demo), demo)
    assert np.linalg.norm(x_d - demo, axis=1).mean() < 0.01 * loop_size(demo)


@pytest.mark.parametrize(
    ("positions", "fragment"),
    [
        (np.tile([0.3, 0.2], (N, 1)), "does not move"),
        (np.where(np.arange(N)[:, None] == 5, np.nan, one_loop(ellipse)), "NaN"),
        (one_loop(ellipse, n=10), "10 samples"),
        (CENTRE + np.linspace(0.0, 1.0, N)[:, None] * [0.2, 0.1], "not periodic"),
    ],
    ids=["constant", "nan", "short", "straight-line"],
)
def test_bad_demos_raise_demo_error_naming_the_demo(positions, fragment: str) -> None:
    with pytest.raises(DemoError, match=fragment) as info:
        fit_periodic_dmp(positions, name="rec.hdf5:demo_7")
    assert "rec.hdf5:demo_7" in str(info.value)


def test_invalid_config_is_rejected() -> None:
    with pytest.raises(ConfigError, match="n_basis"):
        DmpConfig(n_basis=2)
    with pytest.raises(ConfigError, match="max_open_gap"):
        DmpConfig(one_loop_gap=0.3, max_open_gap=0.2)
    with pytest.raises(ConfigError, match="period"):
        fit_periodic_dmp(one_loop(ellipse), period=-1.0)


def test_inputs_are_not_mutated_and_results_are_frozen() -> None:
    demo = one_loop(ellipse)
    before = demo.copy()
    dmp = fit_periodic_dmp(demo)
    canonical_reference(dmp, demo)
    np.testing.assert_array_equal(demo, before)
    with pytest.raises(ValueError, match="read-only"):
        dmp.weights[0, 0] = 1.0
