"""A task's demos on disk (raw and cleaned, with scores) and replaying one on a session's robot.

:func:`load_library` reads ``<recordings>/<task>/`` (raw, one file per demo) and
``<recordings>/.cleaned/<task>.cleaned.hdf5`` (see :mod:`bt_teleop.cleaning`) into
:class:`ReplayTrack` records: the end-effector path in the world frame with its timestamps, the
demonstrator's preference and the utility score Ũ (raw demos: :func:`bt_pipeline.score.utility.
score_demos` over the task's raw demos; cleaned demos: the score the cleaner stored).

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
from pathlib import Path
from typing import Literal

import numpy as np

from bt_pipeline.data.records import FloatArray, Recording
from bt_pipeline.data.tasks import Task, parse_task
from bt_pipeline.exceptions import BtError, ConfigError
from bt_teleop.cleaning import cleaned_path, task_dir
from bt_teleop.session import Session

TrackKind = Literal["raw", "cleaned"]
LOGGER = logging.getLogger("bt.teleop")
APPROACH_TOLERANCE_M = 0.005
"""The approach ends when the end effector is this close to the track's start [m]."""
APPROACH_TIMEOUT_S = 2.0
"""Longest approach [s] of simulation time."""


@dataclass(frozen=True, eq=False)  # holds arrays
class ReplayTrack:
    """One replayable demo."""

    key: str
    """Unique label in the task's library (what the Replay picker shows)."""
    kind: TrackKind
    """raw or cleaned."""
    file: Path
    """The file it was read from."""
    demo: str
    """Its name in that file."""
    positions: FloatArray
    """End-effector path in the world frame, shape (T, 3), in [m]."""
    times_s: FloatArray
    """Timestamps from 0, strictly increasing, shape (T,), in [s]."""
    demonstrator: str
    """Who recorded it."""
    theta_deg: float
    """θ [deg] (NaN when unknown)."""
    rho: float
    """ρ (NaN when unknown)."""
    utility: float | None = None
    """Ũ (raw: among the task's raw demos; cleaned: after cleaning), None if not scored."""
    incomplete: bool = False
    """Saved when its tab closed mid-recording (ep_meta ``incomplete``)."""

    @property
    def duration_s(self) -> float:
        """Length [s]."""
        return float(self.times_s[-1])

    def target_at(self, t_s: float) -> FloatArray:
        """Linearly interpolated position at `t_s` [s] (held outside the track), shape (3,)."""
        return np.array([np.interp(t_s, self.times_s, self.positions[:, j]) for j in range(3)])


@dataclass(frozen=True)
class TaskLibrary:
    """Everything replayable for one task."""

    task: Task
    raw: tuple[ReplayTrack, ...]
    """Raw demos, oldest file first."""
    cleaned: tuple[ReplayTrack, ...]
    """Cleaned demos of the last Clean (empty before one)."""

    @property
    def tracks(self) -> tuple[ReplayTrack, ...]:
        """Raw then cleaned."""
        return self.raw + self.cleaned

    def find(self, key: str) -> ReplayTrack:
        """The track with label `key`.

        Raises:
            ConfigError: No such track (lists a few valid keys).
        """
        for track in self.tracks:
            if track.key == key:
                return track
        valid = ", ".join(t.key for t in self.tracks[:5]) or "none yet"
        raise ConfigError(f"no demo {key!r} to replay; valid are: {valid}")


def load_library(recordings_dir: str | Path, task: str) -> TaskLibrary:
    """Read `task`'s raw and cleaned demos (unreadable files are skipped with a warning)."""
    from bt_pipeline.data.paths import expand_paths
    from bt_pipeline.data.recording import read_recording, read_recordings

    parsed = parse_task(task)
    folder = task_dir(recordings_dir, parsed)
    raw_recordings: list[Recording] = []
    if folder.is_dir():
        try:
            raw_recordings = read_recordings(expand_paths([folder]), strict=False)
        except BtError:  # an empty folder
            raw_recordings = []
    raw = _raw_tracks([r for r in raw_recordings if r.task == parsed])
    cleaned: tuple[ReplayTrack, ...] = ()
    cleaned_file = cleaned_path(recordings_dir, parsed)
    if cleaned_file.is_file():
        try:
            cleaned = _cleaned_tracks(read_recording(cleaned_file))
        except BtError as exc:
            LOGGER.warning("skipping %s", exc)
    return TaskLibrary(parsed, raw, cleaned)


