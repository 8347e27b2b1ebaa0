"""Framing a task in a tab's 3-D view: the default camera per task and the gizmo's axes.

The camera looks at the task plane's origin (the centre of the guide loop) from the side of
the plane that faces away from the robot's base, raised a little and turned a little to the
side, so that the guide, the stylus and the trail are in front of the arm instead of behind
it::

    n   the plane's normal, flipped to point away from the robot base (world origin)
    a   the horizontal direction from the base to the plane origin
    dir = normalise(n + 0.9 a + 0.35 z + 0.3 (z × a))
    camera = origin + distance · dir,  look_at = origin,  up = +z

For the wiping table (n = +z) this is above and in front of the table; for the vertical
weaving frame and pick-and-place board (n = +x) it is in front of the frame. The gizmo's arrows
are the plane's axes u, v and its normal, so dragging along an arrow moves along the task.
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


@dataclass(frozen=True, eq=False)  # holds arrays
class CameraView:
    """Where a tab's camera is and what it looks at (world frame)."""

    position: FloatArray
    """Camera position, shape (3,) [m]."""
    look_at: FloatArray
    """Point looked at, shape (3,) [m]."""
    up: FloatArray
    """Up direction, shape (3,)."""


def default_view(plane: TaskPlane, distance_m: float = VIEW_DISTANCE_M) -> CameraView:
    """The default camera of a task drawn on `plane` (see the module docstring)."""
    origin = np.asarray(plane.origin, dtype=np.float64)
    z = np.array([0.0, 0.0, 1.0])
    normal = plane.normal / np.linalg.norm(plane.normal)
    if float(normal @ origin) < 0.0:  # point away from the robot base at the world origin
        normal = -normal
    away = np.array([origin[0], origin[1], 0.0])
    norm = float(np.linalg.norm(away))
    away = away / norm if norm > 1e-9 else np.array([1.0, 0.0, 0.0])
    direction = normal + 0.9 * away + 0.35 * z + 0.3 * np.cross(z, away)
    direction /= np.linalg.norm(direction)
    return CameraView(origin + distance_m * direction, origin.copy(), z)


def plane_wxyz(plane: TaskPlane) -> FloatArray:
    """Orientation (w, x, y, z) whose x, y, z axes are the plane's u, v and normal, (4,)."""
    u, v = plane.axes[0], plane.axes[1]
    matrix = np.stack([u, v, np.cross(u, v)], axis=1)
    x, y, zq, w = Rotation.from_matrix(matrix).as_quat()
    return np.array([w, x, y, zq])
