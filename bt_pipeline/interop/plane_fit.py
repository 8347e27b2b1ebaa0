"""The task plane of imported demos (fitted by PCA, or given) and their Recording.

Other tools record no task plane. ``--plane auto`` fits one to every end-effector position of the
file: origin = their mean, u and v = the two principal directions of largest variance (the
plane the motion spans), signs fixed so the result does not depend on the SVD's sign choice:
the normal u × v points to +z when the plane is not vertical, else u points to +y.
``--plane ORIGIN,AXES`` gives 9 numbers ``ox,oy,oz,ux,uy,uz,vx,vy,vz`` [m].
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from bt_pipeline.data.plane import FloatArray, TaskPlane
from bt_pipeline.data.records import DemoRecord, Recording
from bt_pipeline.data.tasks import Task
from bt_pipeline.exceptions import ConfigError

_MIN_SPREAD_M = 1e-4
"""Below this second principal spread [m] the motion spans no plane (a line or a point)."""


def fit_plane(ee_pos: Sequence[FloatArray]) -> TaskPlane:
    """The plane spanned by the end-effector positions of all demos (PCA).

    Args:
        ee_pos: Positions of each demo, each shape (T_i, 3), in [m].

    Raises:
        ConfigError: The positions span no plane (all on a line or a point).
    """
    points = np.concatenate([np.asarray(p, dtype=np.float64) for p in ee_pos])
    origin = points.mean(axis=0)
    _, spread, vt = np.linalg.svd(points - origin, full_matrices=False)
    rms = spread / np.sqrt(len(points))
    if rms[1] < _MIN_SPREAD_M:
        raise ConfigError(
            f"--plane auto: the end-effector positions span no plane (RMS spread {rms[0]:.2g} m "
            f"and {rms[1]:.2g} m along the two main directions); give --plane ORIGIN,AXES"
        )
    u, v = vt[0], vt[1]
    normal = np.cross(u, v)
    if abs(normal[2]) > 1e-6:
        if normal[2] < 0:
            v = -v
    elif u[1] < 0 or (abs(u[1]) <= 1e-12 and u[0] < 0):
        u, v = -u, -v
    return TaskPlane(origin=origin, axes=np.stack([u, v]))


def parse_plane(text: str) -> TaskPlane | None:
    """``auto`` -> None (fit later); ``ox,oy,oz,ux,uy,uz,vx,vy,vz`` -> that plane.

    Raises:
        ConfigError: Not 9 numbers, or axes that are not orthonormal.
    """
    if text.strip().lower() == "auto":
        return None
    try:
        numbers = [float(x) for x in text.replace(";", ",").split(",")]
    except ValueError:
        numbers = []
    if len(numbers) != 9:
        raise ConfigError(
            f"--plane {text!r}: expected 'auto' or 9 comma-separated numbers "
            "ox,oy,oz,ux,uy,uz,vx,vy,vz (origin and two orthonormal axes, [m])"
        )
    return TaskPlane(origin=np.array(numbers[:3]), axes=np.array(numbers[3:]).reshape(2, 3))


def imported_recording(
    task: Task,
    plane: TaskPlane | None,
    demos: dict[str, DemoRecord],
    source: str,
    fmt: str,
    env_args: dict[str, Any] | None = None,
    masks: dict[str, list[str]] | None = None,
) -> Recording:
    """The format-v1 recording of imported `demos`, on `plane` or on one fitted to them.

    Args:
        task: The task the demos perform.
        plane: The task plane; None fits one (:func:`fit_plane`).
        demos: The imported demos by name.
        source: Where they were read from (``/data`` attr ``imported_from``).
        fmt: Their format (attr ``imported_format``).
        env_args: robomimic's environment metadata, if well-formed.
        masks: Filter keys to keep.
    """
    return Recording(
        task=task,
        plane=plane if plane is not None else fit_plane([d.ee_pos for d in demos.values()]),
        demos=demos,
        env_args=env_args or {},
        masks=masks or {},
        attrs={"imported_from": source, "imported_format": fmt},
    )
