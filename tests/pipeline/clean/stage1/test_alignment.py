"""Tests of preferences (θ, ρ), their estimation, phase alignment and L4."""

from __future__ import annotations

import numpy as np
import pytest

from bt_pipeline.clean.stage1.alignment import (
    apply_preference,
    estimate_preference,
    phase_align,
    remove_preference,
    rotation_matrix,
    shape_loss,
)
from bt_pipeline.exceptions import ConfigError

N = 300
P = N - 1


def egg(phase: np.ndarray) -> np.ndarray:
    """An asymmetric loop (no rotational or mirror symmetry), about the origin."""
    r = 1.0 + 0.3 * np.cos(phase) + 0.1 * np.sin(2 * phase)
    return 0.1 * np.stack([r * np.cos(phase), 0.6 * r * np.sin(phase)], axis=-1)


def closed(phase_start: float, reverse: bool = False, n: int = N) -> np.ndarray:
    """The egg as a closed loop of n samples starting at phase_start."""
    sign = -1.0 if reverse else 1.0
    return egg(phase_start + sign * 2 * np.pi * np.arange(n) / (n - 1))


def rolled(loop: np.ndarray, shift: int, reverse: bool = False) -> np.ndarray:
    """A closed loop started `shift` samples later (and reversed), still closed."""
    distinct = np.roll(loop[:-1], -shift, axis=0)
    if reverse:
        distinct = np.roll(distinct[::-1], 1, axis=0)
    return np.concatenate([distinct, distinct[:1]])


def test_rotation_is_counter_clockwise_in_degrees() -> None:
    np.testing.assert_allclose(rotation_matrix(90.0) @ [1.0, 0.0], [0.0, 1.0], atol=1e-15)


def test_apply_undoes_remove() -> None:
    x = np.random.default_rng(0).normal(size=(N, 2))
    centre = np.array([0.3, -0.2])
    x_g = remove_preference(x, 7.5, 1.2, centre)
    np.testing.assert_allclose(apply_preference(x_g, 7.5, 1.2, centre), x, atol=1e-14)
    np.testing.assert_allclose(
        remove_preference(apply_preference(x, -10.0, 1.3, centre), -10.0, 1.3, centre), x
    )
    with pytest.raises(ConfigError, match="rho"):
        apply_preference(x, 0.0, 0.0, centre)


@pytest.mark.parametrize("reverse", [False, True])
@pytest.mark.parametrize(("theta", "rho"), [(10.0, 1.3), (-5.0, 0.8), (150.0, 1.0)])
@pytest.mark.parametrize("refine", [False, True])
def test_estimate_preference_is_exact_on_noise_free_shapes(
    theta: float, rho: float, reverse: bool, refine: bool
) -> None:
    x_g = closed(0.0)
    translation = np.array([0.45, -0.05])
    demo = apply_preference(rolled(x_g, 83, reverse), theta, rho, translation)
    fit = estimate_preference(demo, x_g, refine=refine)
    assert fit.theta_deg == pytest.approx(theta, abs=1e-6)
    assert fit.rho == pytest.approx(rho, rel=1e-8)
    np.testing.assert_allclose(fit.translation, translation, atol=1e-9)


def test_estimate_preference_copes_with_uneven_speed_and_an_incomplete_loop() -> None:
    x_g = closed(0.0)
    t = np.linspace(0.0, 1.0, N)
    phase = 1.0 + 2 * np.pi * 0.8 * (t + 0.08 * np.sin(2 * np.pi * t))  # 80% of the loop.
    demo = apply_preference(egg(phase), 12.0, 1.15, [0.2, 0.1])
    coarse = estimate_preference(demo, x_g, refine=False)
    fine = estimate_preference(demo, x_g)
    assert abs(fine.rho - 1.15) < 0.003
    assert abs(fine.theta_deg - 12.0) < 0.3
    assert abs(fine.rho - 1.15) < abs(coarse.rho - 1.15)


@pytest.mark.parametrize("reverse", [False, True])
def test_shape_loss_is_phase_and_direction_invariant(reverse: bool) -> None:
    reference = closed(0.0)
    exact = rolled(reference, 123, reverse)
    assert shape_loss(exact, reference) == pytest.approx(0.0, abs=1e-15)
    # A start phase between two samples costs at most half a sample spacing.
    between = closed(2 * np.pi * 0.37, reverse)
    spacing = np.linalg.norm(np.diff(reference, axis=0), axis=1).max()
    assert shape_loss(between, reference) < 0.5 * spacing
    if reverse:
        assert shape_loss(between, reference, allow_reversal=False) > 10 * spacing


