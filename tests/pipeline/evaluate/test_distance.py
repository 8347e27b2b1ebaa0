"""Chamfer distance: zero for identical sets, symmetric, order-free, grows with misplacement."""

from __future__ import annotations

import numpy as np
import pytest

from bt_pipeline.data.shapes import canonical_loop
from bt_pipeline.evaluate.distance import PointSet, chamfer_distance, distance_to_truth
from bt_pipeline.exceptions import ConfigError


def test_zero_for_identical_curves() -> None:
    loop = canonical_loop("weaving", 300)
    assert chamfer_distance(loop, loop) == 0.0


def test_symmetric_and_independent_of_point_order() -> None:
    rng = np.random.default_rng(1)
    a = canonical_loop("wiping", 300) + rng.normal(0, 0.003, (300, 2))
    b = canonical_loop("wiping", 500)
    assert chamfer_distance(a, b) == pytest.approx(chamfer_distance(b, a))
    # Phase-free: a circular shift and a reversal change nothing.
    shuffled = np.roll(a, 77, axis=0)[::-1]
    assert chamfer_distance(shuffled, b) == pytest.approx(chamfer_distance(a, b))


def test_known_value_for_two_point_sets() -> None:
    a = np.array([[0.0, 0.0], [1.0, 0.0]])
    b = np.array([[0.0, 1.0]])
    # a→b: 1 and √2; b→a: 1.
    assert chamfer_distance(a, b) == pytest.approx(0.5 * ((1 + np.sqrt(2)) / 2 + 1))


@pytest.mark.parametrize("shift", [0.005, 0.01, 0.03])
def test_translation_raises_the_distance(shift) -> None:
    loop = canonical_loop("pick_and_place", 600)
    smaller = chamfer_distance(loop + np.array([shift / 2, 0.0]), loop)
    larger = chamfer_distance(loop + np.array([shift, 0.0]), loop)
    assert 0.0 < smaller < larger <= shift


def test_distance_to_truth_sees_a_missing_part() -> None:
    truth = canonical_loop("wiping", 600)
    complete = canonical_loop("wiping", 300)
    partial = complete[:210]  # 70 % of the loop: no point is off the truth, a part is missing
    assert distance_to_truth(complete, truth) < 1e-3
    assert distance_to_truth(partial, truth) > 3 * distance_to_truth(complete, truth)


def test_bad_inputs_are_rejected() -> None:
    loop = canonical_loop("wiping", 20)
    with pytest.raises(ConfigError, match=r"shape \(n, d\)"):
        chamfer_distance(loop[:, 0], loop)
    with pytest.raises(ConfigError, match="same dimension"):
        chamfer_distance(loop, np.zeros((5, 3)))
    with pytest.raises(ConfigError, match="NaN"):
        distance_to_truth(np.full((4, 2), np.nan), loop)
    with pytest.raises(ConfigError, match="n >= 1"):
        distance_to_truth(np.zeros((0, 2)), loop)


def test_point_sets_give_chamfer_distance_bit_for_bit_and_the_gaps() -> None:
    rng = np.random.default_rng(3)
    curve = rng.normal(size=(120, 2))
    sets = [PointSet.of(rng.normal(size=(n, 2))) for n in (40, 300)]
    drawn = PointSet.of(curve)
    for other in sets:
        assert drawn.chamfer(other) == chamfer_distance(curve, other.points)
        assert other.chamfer(drawn) == chamfer_distance(other.points, curve)
        brute = np.min(np.linalg.norm(other.points[:, None] - curve[None], axis=2), axis=1)
        np.testing.assert_allclose(drawn.gaps(other.points), brute, rtol=1e-12)
    with pytest.raises(ConfigError, match="a rollout"):
        PointSet.of(np.full((5, 2), np.nan), "a rollout")
    with pytest.raises(ConfigError, match="same dimension"):
        drawn.chamfer(PointSet.of(np.zeros((4, 3))))
