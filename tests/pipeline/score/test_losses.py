"""Tests of the task-intention losses L1-L3 (bt_pipeline.score.losses)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bt_pipeline.exceptions import ConfigError, DemoError
from bt_pipeline.score.losses import closure_loss, smoothness_loss, symmetry_loss

N = 400


def symmetric_curve(n: int = N, phase: float = 0.0) -> np.ndarray:
    """A closed curve mirror-symmetric about the vertical axis x = 0, shape (n, 2) [m].

    x(t) is odd and y(t) even in t, so (-x(t), y(t)) = x(-t). With phase 0 the samples on
    t = k / (n - 1) are mirror images of each other; another phase shifts them along the curve.
    """
    t = np.linspace(0.0, 1.0, n) + phase
    x = 0.1 * np.sin(2 * np.pi * t)
    y = 0.05 * np.cos(4 * np.pi * t) + 0.02 * np.cos(2 * np.pi * t)
    return np.column_stack([x, y])


def lopsided_curve(n: int = N) -> np.ndarray:
    """The symmetric curve with its right half stretched by 1.6."""
    curve = symmetric_curve(n)
    curve[:, 0] = np.where(curve[:, 0] > 0.0, 1.6 * curve[:, 0], curve[:, 0])
    return curve


def open_noisy_curve(n: int = N, seed: int = 0) -> np.ndarray:
    """Three quarters of a lopsided loop with position noise: every loss is clearly > 0."""
    rng = np.random.default_rng(seed)
    return lopsided_curve(n)[: 3 * n // 4] + rng.normal(0.0, 0.002, (3 * n // 4, 2))


def rotate(points: np.ndarray, angle_deg: float, about: np.ndarray) -> np.ndarray:
    angle = math.radians(angle_deg)
    rotation = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    return (points - about) @ rotation.T + about


def all_losses(points: np.ndarray) -> np.ndarray:
    return np.array([symmetry_loss(points), closure_loss(points), smoothness_loss(points)])


def test_mirror_symmetric_curve_has_zero_symmetry_loss() -> None:
    assert symmetry_loss(symmetric_curve()) < 1e-12
    # Samples that are not mirror images of each other: L1 is bounded by the sample spacing.
    spacing = float(np.max(np.linalg.norm(np.diff(symmetric_curve(), axis=0), axis=1)))
    shifted = symmetric_curve(phase=0.3 / N)
    assert 0.0 < symmetry_loss(shifted) < spacing
    assert symmetry_loss(lopsided_curve()) > 3 * spacing


def test_symmetry_loss_hand_computed() -> None:
    # C_x = 4/3; mirrors at 8/3, 5/3, -1/3; nearest distances 1/3, 2/3, 1/3.
    points = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0]])
    assert symmetry_loss(points) == pytest.approx(4.0 / 9.0, abs=1e-15)
    assert symmetry_loss(np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 1.0]])) == 0.0


def test_closed_loop_has_exactly_zero_closure_loss() -> None:
    curve = symmetric_curve()
    loop = np.vstack([curve[:-1], curve[:1]])
    assert closure_loss(loop) == 0.0
    assert closure_loss(np.array([[0.0, 0.0], [5.0, 5.0], [3.0, 4.0]])) == 5.0


def test_smoothness_loss_hand_computed() -> None:
    # D = [1, 2, 3] -> 14; D² = [1, 1] -> 2; D³ = [0] -> 0.
    points = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0], [6.0, 0.0]])
    assert smoothness_loss(points) == pytest.approx(0.2 * 14 + 0.3 * 2, abs=1e-12)
    assert smoothness_loss(points, alphas=(0.0, 0.0, 1.0)) == 0.0
    assert smoothness_loss(points, alphas=(1.0, 0.0, 0.0)) == pytest.approx(14.0)
    # The second coordinate counts too (squared Frobenius norm).
    both = np.column_stack([points[:, 0], 2 * points[:, 0]])
    assert smoothness_loss(both) == pytest.approx(5 * smoothness_loss(points))


def test_losses_are_translation_invariant() -> None:
    curve = open_noisy_curve()
    moved = curve + np.array([0.37, -1.2])
    losses, moved_losses = all_losses(curve), all_losses(moved)
    assert np.all(losses > 1e-4)
    np.testing.assert_allclose(moved_losses, losses, rtol=1e-9)
    assert symmetry_loss(moved, theta_deg=20.0) == pytest.approx(
        symmetry_loss(curve, theta_deg=20.0), rel=1e-9
    )


@pytest.mark.parametrize("angle_deg", [15.0, -40.0, 90.0])
def test_closure_and_smoothness_are_rotation_invariant(angle_deg: float) -> None:
    curve = open_noisy_curve()
    turned = rotate(curve, angle_deg, about=np.array([0.3, 0.1]))
    assert closure_loss(turned) == pytest.approx(closure_loss(curve), rel=1e-9)
    assert smoothness_loss(turned) == pytest.approx(smoothness_loss(curve), rel=1e-9)


@pytest.mark.parametrize("theta_deg", [10.0, -25.0])
def test_symmetry_loss_derotates_by_theta(theta_deg: float) -> None:
    turned = rotate(symmetric_curve(), theta_deg, about=np.array([0.2, -0.1]))
    assert symmetry_loss(turned, theta_deg=theta_deg) < 1e-12
    assert symmetry_loss(turned) > 1e-3
    assert symmetry_loss(turned, theta_deg=-theta_deg) > 1e-3  # the sign matters
    assert symmetry_loss(symmetric_curve(), theta_deg=0.0) < 1e-12


@pytest.mark.parametrize("factor", [0.5, 3.0])
def test_scale_behaviour(factor: float) -> None:
    curve = open_noisy_curve()
    s1, s2, s3 = all_losses(curve)
    scaled = factor * curve
    assert symmetry_loss(scaled) == pytest.approx(factor * s1, rel=1e-9)
    assert closure_loss(scaled) == pytest.approx(factor * s2, rel=1e-9)
    assert smoothness_loss(scaled) == pytest.approx(factor**2 * s3, rel=1e-9)


def test_noise_raises_smoothness_loss() -> None:
    rng = np.random.default_rng(1)
    curve = symmetric_curve()
    clean = smoothness_loss(curve)
    slightly = smoothness_loss(curve + rng.normal(0.0, 0.001, curve.shape))
    very = smoothness_loss(curve + rng.normal(0.0, 0.005, curve.shape))
    assert clean < slightly < very


def test_inputs_are_not_mutated() -> None:
    curve = open_noisy_curve()
    copy = curve.copy()
    all_losses(curve)
    symmetry_loss(curve, theta_deg=30.0)
    np.testing.assert_array_equal(curve, copy)


def test_invalid_inputs_raise() -> None:
    curve = symmetric_curve()
    with pytest.raises(DemoError, match=r"\(N, 2\)"):
        symmetry_loss(np.zeros((10, 3)))
    with pytest.raises(DemoError, match="shape"):
        closure_loss(np.zeros(10))
    with pytest.raises(DemoError, match="at least 4 samples"):
        smoothness_loss(curve[:3])
    bad = curve.copy()
    bad[5, 0] = np.inf
    with pytest.raises(DemoError, match="NaN or infinite"):
        smoothness_loss(bad)
    with pytest.raises(ConfigError, match="α1, α2, α3"):
        smoothness_loss(curve, alphas=(0.2, 0.3))
    with pytest.raises(ConfigError, match="α1, α2, α3"):
        smoothness_loss(curve, alphas=(0.2, -0.3, 0.5))
    with pytest.raises(ConfigError, match="theta_deg"):
        symmetry_loss(curve, theta_deg=math.nan)
