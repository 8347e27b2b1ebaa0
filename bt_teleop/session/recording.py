"""A session's recording lifecycle: the demo in progress, from start to a file on disk.

::

    start(info, data, tick)        the first sample is the current state (timestamp 0)
    sample_due(data, tick)         every 1 / record_hz of simulation time: one sample
    take() -> DemoRecorder | None  stop: the samples leave the slot (save or drop them)
    save(recorder) -> SavedTake    Stop & save: the take checks (bt_teleop.takes.checks), then
                                   a new format-v1 file with attr ``flags``, written atomically
    save_incomplete(recorder)      a closed tab: flagged ``closed_mid_take`` (and ep_meta
                                   ``incomplete``), or dropped

:class:`RecordingSlot` holds no lock of its own: :class:`bt_teleop.session.control_loop.Session`
calls it under its state lock, except :meth:`RecordingSlot.save`, which it calls after taking the
recorder out, so disk I/O never stalls the control loop.
"""

# mujoco ships compiled bindings without type stubs, so pyright cannot see MjModel, mj_step,
# mjtObj, ...: attribute checks on the mujoco module are off in this file.
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from bt_pipeline.data.records import MIN_SAMPLES, FloatArray
from bt_pipeline.exceptions import ConfigError
from bt_teleop.session.config import SessionConfig, whole_steps
from bt_teleop.sim.scene import SceneModel
from bt_teleop.takes.checks import TakeCheck, check_take
from bt_teleop.takes.recorder import DemoInfo, DemoRecorder, finish_demo, take_sample

__all__ = ["RecordingSlot", "SavedTake"]

LOGGER = logging.getLogger("bt.teleop")


@dataclass(frozen=True)
class SavedTake:
    """A take written to disk, with what the take checks found."""

    path: Path
    """The file written."""
    check: TakeCheck
    """The checks' result (its flags are the demo attr ``flags``)."""


class RecordingSlot:
    """The demo one session is recording, if any (one at a time)."""

    def __init__(
        self, scene: SceneModel, recordings_dir: Path, session_id: str, config: SessionConfig
    ) -> None:
        """An empty slot; demos go to ``<recordings_dir>/<task>/``.

        Raises:
            ConfigError: ``record_hz`` does not divide ``control_hz``.
        """
        self.scene = scene
        self.recordings_dir = recordings_dir
        self.session_id = session_id
        self.config = config
        self._ticks_per_sample = whole_steps(config.control_hz / config.record_hz, "record")
        self._recorder: DemoRecorder | None = None
        self._tick0 = 0

    @property
    def recorder(self) -> DemoRecorder | None:
        """The demo in progress, None when not recording."""
        return self._recorder

    def start(self, info: DemoInfo, data: mujoco.MjData, tick: int) -> None:
        """Start a demo at control tick `tick` with the state of `data` as its first sample.

        Raises:
            ConfigError: A demo is already being recorded.
        """
        if self._recorder is not None:
            raise ConfigError("a recording is already in progress; stop or discard it first")
        self._recorder = DemoRecorder(info, data.time, has_gripper=self.scene.has_gripper)
        self._tick0 = tick
        take_sample(self._recorder, self.scene, data)

    def count_ik_failure(self) -> None:
        """Count a failed IK tick in the demo in progress (if any)."""
        if self._recorder is not None:
            self._recorder.ik_failures += 1

    def sample_due(self, data: mujoco.MjData, tick: int, *, clamped: bool) -> None:
        """After control tick `tick`: add the state of `data` when a sample is due."""
        recorder = self._recorder
        if recorder is not None and (tick - self._tick0) % self._ticks_per_sample == 0:
            take_sample(recorder, self.scene, data, clamped=clamped)

    def short_of_minimum(self) -> bool:
        """Whether a demo is in progress with fewer samples than a file needs (MIN_SAMPLES)."""
        recorder = self._recorder
        return recorder is not None and recorder.n_samples < MIN_SAMPLES

    def trail(self) -> FloatArray:
        """End-effector positions of the demo in progress, shape (T, 3) [m] (empty if none)."""
        if self._recorder is None:
            return np.zeros((0, 3))
        return self._recorder.ee_positions()

    def take(self) -> DemoRecorder | None:
        """Stop: the demo in progress leaves the slot (None when there was none)."""
        recorder, self._recorder = self._recorder, None
        return recorder

    def check(self, recorder: DemoRecorder, *, incomplete: bool = False) -> TakeCheck:
        """The take checks of `recorder`'s demo (``closed_mid_take`` when `incomplete`)."""
        info = recorder.info
        return check_take(
            recorder.ee_positions(),
            recorder.times(),
            task=self.scene.task,
            plane=self.scene.plane,
            theta_deg=info.theta_deg,
            rho=info.rho,
            closed_mid_take=incomplete,
            config=self.config.take_checks,
        )

    def save(self, recorder: DemoRecorder, *, incomplete: bool = False) -> SavedTake:
        """Check `recorder`'s demo and write it to a new file, flagged when a check failed.

        Raises:
            RecordingError: The demo has fewer samples than the format allows (nothing is
                written) or cannot be written.
        """
        check = self.check(recorder, incomplete=incomplete)
        path = finish_demo(
            recorder,
            self.scene,
            self.recordings_dir,
            incomplete=incomplete,
            session_id=self.session_id,
            flags=check.attr,
            control_hz=self.config.control_hz,
            record_hz=self.config.record_hz,
        )
        LOGGER.info("session %s saved %s %s", self.session_id, path, check.attr)
        return SavedTake(path, check)

    def save_incomplete(self, recorder: DemoRecorder | None, keep: bool) -> Path | None:
        """Settle a demo cut short: saved flagged ``closed_mid_take`` when `keep` and it has at
        least the minimum number of samples, else dropped; the file saved, or None."""
        if recorder is None or not keep or recorder.n_samples < MIN_SAMPLES:
            return None
        return self.save(recorder, incomplete=True).path