def _raw_tracks(recordings: list[Recording]) -> tuple[ReplayTrack, ...]:
    from bt_pipeline.data.demo import demos_from_recording
    from bt_pipeline.score.utility import score_demos

    tracks: list[ReplayTrack] = []
    demos = []
    for recording in recordings:
        assert recording.path is not None
        several = len(recording.demos) > 1
        for name, record in recording.demos.items():
            key = f"raw · {recording.path.stem}" + (f" · {name}" if several else "")
            tracks.append(
                ReplayTrack(
                    key=key,
                    kind="raw",
                    file=recording.path,
                    demo=name,
                    positions=record.ee_pos,
                    times_s=record.timestamps - record.timestamps[0],
                    demonstrator=record.demonstrator,
                    theta_deg=record.theta_deg,
                    rho=record.rho,
                    incomplete=bool(record.ep_meta.get("incomplete", False)),
                )
            )
        demos.extend(demos_from_recording(recording))
    if not demos:
        return ()
    try:
        scores = score_demos(demos).scores
    except BtError as exc:
        LOGGER.warning("cannot score the raw demos: %s", exc)
        return tuple(tracks)
    return tuple(
        _with_utility(track, score.utility) for track, score in zip(tracks, scores, strict=True)
    )


def _cleaned_tracks(recording: Recording) -> tuple[ReplayTrack, ...]:
    assert recording.path is not None
    tracks = []
    for name, record in recording.demos.items():
        source = str(record.attrs.get("cleaned_from", name))
        file, _, demo = source.rpartition(":")
        label = Path(file).stem if file else name
        if demo and demo != "demo_0":
            label = f"{label} · {demo}"
        utility = record.attrs.get("utility_cleaned")
        tracks.append(
            ReplayTrack(
                key=f"cleaned · {label}",
                kind="cleaned",
                file=recording.path,
                demo=name,
                positions=record.ee_pos,
                times_s=record.timestamps - record.timestamps[0],
                demonstrator=record.demonstrator,
                theta_deg=record.theta_deg,
                rho=record.rho,
                utility=None if utility is None else float(utility),
                incomplete=bool(record.ep_meta.get("incomplete", False)),
            )
        )
    return tuple(tracks)


def _with_utility(track: ReplayTrack, utility: float) -> ReplayTrack:
    from dataclasses import replace

    return replace(track, utility=float(utility))


def library_markdown(library: TaskLibrary, max_rows: int = 12) -> str:
    """A Markdown table of the task's raw demos, best Ũ first, and a line on the cleaned ones."""
    if not library.raw:
        return f"No {library.task} recordings yet: press **Record**."
    ranked = sorted(library.raw, key=lambda t: -(t.utility if t.utility is not None else -1.0))
    rows = ["| | who | θ, ρ | s | Ũ |", "|---|---|---|---|---|"]
    for k, track in enumerate(ranked[:max_rows]):
        mark = "★" if k == 0 and track.utility is not None else ("⚠" if track.incomplete else "")
        pref = "?" if math.isnan(track.theta_deg) else f"{track.theta_deg:.0f}°, {track.rho:.2f}"
        score = "–" if track.utility is None else f"{track.utility:.2f}"
        who = track.demonstrator.replace("|", "/")[:16]
        rows.append(f"| {mark} | {who} | {pref} | {track.duration_s:.1f} | {score} |")
    lines = [f"{len(library.raw)} demos of {library.task} (★ best, ⚠ incomplete)", "", *rows]
    if len(ranked) > max_rows:
        lines.append(f"… and {len(ranked) - max_rows} more")
    if library.cleaned:
        scores = [t.utility for t in library.cleaned if t.utility is not None]
        mean = f": mean Ũ {np.mean(scores):.2f}" if scores else ""
        lines += ["", f"Cleaned: {len(library.cleaned)} demos{mean}"]
    return "\n".join(lines)


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
