"""bt_teleop.framing: each task's default camera faces the side of the task plane the robot
works on and keeps the whole guide in view; the gizmo's axes are the task plane's axes."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bt_teleop.framing import default_view, plane_wxyz
from bt_teleop.scene import load_scene
from bt_teleop.viewer import guide_loop_world

TASKS = ("wiping", "weaving", "pick_and_place")


@pytest.mark.parametrize("task", TASKS)
def test_the_camera_sees_the_guide_from_the_working_side(task: str) -> None:
    scene = load_scene(task)
    view = default_view(scene.plane)
    normal = scene.plane.normal
    origin = scene.plane.origin
    shoulder = np.array([0.0, 0.0, 0.333])  # FR3 link 1: on the side the robot works from
    robot_side = np.sign(normal @ (shoulder - origin))
    assert robot_side * (normal @ (view.position - origin)) > 0.05  # not the back of the board
    forward = (view.look_at - view.position) / np.linalg.norm(view.look_at - view.position)
    for theta, rho in ((0.0, 1.0), (30.0, 1.5), (-30.0, 0.5)):
        loop = guide_loop_world(scene, theta, rho)
        rays = (loop - view.position) / np.linalg.norm(loop - view.position, axis=1)[:, None]
        off_axis = np.degrees(np.arccos(np.clip(rays @ forward, -1.0, 1.0)))
        assert off_axis.max() < 25.0  # inside a 50° field of view
    assert view.position[2] > origin[2]  # from above the plane origin
    assert np.linalg.norm(view.position - origin) == pytest.approx(0.85)


@pytest.mark.parametrize("task", TASKS)
def test_the_gizmo_axes_are_the_task_plane_axes(task: str) -> None:
    plane = load_scene(task).plane
    w, x, y, z = plane_wxyz(plane)
    matrix = Rotation.from_quat([x, y, z, w]).as_matrix()
    np.testing.assert_allclose(matrix[:, 0], plane.axes[0], atol=1e-9)
    np.testing.assert_allclose(matrix[:, 1], plane.axes[1], atol=1e-9)
    np.testing.assert_allclose(matrix[:, 2], plane.normal, atol=1e-9)
