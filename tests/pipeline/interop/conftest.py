"""Shared by the interop tests: ``full_recording(task="wiping", plane=None)``, a recording with
every optional field an exporter writes."""

from __future__ import annotations

import dataclasses

from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.records import Recording
from tests.conftest import build_recording


def full_recording(task: str = "wiping", plane: TaskPlane | None = None) -> Recording:
    """3 demos with quaternion, joints and gripper (the fixture's extra attrs, flags among them,
    dropped: a flagged take is never exported); `plane` as in :func:`build_recording`."""
    recording = build_recording(task, n_demos=3, n_samples=60, optional=True, plane=plane)
    demos = {k: dataclasses.replace(d, attrs={}) for k, d in recording.demos.items()}
    return dataclasses.replace(recording, demos=demos)
