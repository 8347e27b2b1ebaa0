"""Resample a recorded demo onto a fixed frame rate (what LeRobot's frame-based datasets need).

Demos are recorded at uneven sample times (browser events, IK lag). LeRobot indexes frames at
``timestamp = frame_index / fps``, so an export puts every demo on the grid t_k = k / fps from its
first sample: positions, joints and gripper by linear interpolation, orientations by spherical
linear interpolation (scipy's ``Slerp``), actions recomputed on the grid by forward difference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bt_pipeline.data.carry import slerp_wxyz
from bt_pipeline.data.records import DemoRecord, FloatArray, forward_difference_actions
from bt_pipeline.exceptions import ConfigError


@dataclass(frozen=True)
class FixedRateDemo:
    """A demo on the grid t_k = k / fps, k = 0 .. T-1 (times from the demo's first sample)."""

    timestamps: FloatArray
    """t_k = k / fps, shape (T,), in [s]."""
    ee_pos: FloatArray
    """End-effector positions, shape (T, 3), in [m]."""
    actions: FloatArray
    """End-effector velocity by forward difference on the grid, last row 0, shape (T, 3) [m/s]."""
    ee_quat: FloatArray | None
    """Orientation w, x, y, z (unit), shape (T, 4), or None."""
    joint_pos: FloatArray | None
    """Joint positions, shape (T, 7) [rad], or None."""
    gripper: FloatArray | None
    """Gripper opening, shape (T, 1), or None."""


def resample_fixed_rate(record: DemoRecord, fps: float) -> FixedRateDemo:
    """Put `record` on the grid k / fps covering its duration (the last frame at or before it).

    Args:
        record: A demo as stored, with strictly increasing timestamps.
        fps: Frame rate [Hz], > 0.

    Raises:
        ConfigError: fps is not positive, or the demo is shorter than two frames at this rate.
    """
    if not fps > 0:
        raise ConfigError(f"--fps must be > 0; got {fps}")
    t_raw = record.timestamps - record.timestamps[0]
    n_frames = int(np.floor(t_raw[-1] * fps + 1e-9)) + 1
    if n_frames < 2:
        raise ConfigError(
            f"a demo of {t_raw[-1]:.3f} s has fewer than 2 frames at {fps} fps; raise --fps"
        )
    t = np.arange(n_frames) / fps
    ee_pos = _interp(t, t_raw, record.ee_pos)
    return FixedRateDemo(
        timestamps=t,
        ee_pos=ee_pos,
        actions=forward_difference_actions(ee_pos, t),
        ee_quat=None if record.ee_quat is None else slerp_wxyz(t, t_raw, record.ee_quat),
        joint_pos=None if record.joint_pos is None else _interp(t, t_raw, record.joint_pos),
        gripper=None if record.gripper is None else _interp(t, t_raw, record.gripper),
    )


def _interp(t_new: FloatArray, t: FloatArray, values: FloatArray) -> FloatArray:
    values = np.asarray(values, dtype=np.float64)
    return np.stack([np.interp(t_new, t, values[:, j]) for j in range(values.shape[1])], axis=1)
