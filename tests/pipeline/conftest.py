"""Shared by the pipeline's tests: a task with no built-in guide, on a plane of its own.

* ``STIRRING_PLANE``: a tilted plane no built-in task uses.
* ``write_stirring_file(directory, name="stirring.hdf5", n_demos=4, n_samples=60)`` writes a
  format-v1 file of task "stirring" on it and returns the path.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from bt_pipeline.data.demo import Demo
from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.recording import write_recording
from bt_pipeline.data.tasks import default_plane
from tests.conftest import build_recording


def demo_of(
    x: np.ndarray, t: np.ndarray, name: str, task: str, theta: float | None, rho: float | None
) -> Demo:
    """A demo of raw samples `x` (T, 2) at times `t` (its N samples a thinning of them), its
    demonstrator named as the demo, on the wiping plane."""
    return Demo(
        positions=x[:: max(1, x.shape[0] // 300)][:300],
        task=task,
        file="",
        name=name,
        demonstrator=name,
        theta_deg=theta,
        rho=rho,
        plane=default_plane("wiping"),
        duration_s=float(t[-1] - t[0]),
        raw_positions=x,
        raw_times_s=t,
    )


TILT = math.radians(20.0)
STIRRING_PLANE = TaskPlane(
    origin=np.array([0.42, 0.18, 0.12]),
    axes=np.array([[1.0, 0.0, 0.0], [0.0, math.cos(TILT), math.sin(TILT)]]),
)
"""A plane no built-in task uses: a pot's rim tilted 20° towards the robot."""


def write_stirring_file(
    directory: Path, name: str = "stirring.hdf5", n_demos: int = 4, n_samples: int = 60
) -> Path:
    """A format-v1 file of task "stirring" (no built-in guide) written with the format-v1
    writer: `n_demos` circles on :data:`STIRRING_PLANE` (:func:`build_recording`)."""
    recording = build_recording("stirring", n_demos, n_samples, plane=STIRRING_PLANE)
    return write_recording(Path(directory) / name, recording)
