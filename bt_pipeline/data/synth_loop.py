"""The loop a synthetic set draws: the task's guide or a given shape, and how it is recorded.

Both generators (:mod:`bt_pipeline.data.synth`, :mod:`bt_pipeline.data.synth_human`) draw the
task's guide (:mod:`bt_pipeline.data.shapes`) unless given a ``shape``, a
:class:`~bt_pipeline.data.loop_shape.LoopShape` (e.g. from :mod:`bt_pipeline.data.random_loops`).
With a shape:

* every demo of the set draws that loop, under its demonstrator's θ and ρ, and its truth
  (``truth_uv``, ``SynthDemo.truth``) is that loop;
* the ``lopsided`` defect bulges the side of that loop's bounding box;
* the recording's ``env_kwargs`` hold the loop (:func:`shape_kwargs`): ``shape``, its label, and
  ``shape_coefficients``, its c_k for k = −K..K as [re, im] pairs [m];
* the task may be any safe name (``[A-Za-z0-9][A-Za-z0-9_-]*``, at most 64 characters) besides
  the three with a guide: such a task seeds its sets from the CRC-32 of its name and works in
  wiping's default plane.

Without a shape the generators' output is what it always was, bit for bit.
"""

from __future__ import annotations

import zlib
from typing import Any

import numpy as np

from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.shapes import SHAPE_SIZE, canonical_shape
from bt_pipeline.data.tasks import (
    TASK_NAME_RULE,
    TASKS,
    Task,
    default_plane,
    parse_guided_task,
    parse_task,
)
from bt_pipeline.exceptions import ConfigError, UnknownTaskError

_BOX_POINTS = 1024  # Points a shape's bounding box is read on (as LoopShape.size_m).


def resolve_task(task: str, shape: LoopShape | None) -> tuple[Task, int, TaskPlane]:
    """A generator's task name, the rng key it seeds sets with, and its plane.

    One of the three tasks keeps its index in :data:`TASKS` and its default plane. Another name
    is taken only with a shape (there is no guide to draw) and only if it is safe: it seeds from
    its CRC-32 and works in wiping's plane (the module doc).
    """
    if task in TASKS:
        return task, TASKS.index(task), default_plane(task)
    if shape is None:
        raise UnknownTaskError(
            f"task {task!r:.80} has no built-in guide to draw; valid tasks are {', '.join(TASKS)} "
            "(another name needs a shape)"
        )
    try:
        name = parse_task(task)
    except UnknownTaskError as error:
        raise ConfigError(f"task name {task!r:.80} is not safe: {TASK_NAME_RULE}") from error
    return name, zlib.crc32(name.encode("ascii")), default_plane("wiping")


def shape_kwargs(shape: LoopShape | None) -> dict[str, Any]:
    """The ``env_kwargs`` entries that record a set's loop: none for the guide (None)."""
    if shape is None:
        return {}
    return {
        "shape": shape.label,
        "shape_coefficients": [[float(c.real), float(c.imag)] for c in shape.coefficients],
    }


def loop_positions(task: Task, shape: LoopShape | None, phase: FloatArray) -> FloatArray:
    """The set's loop at `phase` [rad], shape (..., 2) [m]: `shape`, or the task's guide."""
    return canonical_shape(task, phase) if shape is None else shape.at(phase)


def lopsided(
    uv: FloatArray, task: Task, rng: np.random.Generator, shape: LoopShape | None = None
) -> tuple[FloatArray, dict]:
    """Bulge one side (x > 0 or x < 0) of a canonical-frame shape outward and shift it in y.

    The sides, the bulge and the lift are measured from the centre and half sides of the loop's
    bounding box: the task's guide (:data:`SHAPE_SIZE`, centred on the origin), or `shape`'s.
    """
    centre = None
    if shape is None:
        half_w, half_h = (s / 2.0 for s in SHAPE_SIZE[parse_guided_task(task)])
    else:
        box = shape.points(_BOX_POINTS)
        centre = 0.5 * (box.min(axis=0) + box.max(axis=0))
        half_w, half_h = (float(s) / 2.0 for s in np.ptp(box, axis=0))
        uv = uv - centre
    side = float(rng.choice([-1.0, 1.0]))
    gain = rng.uniform(0.2, 0.35)
    lift = rng.uniform(-0.25, 0.25) * half_h
    weight = 1.0 / (1.0 + np.exp(-side * uv[:, 0] / (0.15 * half_w)))  # ~1 on that side
    out = uv * (1.0 + gain * weight)[:, None]
    out[:, 1] += lift * weight
    if centre is not None:
        out += centre
    return out, {"lopsided_side": side, "lopsided_gain": gain, "lopsided_lift_m": lift}


__all__ = ["loop_positions", "lopsided", "resolve_task", "shape_kwargs"]
