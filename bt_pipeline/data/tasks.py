"""Task names, the tasks with a built-in guide and scene, and their default task planes.

A recording may perform any rhythmic task: its name (``/data`` attr ``task``) is free, within
the rule of :func:`parse_task`, because it also names output files (``DIR/<task>.cleaned.hdf5``)
and the app's folders. Three tasks, :data:`TASKS`, come with a built-in guide shape
(:mod:`bt_pipeline.data.shapes`), a default task plane and a teleop scene; code that needs one of
those narrows a name with :func:`parse_guided_task` or :func:`has_guide`.
"""

from __future__ import annotations

import re
from typing import Literal, TypeAlias, TypeGuard, get_args

import numpy as np

from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.exceptions import UnknownTaskError

Task: TypeAlias = str
"""A task name as stored in the ``/data`` attr ``task`` of a recording, checked by
:func:`parse_task`: 1-64 characters of ``A-Z a-z 0-9 _ -``, starting with a letter or digit."""

GuidedTask = Literal["wiping", "weaving", "pick_and_place"]
"""A task with a built-in guide shape, default task plane and teleop scene."""

TASKS: tuple[GuidedTask, ...] = get_args(GuidedTask)
"""The tasks with a built-in guide and scene, in their canonical order."""

MAX_TASK_CHARS = 64
"""Longest task name [characters]."""
_TASK_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")
TASK_NAME_RULE = (
    f"a task name is 1-{MAX_TASK_CHARS} characters of letters, digits, '_' and '-', starting "
    "with a letter or digit (e.g. stirring, pick_and_place)"
)
"""What :func:`parse_task` accepts, in words (part of its error message)."""


def parse_task(name: object) -> Task:
    """Return `name` if it is a valid task name, with or without a built-in guide.

    A task name becomes part of file and folder names, so it holds no path separator, dot,
    space or NUL: 1-64 characters of ``A-Z a-z 0-9 _ -``, starting with a letter or digit.

    Raises:
        UnknownTaskError: `name` is not a string or breaks the rule; the message says the rule.
    """
    if not isinstance(name, str):
        raise UnknownTaskError(f"invalid task name {name!r:.80}: not a string; {TASK_NAME_RULE}")
    if len(name) > MAX_TASK_CHARS:
        raise UnknownTaskError(
            f"invalid task name {name!r:.80} ({len(name)} characters); {TASK_NAME_RULE}"
        )
    if _TASK_NAME.fullmatch(name) is None:
        raise UnknownTaskError(f"invalid task name {name!r}; {TASK_NAME_RULE}")
    return name


def is_task_name(name: object) -> bool:
    """Whether :func:`parse_task` accepts `name`."""
    return (
        isinstance(name, str) and len(name) <= MAX_TASK_CHARS and bool(_TASK_NAME.fullmatch(name))
    )


def has_guide(task: str) -> TypeGuard[GuidedTask]:
    """Whether `task` is one of :data:`TASKS` (a built-in guide shape, plane and scene)."""
    return task in TASKS


def parse_guided_task(name: object) -> GuidedTask:
    """Return `name` as a :data:`GuidedTask`, for code that needs a built-in guide or scene.

    Raises:
        UnknownTaskError: `name` is not one of :data:`TASKS`; the message lists them.
    """
    for task in TASKS:
        if name == task:
            return task
    raise UnknownTaskError(
        f"task {name!r:.80} has no built-in guide and scene; valid tasks are {', '.join(TASKS)}"
    )


# Default task planes, shared by the synthetic demonstrators and the teleop scenes. The FR3 base
# sits at the world origin on the table top (z = 0); all planes lie well inside its reach.
_DEFAULT_PLANES: dict[GuidedTask, TaskPlane] = {
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
    """The default task plane of `task` (the one the bundled scenes declare).

    Raises:
        UnknownTaskError: `task` has no built-in plane (only :data:`TASKS` have one); take the
            plane from its recording, or fit one (``bt import --plane auto``).
    """
    if not has_guide(task):
        raise UnknownTaskError(
            f"task {task!r:.80} has no default task plane (only {', '.join(TASKS)} have one); "
            "take the plane from its recording or fit one (bt import --plane auto)"
        )
    return _DEFAULT_PLANES[task]
