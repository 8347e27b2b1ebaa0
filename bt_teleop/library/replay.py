"""Replaying one demo of a task's library (:mod:`bt_teleop.library.listing`) on a session's robot.

Replaying feeds the track's samples (read from its file on Play:
:class:`~bt_teleop.library.track_samples.TrackReader`) to the session as its target, so the FR3
tracks
it through the same IK as a person's gizmo::

    ReplayPlayer thread (every ~5 ms of wall time)
        approach: target = track start, until the end effector is within 5 mm (or 2 s)
        play:     target = track(t_sim - t0), t_sim the session's simulation time
        -> ReplayResult (actual path, target path, RMS tracking error)
    after: target = where the end effector stands (:func:`hold_pose`)

Every target a replay sets lies in the scene's workspace box (:func:`within_workspace`). A
demo's samples are where its end effector *was*, which may lie a hair outside the box (a wiping
take pressed onto the table, z below the box's floor), and the session flags a target it had to
clamp: the page's "⚠ target clamped to the workspace" is for a person's own target, not for a
replay nobody touched.

:func:`replay_sync` does the same synchronously, stepping the session (tests, benchmarks).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import BtError
from bt_teleop.library.listing import (
    ReplayTrack,
    TaskLibrary,
    TrackKind,
    library_markdown,
    load_library,
)
from bt_teleop.library.track_samples import TrackReader, TrackSamples
from bt_teleop.session.control_loop import Session
from bt_teleop.session.process import SessionProcess

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


def within_workspace(session: Session | SessionProcess, p_world: FloatArray) -> FloatArray:
    """`p_world` (3,) [m] moved into `session`'s workspace box (the nearest point of it)."""
    return session.scene.workspace.clamp(p_world)[0]


def hold_pose(session: Session | SessionProcess) -> FloatArray:
    """After a replay: make where the end effector stands (inside the workspace) the target, so
    the robot stays and nothing is flagged clamped; that target, shape (3,) [m]."""
    target = within_workspace(session, session.status().ee_pos)
    session.set_target(target)
    return target


def replay_sync(session: Session, track: TrackSamples) -> ReplayResult:
    """Replay `track` on `session` synchronously (the session must not run in real time)."""
    quat = session.scene.ee_quat
    session.set_target(within_workspace(session, track.positions[0]), quat)
    waited = 0.0
    while waited < APPROACH_TIMEOUT_S:
        if np.linalg.norm(session.status().ee_pos - track.positions[0]) < APPROACH_TOLERANCE_M:
            break
        session.step(1)
        waited += session.dt_s
    times, reached, targets = [], [], []
    for k in range(math.ceil(track.duration_s / session.dt_s) + 1):
        t_s = min(k * session.dt_s, track.duration_s)
        session.set_target(within_workspace(session, track.target_at(t_s)))
        session.step(1)
        times.append(t_s)
        reached.append(session.status().ee_pos)
        targets.append(track.target_at(t_s + session.dt_s))  # where it should be after the tick
    return ReplayResult(np.array(times), np.array(reached), np.array(targets))


def read_replay(
    library: TaskLibrary,
    track: ReplayTrack,
    reader: TrackReader,
    on_stale: Callable[[], object] = lambda: None,
) -> tuple[TrackSamples, list[tuple[TrackKind, FloatArray]]]:
    """Read `track`'s samples for Play, and the paths drawn while it replays.

    Args:
        library: The listed library `track` is from.
        track: The demo to play.
        reader: Reads (or recalls) a track's samples from its file.
        on_stale: Called when `track`'s file is gone or changed (the list needs a reload).

    Returns:
        The samples, and each path drawn as (kind, positions of shape (T, 3) [m]): the track
        and, for a cleaned demo, its raw source to compare (left out when that cannot be read).

    Raises:
        RecordingError: `track` cannot be read (the message names it and its file).
    """
    try:
        samples = reader.read(track)
    except BtError:
        on_stale()
        raise
    paths: list[tuple[TrackKind, FloatArray]] = [(track.kind, samples.positions)]
    source = library.source_of(track)
    if source is not None:
        try:
            paths.append((source.kind, reader.read(source).positions))
        except BtError as exc:
            LOGGER.info("not drawing the raw source: %s", exc)
    return samples, paths


class ReplayPlayer:
    """Plays a track on a session running in real time, from a thread of its own."""

    def __init__(
        self,
        session: Session | SessionProcess,
        track: ReplayTrack,
        samples: TrackSamples,
        period_s: float = 0.005,
    ) -> None:
        """Prepare to replay `track` (its `samples`) on `session`; call :meth:`start`."""
        self.session = session
        self.track = track
        """The demo played (as listed)."""
        self.samples = samples
        """Its samples."""
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
        duration = self.samples.duration_s
        fraction = self._t_s / duration if duration > 0 else 1.0
        return self._phase, min(1.0, fraction)

    def _run(self) -> None:
        try:
            self._play()
        except BtError as exc:  # e.g. the session closed under us
            LOGGER.info("replay stopped: %s", exc)
        finally:
            self._phase = "done"

    def _play(self) -> None:
        session, track = self.session, self.samples
        session.set_target(within_workspace(session, track.positions[0]), session.scene.ee_quat)
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
            session.set_target(within_workspace(session, track.target_at(t_s + self.period_s)))
            time.sleep(self.period_s)
        if not self._stop.is_set():
            self.result = ReplayResult(np.array(times), np.array(reached), np.array(targets))


__all__ = [
    "ReplayPlayer",
    "ReplayResult",
    "ReplayTrack",
    "TaskLibrary",
    "TrackKind",
    "TrackSamples",
    "hold_pose",
    "library_markdown",
    "load_library",
    "read_replay",
    "replay_sync",
    "within_workspace",
]
