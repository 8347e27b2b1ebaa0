"""Workspace box, task-plane projection and target validation."""

from __future__ import annotations

import numpy as np
import pytest

from bt_pipeline.data.tasks import TASKS, Task, default_plane
from bt_pipeline.exceptions import ConfigError
from bt_teleop.sim.workspace import (
    Workspace,
    project_onto_plane,
    slew_toward,
    validate_position,
    validate_quat,
)

BOX = Workspace(lo=np.array([0.3, -0.3, 0.05]), hi=np.array([0.7, 0.3, 0.35]))


def test_clamp_returns_the_nearest_point_of_the_box() -> None:
    rng = np.random.default_rng(0)
    for p in rng.uniform(-5.0, 5.0, size=(200, 3)):
        clamped, moved = BOX.clamp(p)
        assert BOX.contains(clamped)
        assert moved == (not BOX.contains(p))
        # Nearest point: no box corner or sample is closer.
        samples = rng.uniform(BOX.lo, BOX.hi, size=(50, 3))
        assert np.linalg.norm(p - clamped) <= np.min(np.linalg.norm(samples - p, axis=1)) + 1e-12


def test_clamp_keeps_inside_points_and_does_not_mutate() -> None:
    p = np.array([0.5, 0.1, 0.2])
    before = p.copy()
    clamped, moved = BOX.clamp(p)
    assert not moved
    np.testing.assert_array_equal(clamped, p)
    np.testing.assert_array_equal(p, before)


@pytest.mark.parametrize("task", TASKS)
def test_projection_lands_on_the_plane_and_is_idempotent(task: Task) -> None:
    plane = default_plane(task)
    rng = np.random.default_rng(1)
    for p in rng.normal(size=(20, 3)):
        q = project_onto_plane(plane, p)
        assert abs(float(np.dot(q - plane.origin, plane.normal))) < 1e-12
        np.testing.assert_allclose(project_onto_plane(plane, q), q, atol=1e-12)
        np.testing.assert_allclose(plane.to_plane(q), plane.to_plane(p), atol=1e-12)


def test_invalid_boxes_and_targets_are_refused() -> None:
    with pytest.raises(ConfigError, match="lo <= hi"):
        Workspace(lo=np.array([1.0, 0.0, 0.0]), hi=np.zeros(3))
    with pytest.raises(ConfigError, match="finite"):
        validate_position([0.0, np.nan, 0.0])
    with pytest.raises(ConfigError, match="3 numbers"):
        validate_position("abc")
    with pytest.raises(ConfigError, match="zero norm"):
        validate_quat([0.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(validate_quat([2.0, 0.0, 0.0, 0.0]), [1.0, 0.0, 0.0, 0.0])


def _angle(q1: np.ndarray, q2: np.ndarray) -> float:
    return 2.0 * float(np.arccos(min(1.0, abs(float(np.dot(q1, q2))))))


def test_slew_steps_are_bounded_and_reach_the_goal() -> None:
    rng = np.random.default_rng(2)
    for _ in range(20):
        pos, goal_pos = rng.normal(size=3), rng.normal(size=3)
        quat = rng.normal(size=4)
        quat /= np.linalg.norm(quat)
        goal_quat = rng.normal(size=4)
        goal_quat /= np.linalg.norm(goal_quat)
        for _ in range(500):
            new_pos, new_quat = slew_toward(pos, quat, goal_pos, goal_quat, 0.01, 0.03)
            assert np.linalg.norm(new_pos - pos) <= 0.01 + 1e-12
            assert _angle(new_quat, quat) <= 0.03 + 1e-9
            assert abs(np.linalg.norm(new_quat) - 1.0) < 1e-12
            pos, quat = new_pos, new_quat
        np.testing.assert_allclose(pos, goal_pos, atol=1e-12)
        assert _angle(quat, goal_quat) < 1e-6  # arccos near 1 resolves ~1e-8


def test_slew_takes_the_short_way_round() -> None:
    quat = np.array([1.0, 0.0, 0.0, 0.0])
    goal = -np.array([np.cos(0.05), np.sin(0.05), 0.0, 0.0])  # 0.1 rad away, other sign
    _, new = slew_toward(np.zeros(3), quat, np.zeros(3), goal, 1.0, 0.5)
    assert _angle(new, goal) < 1e-6 and _angle(new, quat) == pytest.approx(0.1)
