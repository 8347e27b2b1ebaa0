"""Framing a task in a tab's 3-D view: the default camera per task and the gizmo's axes.

The camera looks at the task plane's origin (the centre of the guide loop) from the side the
robot works on, so that the guide, the stylus and the trail face the camera (not the back of a
board), and from where the arm hides little of them::

    a   the horizontal direction from the robot base (world origin) to the plane origin
    l   z × a, sideways
    horizontal plane (a table, |n·z| > 0.7):  dir = normalise(z + 0.9 a + 0.3 l)
        above the table and in front of the robot, looking down past the arm
    vertical plane (a board):                  dir = normalise(n_r + 1.1 l + 0.45 z)
        n_r the normal pointing to the robot's side; from the robot's side, well to the
        left of the arm and a little above
    camera = origin + distance · dir,  look_at = origin,  up = +z,  vertical field of view 75°

The gizmo's arrows are the plane's axes u, v and its normal, so dragging along an arrow moves
along the task. The gizmo sits at the end effector, inside the tool, so its middle is no handle
(a press there turns the view); its arrows' tips and the square between u and v reach past the
tool and the arm in each task's default view (``tests/teleop/ui/test_framing.py`` projects them
and casts rays at the robot).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.records import FloatArray

__all__ = ["CameraView", "default_view", "plane_wxyz"]

VIEW_DISTANCE_M = 0.85
"""Distance of the default camera from the plane origin [m]."""
VIEW_FOV_RAD = float(np.radians(75.0))
"""Vertical field of view of the default camera [rad] (viser's default, set explicitly: the view
``tests/teleop/ui/test_framing.py`` projects the gizmo into)."""


@dataclass(frozen=True, eq=False)  # holds arrays
class CameraView:
    """Where a tab's camera is and what it looks at (world frame)."""

    position: FloatArray
    """Camera position, shape (3,) [m]."""
    look_at: FloatArray
    """Point looked at, shape (3,) [m]."""
    up: FloatArray
    """Up direction, shape (3,)."""
    fov_rad: float = VIEW_FOV_RAD
    """Vertical field of view [rad]."""


def default_view(plane: TaskPlane, distance_m: float = VIEW_DISTANCE_M) -> CameraView:
    """The default camera of a task drawn on `plane` (see the module docstring)."""
    origin = np.asarray(plane.origin, dtype=np.float64)
    z = np.array([0.0, 0.0, 1.0])
    normal = plane.normal / np.linalg.norm(plane.normal)
    away = np.array([origin[0], origin[1], 0.0])
    norm = float(np.linalg.norm(away))
    away = away / norm if norm > 1e-9 else np.array([1.0, 0.0, 0.0])
    side = np.cross(z, away)
    if abs(float(normal @ z)) > 0.7:  # a table: look down from in front of the robot
        direction = z + 0.9 * away + 0.3 * side
    else:  # a board: from the robot's side of it, to the side of the arm
        toward_robot = normal if float(normal @ -origin) > 0.0 else -normal
        direction = toward_robot + 1.1 * side + 0.45 * z
    direction = direction / np.linalg.norm(direction)
    return CameraView(origin + distance_m * direction, origin.copy(), z)


def plane_wxyz(plane: TaskPlane) -> FloatArray:
    """Orientation (w, x, y, z) whose x, y, z axes are the plane's u, v and normal, (4,)."""
    u, v = plane.axes[0], plane.axes[1]
    matrix = np.stack([u, v, np.cross(u, v)], axis=1)
    x, y, zq, w = Rotation.from_matrix(matrix).as_quat()
    return np.array([w, x, y, zq])
