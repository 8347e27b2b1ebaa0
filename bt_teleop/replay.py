"""Replaying one demo of a task's library (:mod:`bt_teleop.library`) on a session's robot.

Replaying feeds the track to the session as its target, so the FR3 tracks it through the same
IK as a person's gizmo::

    ReplayPlayer thread (every ~5 ms of wall time)
        approach: target = track start, until the end effector is within 5 mm (or 2 s)
        play:     target = track(t_sim - t0), t_sim the session's simulation time
        -> ReplayResult (actual path, target path, RMS tracking error)

:func:`replay_sync` does the same synchronously, stepping the session (tests, benchmarks).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass

import numpy as np

from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import BtError
from bt_teleop.library import ReplayTrack, TaskLibrary, TrackKind, library_markdown, load_library
from bt_teleop.session import Session

LOGGER = logging.getLogger("bt.teleop")
APPROACH_TOLERANCE_M = 0.005
"""The approach ends when the end effector is this close to the track's start [m]."""
APPROACH_TIMEOUT_S = 2.0
"""Longest approach [s] of simulation time."""


@dataclass(frozen=True, eq=False)  # holds arrays
class ReplayResult:
    """How well the robot tracked a replayed demo."""

    times_s: FloatArray
    """Track time of each sample, shape (K,), in [s]."""
    ee_positions: FloatArray
    """End-effector positions reached, shape (K, 3), in [m]."""
    targets: FloatArray
    """Track positions at the same times, shape (K, 3), in [m]."""

    @property
    def rms_error_m(self) -> float:
        """RMS distance between the end effector and the track [m]."""
        if len(self.times_s) == 0:
            return math.nan
        return float(np.sqrt(np.mean(np.sum((self.ee_positions - self.targets) ** 2, axis=1))))


def replay_sync(session: Session, track: ReplayTrack) -> ReplayResult:
    """Replay `track` on `session` synchronously (the session must not run in real time)."""
    quat = session.scene.ee_quat
    session.set_target(track.positions[0], quat)
    waited = 0.0
    while waited < APPROACH_TIMEOUT_S:
        if np.linalg.norm(session.status().ee_pos - track.positions[0]) < APPROACH_TOLERANCE_M:
            break
        session.step(1)
        waited += session.dt_s
    times, reached, targets = [], [], []
    for k in range(math.ceil(track.duration_s / session.dt_s) + 1):
        t_s = min(k * session.dt_s, track.duration_s)
        target = track.target_at(t_s)
        session.set_target(target)
        session.step(1)
        times.append(t_s)
        reached.append(session.status().ee_pos)
        targets.append(track.target_at(t_s + session.dt_s))  # where it should be after the tick
    return ReplayResult(np.array(times), np.array(reached), np.array(targets))


class ReplayPlayer:
    """Plays a track on a session running in real time, from a thread of its own."""

    def __init__(self, session: Session, track: ReplayTrack, period_s: float = 0.005) -> None:
        """Prepare to replay `track` on `session`; call :meth:`start`."""
        self.session = session
        self.track = track
        self.period_s = period_s
        self.result: ReplayResult | None = None
        """Set when the track has been played to its end."""
        self._stop = threading.Event()
        self._phase = "approach"
        self._t_s = 0.0
        self._thread = threading.Thread(target=self._run, name="bt-replay", daemon=True)

    def start(self) -> None:
        """Begin: approach the track's start, then play it at simulation speed."""
        self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop early (the robot holds its last target)."""
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)

    @property
    def finished(self) -> bool:
        """Whether the replay ended (played to its end, stopped, or failed)."""
        return self._thread.ident is not None and not self._thread.is_alive()

    @property
    def progress(self) -> tuple[str, float]:
        """(phase, fraction played): phase is approach, play or done."""
        fraction = self._t_s / self.track.duration_s if self.track.duration_s > 0 else 1.0
        return self._phase, min(1.0, fraction)

    def _run(self) -> None:
        try:
            self._play()
        except BtError as exc:  # e.g. the session closed under us
            LOGGER.info("replay stopped: %s", exc)
        finally:
            self._phase = "done"

    def _play(self) -> None:
        session, track = self.session, self.track
        session.set_target(track.positions[0], session.scene.ee_quat)
        t_start = session.status().sim_time_s
        while not self._stop.is_set():
            status = session.status()
            close = np.linalg.norm(status.ee_pos - track.positions[0]) < APPROACH_TOLERANCE_M
            if close or status.sim_time_s - t_start > APPROACH_TIMEOUT_S or not status.running:
                break
            time.sleep(self.period_s)
        self._phase = "play"
        t0 = session.status().sim_time_s
        times, reached, targets = [], [], []
        while not self._stop.is_set():
            status = session.status()
            t_s = status.sim_time_s - t0
            if t_s > 0.0:  # the pose now answers the target set one period ago
                times.append(t_s)
                reached.append(status.ee_pos)
                targets.append(track.target_at(t_s))
            self._t_s = t_s
            if t_s >= track.duration_s or not status.running:
                break
            session.set_target(track.target_at(t_s + self.period_s))
            time.sleep(self.period_s)
        if not self._stop.is_set():
            self.result = ReplayResult(np.array(times), np.array(reached), np.array(targets))


__all__ = [
    "ReplayPlayer",
    "ReplayResult",
    "ReplayTrack",
    "TaskLibrary",
    "TrackKind",
    "library_markdown",
    "load_library",
    "replay_sync",
]
