"""The tasks bt knows and their default task planes."""

from __future__ import annotations

from typing import Literal, get_args

import numpy as np

from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.exceptions import UnknownTaskError

Task = Literal["wiping", "weaving", "pick_and_place"]
"""A task name as stored in the `/data` attr `task` of a recording."""

TASKS: tuple[Task, ...] = get_args(Task)


def parse_task(name: str) -> Task:
    """Return `name` as a :data:`Task`, or raise an error that lists the valid names."""
    for task in TASKS:
        if name == task:
            return task
    raise UnknownTaskError(f"unknown task {name!r}; valid tasks are {', '.join(TASKS)}")


# Default task planes, shared by the synthetic demonstrators and the teleop scenes. The FR3 base
# sits at the world origin on the table top (z = 0); all planes lie well inside its reach.
_DEFAULT_PLANES: dict[Task, TaskPlane] = {
    # Horizontal: the wiping surface. u = -world y (robot's right), v = world x (forward);
    # normal up.
    "wiping": TaskPlane(
        origin=np.array([0.5, 0.0, 0.05]), axes=np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])
    ),
    # Vertical, facing the robot: the weaving frame. u = world y, v = world z.
    "weaving": TaskPlane(
        origin=np.array([0.55, 0.0, 0.45]), axes=np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    ),
    # Vertical through both places: the arch over high and back low. u = world y, v = world z.
    # At z = 0.20 the arch (ρ = 1) spans z 0.125-0.275 and its ends, the places, lie at z 0.1625:
    # inside the scene's workspace (floor z 0.12) and low enough to grasp the block's top.
    "pick_and_place": TaskPlane(
        origin=np.array([0.5, 0.0, 0.2]), axes=np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    ),
}


def default_plane(task: Task) -> TaskPlane:
    """The default task plane of `task` (the one the bundled scenes declare)."""
    return _DEFAULT_PLANES[task]
