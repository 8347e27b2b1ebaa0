"""Canonical shapes are closed, smooth, centred, symmetric about y and of the documented size."""

from __future__ import annotations

import numpy as np
import pytest

from bt_pipeline.data.shapes import (
    SHAPE_SIZE,
    canonical_loop,
    canonical_shape,
    rotation_matrix,
    similarity_transform,
)
from bt_pipeline.data.tasks import TASKS
from bt_pipeline.evaluate.distance import chamfer_distance
from bt_pipeline.exceptions import ConfigError, UnknownTaskError


@pytest.mark.parametrize("task", TASKS)
def test_shape_is_periodic_and_closed(task) -> None:
    phase = np.linspace(0.0, 2.0 * np.pi, 50)
    np.testing.assert_allclose(
        canonical_shape(task, phase), canonical_shape(task, phase + 2 * np.pi), atol=1e-12
    )
    loop = canonical_loop(task, 300)
    # The step from the last point back to the first is like the steps beside it.
    steps = np.linalg.norm(np.diff(np.vstack([loop, loop[:1]]), axis=0), axis=1)
    assert steps[-1] == pytest.approx(steps[-2], rel=0.05)
    assert steps[-1] == pytest.approx(steps[0], rel=0.05)


@pytest.mark.parametrize("task", TASKS)
def test_shape_is_smooth(task) -> None:
    # For a C² curve the periodic second difference scales as h²: halving the step quarters it.
    # A kink would only halve it.
    def max_second_difference(n: int) -> float:
        loop = canonical_loop(task, n)
        return float(np.abs(np.roll(loop, -1, 0) - 2 * loop + np.roll(loop, 1, 0)).max())

    ratio = max_second_difference(400) / max_second_difference(800)
    assert ratio == pytest.approx(4.0, rel=0.05)


@pytest.mark.parametrize("task", TASKS)
def test_shape_size_and_centre(task) -> None:
    loop = canonical_loop(task, 4000)
    width, height = SHAPE_SIZE[task]
    np.testing.assert_allclose(loop.max(0) - loop.min(0), [width, height], rtol=1e-3)
    np.testing.assert_allclose(0.5 * (loop.max(0) + loop.min(0)), [0.0, 0.0], atol=1e-4)
    assert 0.2 <= width <= 0.35 and 0.1 <= height <= 0.2


@pytest.mark.parametrize("task", TASKS)
def test_shape_is_mirror_symmetric_about_the_y_axis(task) -> None:
    loop = canonical_loop(task, 2000)
    mirrored = loop * np.array([-1.0, 1.0])
    assert chamfer_distance(loop, mirrored) < 1e-4
    # ... and the test can tell: a shifted loop is not symmetric about the y axis.
    assert chamfer_distance(loop + np.array([0.02, 0.0]), mirrored - np.array([0.02, 0.0])) > 5e-3


def test_pick_and_place_goes_over_high_and_back_low() -> None:
    phase = np.linspace(0.0, 2.0 * np.pi, 401)
    xy = canonical_shape("pick_and_place", phase)
    outbound, back = xy[1:200], xy[201:400]
    assert np.all(np.diff(outbound[:, 0]) > 0) and np.all(np.diff(back[:, 0]) < 0)
    places_y = xy[0, 1]
    assert outbound[:, 1].max() - places_y > 2.5 * (places_y - back[:, 1].min())


def test_weaving_has_two_loops_crossing_at_the_centre() -> None:
    loop = canonical_loop("weaving", 400)
    assert np.min(np.linalg.norm(loop, axis=1)) < 1e-9
    x = loop[:, 0]
    assert np.sum(x > 1e-9) == np.sum(x < -1e-9) == 199  # two lobes, one each side


def test_canonical_loop_excludes_the_endpoint() -> None:
    loop = canonical_loop("wiping", 8)
    expected = canonical_shape("wiping", 2 * np.pi * np.arange(8) / 8)
    np.testing.assert_allclose(loop, expected)
    assert loop.shape == (8, 2)


def test_bad_arguments_are_rejected() -> None:
    with pytest.raises(UnknownTaskError, match="task 'painting' has no built-in guide shape"):
        canonical_shape("painting", np.zeros(3))
    with pytest.raises(UnknownTaskError, match="invalid task name"):
        canonical_loop("../wiping")
    with pytest.raises(ConfigError, match="n >= 3"):
        canonical_loop("wiping", 2)
    with pytest.raises(ConfigError, match="rho"):
        similarity_transform(np.zeros((3, 2)), 0.0, 0.0)
    with pytest.raises(ConfigError, match="last axis"):
        similarity_transform(np.zeros((3, 3)), 0.0, 1.0)
    with pytest.raises(ConfigError, match="centre"):
        similarity_transform(np.zeros((3, 2)), 0.0, 1.0, centre=(1.0, 2.0, 3.0))


def test_similarity_transform_rotates_counter_clockwise_and_scales() -> None:
    out = similarity_transform(np.array([[1.0, 0.0]]), 90.0, 2.0, centre=(0.5, -0.5))
    np.testing.assert_allclose(out, [[0.5, 1.5]], atol=1e-12)


def test_similarity_transform_composition_and_inverse() -> None:
    rng = np.random.default_rng(0)
    points = rng.normal(size=(20, 2))
    centre = np.array([0.3, -0.2])
    # Composition about the origin: (θ2, ρ2) ∘ (θ1, ρ1) = (θ1 + θ2, ρ1 ρ2).
    np.testing.assert_allclose(
        similarity_transform(similarity_transform(points, 10.0, 1.2), -35.0, 0.5),
        similarity_transform(points, -25.0, 0.6),
        atol=1e-12,
    )
    # Inverse: (-θ, 1/ρ) applied to q - c.
    forward = similarity_transform(points, 17.0, 1.3, centre=centre)
    np.testing.assert_allclose(similarity_transform(forward - centre, -17.0, 1 / 1.3), points)
    # Distances scale by ρ; the caller's array is not touched.
    before = points.copy()
    d_in = np.linalg.norm(points[1:] - points[:-1], axis=1)
    d_out = np.linalg.norm(forward[1:] - forward[:-1], axis=1)
    np.testing.assert_allclose(d_out, 1.3 * d_in)
    np.testing.assert_array_equal(points, before)


def test_rotation_matrix_is_orthonormal() -> None:
    r = rotation_matrix(37.0)
    np.testing.assert_allclose(r @ r.T, np.eye(2), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)


def test_a_placed_loop_stays_placed_travelled_the_other_way_or_started_elsewhere() -> None:
    """A loop kept where its demo drew it is the same points in the same place reversed or
    started at another phase; turned, scaled or moved it is not (LoopShape.placed, near_guide)."""
    from bt_pipeline.data.loop_shape import LoopShape

    c = np.zeros(5, dtype=complex)
    c[3], c[4], c[2] = 0.1, 0.02j, 0.004  # an egg 4 mm off the origin
    loop = LoopShape(c, "egg", placed=True)
    assert loop.anchored and loop.reversed().placed and loop.started_at(1.0).placed
    assert not loop.transformed(10.0).placed and not LoopShape(c, "egg").anchored
    assert LoopShape.guide("wiping").anchored
    # A loop that replaced a guide it lies near stays fitted against as that guide was.
    near = LoopShape(c, "egg", placed=True, near_guide=True)
    assert near.reversed().near_guide and near.started_at(1.0).near_guide
    assert not near.transformed(10.0).near_guide and not loop.near_guide
    ring = loop.points(64)
    assert chamfer_distance(loop.reversed().points(64), ring) < 1e-3
