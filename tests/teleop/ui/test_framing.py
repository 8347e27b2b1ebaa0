"""bt_teleop.ui.framing: each task's default camera faces the side of the task plane the robot
works on and keeps the whole guide in view; the gizmo's axes are the task plane's axes, and its
handles show in that view beside the tool, left of the control panel, large enough to grab."""

# mujoco ships compiled bindings without type stubs, so pyright cannot see MjData, mj_ray, ...:
# attribute checks on the mujoco module are off in this file.
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bt_teleop.session.control_loop import Session
from bt_teleop.sim.scene import SceneModel, load_scene
from bt_teleop.testing.harness import VIEWPORT
from bt_teleop.ui.framing import CameraView, default_view, plane_wxyz
from bt_teleop.ui.tab_scene import GIZMO_SCALE_M
from bt_teleop.ui.viewer import guide_loop_world

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


# -- the gizmo in the default view (issue 37) ---------------------------------------------------

PANEL_PX = 340
"""The control panel covers this much of the page's right side [px] (viser's default width)."""
MIN_HANDLE_PX = 24
"""Smallest side [px] of the square a person grabs to drag in the task plane."""
VISIBLE_GROUPS = np.array([1, 1, 1, 0, 0, 0], dtype=np.uint8)  # geoms the page draws (ui/viewer.py)


def gizmo_axes(scene: SceneModel) -> tuple[np.ndarray, np.ndarray]:
    """The gizmo's x and y axes in the world (the task plane's u and v), each shape (3,)."""
    w, x, y, z = plane_wxyz(scene.plane)
    axes = Rotation.from_quat([x, y, z, w]).as_matrix()
    return axes[:, 0], axes[:, 1]


def gizmo_handles(scene: SceneModel) -> dict[str, np.ndarray]:
    """Points of the gizmo's in-plane handles as viser draws them (drei's PivotControls, not
    ``fixed``: sizes in world units), at the default pose: the tips of the u and v arrows (their
    cones: the last fifth of an arrow of GIZMO_SCALE_M) and the middle of the square between u
    and v (0.225 of the scale across, centred 1.7/7 of the scale along u and v), each (K, 3) [m]."""
    u, v = gizmo_axes(scene)
    centre, s = scene.ready_pos, GIZMO_SCALE_M
    tip = np.linspace(0.8, 1.0, 5)[:, None] * s
    grid = s * (1.7 / 7 + 0.225 * np.linspace(-0.3, 0.3, 3))
    square = np.array([centre + a * u + b * v for a in grid for b in grid])
    return {"u arrow": centre + tip * u, "v arrow": centre + tip * v, "u-v square": square}


def square_corners(scene: SceneModel) -> np.ndarray:
    """The corners of the gizmo's square between u and v, in order around it, shape (4, 3) [m]."""
    u, v = gizmo_axes(scene)
    middle, half = GIZMO_SCALE_M * 1.7 / 7, GIZMO_SCALE_M * 0.225 / 2
    steps = ((-1, -1), (1, -1), (1, 1), (-1, 1))
    return np.array(
        [scene.ready_pos + (middle + a * half) * u + (middle + b * half) * v for a, b in steps]
    )


def pixels(view: CameraView, points: np.ndarray) -> np.ndarray:
    """Where `points` (K, 3) [m] show on a page of VIEWPORT (K, 2) [px], x right, y down."""
    forward = (view.look_at - view.position) / np.linalg.norm(view.look_at - view.position)
    right = np.cross(forward, view.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    rel = points - view.position
    depth = rel @ forward
    assert np.all(depth > 0.05), "behind the camera"
    width, height = VIEWPORT["width"], VIEWPORT["height"]
    focal = 0.5 * height / np.tan(0.5 * view.fov_rad)
    return np.column_stack(
        [0.5 * width + focal * (rel @ right) / depth, 0.5 * height - focal * (rel @ up) / depth]
    )


def hidden(scene: SceneModel, data: mujoco.MjData, view: CameraView, point: np.ndarray) -> str:
    """The geom the page draws between the camera and `point` ("" when none)."""
    ray = point - view.position
    distance = float(np.linalg.norm(ray))
    geom = np.array([-1], dtype=np.int32)
    hit = mujoco.mj_ray(
        scene.model, data, view.position, ray / distance, VISIBLE_GROUPS, 1, -1, geom
    )
    return "" if hit < 0 or hit > distance - 1e-3 else scene.model.geom(int(geom[0])).name or "?"


@pytest.mark.parametrize("task", TASKS)
def test_the_gizmos_handles_show_in_the_default_view(task: str, tmp_path: Path) -> None:
    scene = load_scene(task)
    view = default_view(scene.plane)
    session = Session(scene, tmp_path)  # the robot at its default pose, as a tab opens
    try:
        for name, points in gizmo_handles(scene).items():
            px = pixels(view, points)
            assert np.all(px[:, 0] > 20) and np.all(px[:, 0] < VIEWPORT["width"] - PANEL_PX), name
            assert np.all(px[:, 1] > 20) and np.all(px[:, 1] < VIEWPORT["height"] - 20), name
            blocked = [hidden(scene, session.data, view, p) for p in points]
            assert not any(blocked), f"{task}: the {name} is behind {set(blocked) - {''}}"
        corners = pixels(view, square_corners(scene))  # around the square, in order
        sides = np.linalg.norm(np.diff(np.vstack([corners, corners[:1]]), axis=0), axis=1)
        assert sides.min() >= MIN_HANDLE_PX, f"{task}: the square's sides are {sides} px"
    finally:
        session.close()