def test_phase_align_reorders_the_reference_onto_the_demo() -> None:
    reference = closed(0.0)
    demo = rolled(reference, 40, reverse=True)
    alignment = phase_align(reference, demo)
    assert alignment.reversed
    np.testing.assert_allclose(alignment.aligned, demo, atol=1e-15)
    assert alignment.aligned[0] == pytest.approx(reference[alignment.shift])


def test_phase_align_finds_the_brute_force_minimum() -> None:
    """Also on demos with uneven speed and incomplete loops, where the squared-distance optimum
    is not the Euclidean one."""
    rng = np.random.default_rng(4)
    reference = closed(0.0)
    t = np.linspace(0.0, 1.0, N)
    k = np.arange(N)
    for trial in range(12):
        warp = t + rng.uniform(0.0, 0.12) * np.sin(2 * np.pi * rng.integers(1, 4) * t)
        sign = -1.0 if trial % 2 else 1.0
        phase = rng.uniform(0, 2 * np.pi) + sign * 2 * np.pi * rng.uniform(0.75, 1.0) * warp
        demo = egg(phase) * rng.uniform(0.8, 1.2) + rng.normal(0.0, 0.01, size=(N, 2))
        brute = min(
            np.linalg.norm(reference[:-1][index] - demo, axis=1).mean()
            for s in range(P)
            for index in ((s + k) % P, (s - k) % P)
        )
        assert phase_align(reference, demo).loss == pytest.approx(brute, rel=1e-12)


def test_different_shapes_have_a_positive_loss() -> None:
    reference = closed(0.0)
    assert shape_loss(1.2 * reference, reference) > 0.01


def test_reference_must_be_closed_and_shapes_must_match() -> None:
    open_reference = egg(2 * np.pi * np.arange(N) / N)
    with pytest.raises(ConfigError, match="closed"):
        phase_align(open_reference, closed(0.0))
    with pytest.raises(ConfigError, match="shape"):
        shape_loss(closed(0.0, n=100), closed(0.0))


def test_phase_align_stops_on_flat_costs() -> None:
    """A reference shrunk to a point (ρ = 1e-300) gives equal costs: the descent must stop."""
    from bt_pipeline.clean.stage1.alignment import apply_preference, phase_align

    t = np.linspace(0.0, 2 * np.pi, 61)
    loop = np.stack([np.cos(t), np.sin(t)], axis=1) * 0.1
    flat = apply_preference(loop, 0.0, 1e-300, np.zeros(2))
    result = phase_align(flat, loop)
    assert np.isfinite(result.loss)


def test_phase_align_names_the_demo_on_non_finite_costs() -> None:
    """One sample at 1e30 overflows the squared costs: a DemoError naming the demo, no hang."""
    import pytest

    from bt_pipeline.clean.stage1.alignment import phase_align
    from bt_pipeline.exceptions import DemoError

    t = np.linspace(0.0, 2 * np.pi, 61)
    loop = np.stack([np.cos(t), np.sin(t)], axis=1) * 0.1
    demo = loop.copy()
    demo[5] = np.nan
    with pytest.raises(DemoError, match="demo_7"):
        phase_align(loop, demo, name="demo_7")


def test_phase_align_ends_with_one_sample_at_1e30() -> None:
    """Costs dominated by one huge sample are flat over shifts: the bounded descent stops."""
    from bt_pipeline.clean.stage1.alignment import phase_align

    t = np.linspace(0.0, 2 * np.pi, 61)
    loop = np.stack([np.cos(t), np.sin(t)], axis=1) * 0.1
    demo = loop.copy()
    demo[3] = 1e30
    result = phase_align(loop, demo)
    assert result.loss > 1e27


def test_period_search_names_the_demo_on_non_finite_positions() -> None:
    import pytest

    from bt_pipeline.clean.stage1.period import estimate_period
    from bt_pipeline.exceptions import DemoError

    t = np.linspace(0.0, 4 * np.pi, 200)
    x = np.stack([np.cos(t), np.sin(t)], axis=1)
    x[10] = np.inf
    with pytest.raises(DemoError, match="demo_4"):
        estimate_period(x, name="demo_4")
    x[10] = 1e300  # squares overflow: a clear error, not a hang
    with pytest.raises(DemoError, match="demo_4"):
        estimate_period(x, name="demo_4")
