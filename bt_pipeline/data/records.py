"""Typed records of format-v1 recordings (what the HDF5 reader returns and the writer takes).

The on-disk layout is described in ``docs/recording-format.md``; :mod:`bt_pipeline.data.recording`
reads and writes it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.tasks import Task

FloatArray = NDArray[np.float64]
Source = Literal["teleop", "synthetic", "import"]
TakeFlag = Literal["too_short", "no_motion", "incomplete", "closed_mid_take", "off_guide"]
"""What the app's take checks found (demo attr ``flags``; docs/recording-format.md): why a take
failed them, or a remark (:data:`INFO_FLAGS`)."""
INFO_FLAGS: frozenset[TakeFlag] = frozenset({"off_guide"})
"""Flags that are remarks, not failures: a demo with only these is kept, scored and cleaned
(``off_guide``: it closes a loop of its own whose shape is not the guide's)."""
MIN_SAMPLES = 16
"""Fewest samples a demo may have."""


def forward_difference_actions(positions: FloatArray, timestamps: FloatArray) -> FloatArray:
    """Actions by forward difference, last row 0 (paper Sec. II).

    Args:
        positions: Positions, shape (T, d).
        timestamps: Strictly increasing times, shape (T,), in [s].

    Returns:
        a_k = (x_{k+1} - x_k) / (t_{k+1} - t_k) with a_T = 0, shape (T, d).
    """
    actions = np.zeros_like(positions, dtype=np.float64)
    actions[:-1] = np.diff(positions, axis=0) / np.diff(timestamps)[:, None]
    return actions


@dataclass(frozen=True)
class DemoRecord:
    """One demonstration as stored under ``/data/demo_<k>``."""

    ee_pos: FloatArray
    """End-effector positions in the world frame, shape (T, 3), in [m]."""
    timestamps: FloatArray
    """Sample times, strictly increasing, shape (T,), in [s]."""
    demonstrator: str
    """Who recorded the demo (free text)."""
    theta_deg: float
    """Demonstrator rotation θ [deg]; NaN when unknown (bt then estimates it)."""
    rho: float
    """Demonstrator scale ρ; NaN when unknown."""
    source: Source
    """Where the demo came from."""
    actions: FloatArray | None = None
    """End-effector velocity, shape (T, 3), [m/s]; forward difference of ee_pos when None."""
    created: str | None = None
    """ISO 8601 creation time."""
    ep_meta: dict[str, Any] = field(default_factory=dict)
    """Free-form episode metadata (stored as a JSON string)."""
    ee_quat: FloatArray | None = None
    """End-effector orientation, wxyz, shape (T, 4)."""
    joint_pos: FloatArray | None = None
    """Arm joint positions, shape (T, 7), in [rad]."""
    gripper: FloatArray | None = None
    """Gripper opening, shape (T, 1)."""
    states: FloatArray | None = None
    """Full MuJoCo state for exact replay, shape (T, S)."""
    attrs: dict[str, Any] = field(default_factory=dict)
    """Extra per-demo attrs written as they are (e.g. the cleaner's scores)."""
    extra_obs: dict[str, NDArray[Any]] = field(default_factory=dict)
    """Other ``obs/<key>`` datasets (e.g. another tool's object poses), each shape (T, ...), any
    numeric dtype: kept and written back, never used by bt."""

    @property
    def num_samples(self) -> int:
        """Number of samples T."""
        return int(self.ee_pos.shape[0])

    @property
    def flags(self) -> tuple[str, ...]:
        """Take-check flags of this demo (attr ``flags``, comma-separated; see the format doc).

        ``ep_meta["incomplete"]`` (a tab closed mid-take, as older app versions wrote it) counts as
        the flag ``closed_mid_take``. A flagged demo is never the best demo, and scoring and
        cleaning skip it with a note naming it.
        """
        raw = self.attrs.get("flags", "")
        items = list(raw) if isinstance(raw, list | tuple | np.ndarray) else [raw]
        found: list[str] = []
        for item in items:  # a string "a,b", or a list of strings (h5py gives an array)
            text = item.decode("utf-8", "replace") if isinstance(item, bytes) else str(item)
            found += [f.strip() for f in text.split(",") if f.strip()]
        if self.ep_meta.get("incomplete") is True and "closed_mid_take" not in found:
            found.append("closed_mid_take")
        return tuple(found)

    def resolved_actions(self) -> FloatArray:
        """The stored actions, or the forward difference of ee_pos when none are stored."""
        if self.actions is not None:
            return self.actions
        return forward_difference_actions(self.ee_pos, self.timestamps)


@dataclass(frozen=True)
class Recording:
    """A whole format-v1 file: one task, one task plane, any number of demos."""

    task: Task
    """The task every demo of the file performs."""
    plane: TaskPlane
    """The task plane (``/data`` attrs ``plane_origin`` and ``plane_axes``)."""
    demos: dict[str, DemoRecord]
    """Demos by name (``demo_<k>``), in the order of k."""
    env_args: dict[str, Any] = field(default_factory=dict)
    """robomimic's ``env_args`` (``env_name``, ``type``, ``env_kwargs``)."""
    masks: dict[str, list[str]] = field(default_factory=dict)
    """robomimic filter keys: mask name to demo names."""
    attrs: dict[str, Any] = field(default_factory=dict)
    """Extra ``/data`` attrs written as they are (e.g. ``best_file``)."""
    path: Path | None = None
    """The file this recording was read from, if any."""

    @property
    def total(self) -> int:
        """Samples over all demos (``/data`` attr ``total``)."""
        return sum(d.num_samples for d in self.demos.values())
