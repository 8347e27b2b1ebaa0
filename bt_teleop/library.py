"""A task's demos on disk, as the page lists them: raw and cleaned, scored, flagged, moderated.

:func:`load_library` reads ``<recordings>/<task>/`` (raw, one file per demo) and
``<recordings>/.cleaned/<task>.cleaned.hdf5`` (see :mod:`bt_teleop.cleaning`) into
:class:`ReplayTrack` records: the end-effector path in the world frame with its timestamps, the
demonstrator's preference, the take-check flags (demo attr ``flags``), whether the file is
excluded (:mod:`bt_pipeline.data.moderation`) and the utility score Ũ.

Scores (paper Eq. 8, :func:`bt_pipeline.score.utility.score_demos`) are computed over the
*usable* raw demos only: neither flagged nor excluded. A junk take therefore never shifts the
others' scores and is never the best demo (★). :func:`library_markdown` renders the table every
tab shows, escaping every text a browser typed (:mod:`bt_teleop.escape`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from bt_pipeline.data.moderation import is_excluded
from bt_pipeline.data.records import DemoRecord, FloatArray, Recording
from bt_pipeline.data.tasks import Task, parse_task
from bt_pipeline.exceptions import BtError, ConfigError, RecordingError
from bt_teleop.cleaning import cleaned_path, task_dir
from bt_teleop.escape import markdown_text

if TYPE_CHECKING:
    from bt_pipeline.data.demo import Demo
    from bt_pipeline.score.utility import RawMetrics

__all__ = [
    "ReplayTrack",
    "TaskLibrary",
    "TrackKind",
    "library_markdown",
    "load_library",
    "plural",
]

TrackKind = Literal["raw", "cleaned"]
LOGGER = logging.getLogger("bt.teleop")
CLAMPED_WARNING_SHARE = 0.05
"""A demo with more than this share of samples clamped to the workspace gets a ⚠ warning."""


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
    """Who recorded it (as typed: escape it before showing it)."""
    theta_deg: float
    """θ [deg] (NaN when unknown)."""
    rho: float
    """ρ (NaN when unknown)."""
    utility: float | None = None
    """Ũ (raw: among the task's usable raw demos; cleaned: after cleaning), None if not scored."""
    flags: tuple[str, ...] = ()
    """Failed take checks (demo attr ``flags``; ``closed_mid_take`` for ep_meta incomplete)."""
    excluded: bool = False
    """Its file is excluded by moderation (a sidecar; the file is untouched)."""
    session: str = ""
    """The app session that recorded it (ep_meta ``session``; empty when unknown)."""
    warnings: tuple[str, ...] = ()
    """Things worth a look that do not make it unusable (e.g. ``clamped``, ``ik_failures``)."""

    @property
    def usable(self) -> bool:
        """Neither flagged nor excluded: scored, rankable, cleaned."""
        return not self.flags and not self.excluded

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
    """Raw demos, oldest file first (flagged and excluded ones included)."""
    cleaned: tuple[ReplayTrack, ...]
    """Cleaned demos of the last Clean (empty before one)."""
    cleaned_stale: bool = False
    """A raw file changed after the last Clean (its output misses the newest takes)."""

    @property
    def tracks(self) -> tuple[ReplayTrack, ...]:
        """Raw then cleaned."""
        return self.raw + self.cleaned

    @property
    def best(self) -> ReplayTrack | None:
        """The usable raw demo with the highest Ũ (never a flagged or excluded one)."""
        scored = [t for t in self.raw if t.usable and t.utility is not None]
        return max(scored, key=lambda t: t.utility or 0.0) if scored else None

    def find(self, key: str) -> ReplayTrack:
        """The track with label `key`.

        Raises:
            ConfigError: No such track (lists a few valid keys).
        """
        for track in self.tracks:
            if track.key == key:
                return track
        valid = ", ".join(t.key for t in self.tracks[:5]) or "none yet"
        raise ConfigError(f"no demo {key!r}; valid are: {valid}")


def load_library(
    recordings_dir: str | Path,
    task: str,
    read: Callable[[Path], Recording] | None = None,
    metrics: MetricsOf | None = None,
) -> TaskLibrary:
    """Read `task`'s raw and cleaned demos (unreadable files are skipped with a warning).

    Args:
        recordings_dir: Root folder of the recordings.
        task: The task.
        read: Reads one file (e.g. from a cache: :class:`bt_teleop.library_loader.LibraryLoader`);
            :func:`~bt_pipeline.data.recording.read_recording` when None.
        metrics: The raw metrics (I, L1-L3) of a file's demo (e.g. from a cache);
            :func:`~bt_pipeline.score.utility.raw_metrics` when None. Ũ is then normalised over
            the task's usable demos (Eqs. 7-8), exactly as
            :func:`~bt_pipeline.score.utility.score_demos` does.
    """
    from bt_pipeline.data.paths import expand_paths
    from bt_pipeline.data.recording import read_recording

    read = read or read_recording
    parsed = parse_task(task)
    folder = task_dir(recordings_dir, parsed)
    raw_recordings: list[Recording] = []
    if folder.is_dir():
        try:
            paths = expand_paths([folder])
        except BtError:  # an empty folder
            paths = []
        for path in paths:
            try:
                raw_recordings.append(read(path))
            except RecordingError as exc:
                LOGGER.warning("skipping %s", exc)
    raw_recordings = [r for r in raw_recordings if r.task == parsed]
    raw = _raw_tracks(raw_recordings, metrics or _raw_metrics)
    cleaned: tuple[ReplayTrack, ...] = ()
    stale = False
    cleaned_file = cleaned_path(recordings_dir, parsed)
    if cleaned_file.is_file():
        try:
            cleaned = _cleaned_tracks(read(cleaned_file))
        except BtError as exc:
            LOGGER.warning("skipping %s", exc)
        stale = _newest_change(raw_recordings) > cleaned_file.stat().st_mtime
    return TaskLibrary(parsed, raw, cleaned, cleaned_stale=stale)


def _newest_change(recordings: list[Recording]) -> float:
    """Latest modification time [s since the epoch] of the files and their sidecars."""
    from bt_pipeline.data.moderation import sidecar_path

    newest = 0.0
    for recording in recordings:
        if recording.path is None:
            continue
        for path in (recording.path, sidecar_path(recording.path)):
            try:
                newest = max(newest, path.stat().st_mtime)
            except OSError:
                continue
    return newest


MetricsOf = Callable[[Path, str, "Demo"], "RawMetrics"]
"""(file, demo name, demo) -> its raw metrics."""


def _raw_metrics(_path: Path, _name: str, demo: Demo) -> RawMetrics:
    from bt_pipeline.score.utility import raw_metrics

    return raw_metrics(demo.positions, demo.actions, demo.theta_deg)


def _utilities(metrics: list[RawMetrics]) -> FloatArray:
    """Ũ of each demo from its raw metrics, normalised over all of them (Eqs. 7-8)."""
    from bt_pipeline.score.utility import Normaliser, ScoreConfig, normalised_utility

    config = ScoreConfig()
    normaliser = Normaliser.from_raw_metrics(metrics, config.delta)
    normalised = normaliser.normalise(np.stack([m.as_array() for m in metrics]))
    return normalised_utility(normalised[:, 0], normalised[:, 1:], config.weights, config.beta)


def _raw_tracks(recordings: list[Recording], metrics_of: MetricsOf) -> tuple[ReplayTrack, ...]:
    from bt_pipeline.data.demo import demos_from_recording

    tracks: list[ReplayTrack] = []
    demos = []
    usable: list[int] = []
    for recording in recordings:
        assert recording.path is not None
        several = len(recording.demos) > 1
        excluded = is_excluded(recording.path)
        file_demos = demos_from_recording(recording)
        for (name, record), demo in zip(recording.demos.items(), file_demos, strict=True):
            key = f"raw · {recording.path.stem}" + (f" · {name}" if several else "")
            meta = record.ep_meta
            warnings = []
            clamped = meta.get("clamped_samples", 0)
            if isinstance(clamped, int) and clamped > CLAMPED_WARNING_SHARE * record.num_samples:
                warnings.append("clamped")
            if isinstance(meta.get("ik_failures"), int) and meta["ik_failures"] > 0:
                warnings.append("ik_failures")
            track = _track(
                key,
                "raw",
                recording.path,
                name,
                record,
                flags=record.flags,
                excluded=excluded,
                session=str(meta.get("session", "")),
                warnings=tuple(warnings),
            )
            if track.usable:
                usable.append(len(tracks))
                demos.append((recording.path, name, demo))
            tracks.append(track)
    if not demos:
        return tuple(tracks)
    try:
        utilities = _utilities([metrics_of(*usable_demo) for usable_demo in demos])
    except BtError as exc:
        LOGGER.warning("cannot score the raw demos: %s", exc)
        return tuple(tracks)
    for index, utility in zip(usable, utilities, strict=True):
        tracks[index] = replace(tracks[index], utility=float(utility))
    return tuple(tracks)


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
        utility = None if utility is None else float(utility)
        tracks.append(
            _track(f"cleaned · {label}", "cleaned", recording.path, name, record, utility=utility)
        )
    return tuple(tracks)


def _track(
    key: str, kind: TrackKind, file: Path, demo: str, record: DemoRecord, **extra: Any
) -> ReplayTrack:
    """A track of `record` (demo `demo` of `file`); `extra` sets the other fields."""
    return ReplayTrack(
        key=key,
        kind=kind,
        file=file,
        demo=demo,
        positions=record.ee_pos,
        times_s=record.timestamps - record.timestamps[0],
        demonstrator=record.demonstrator,
        theta_deg=record.theta_deg,
        rho=record.rho,
        **extra,
    )


def plural(n: int, noun: str) -> str:
    """``1 demo``, ``2 demos``, ``0 demos``."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def library_markdown(library: TaskLibrary, max_rows: int = 12) -> str:
    """A Markdown table of the task's raw demos, and a line on the cleaned ones.

    Rows: usable demos by Ũ (best first), then flagged ones, then excluded ones. Marks: ★ the
    best demo, ⚠ a flagged demo or one with warnings (both on the best demo when it has a
    warning), ⊘ excluded. Every name is escaped (:func:`bt_teleop.escape.markdown_text`).
    """
    if not library.raw:
        return f"No {library.task} recordings yet: press **Record**."
    best = library.best

    def order(track: ReplayTrack) -> tuple[int, float]:
        group = 0 if track.usable else (1 if not track.excluded else 2)
        return group, -(track.utility if track.utility is not None else -1.0)

    ranked = sorted(library.raw, key=order)
    rows = ["| | who | θ, ρ | s | Ũ | note |", "|---|---|---|---|---|---|"]
    for track in ranked[:max_rows]:
        mark = ("★" if track is best else "") + ("⚠" if track.flags or track.warnings else "")
        if track.excluded:
            mark = "⊘"
        pref = "?" if math.isnan(track.theta_deg) else f"{track.theta_deg:.0f}°, {track.rho:.2f}"
        score = "–" if track.utility is None else f"{track.utility:.2f}"
        note = ", ".join(
            (["excluded"] if track.excluded else []) + list(track.flags) + list(track.warnings)
        )
        who = markdown_text(track.demonstrator, 24)
        rows.append(
            f"| {mark} | {who} | {pref} | {track.duration_s:.1f} | {score} | "
            f"{note.replace('_', ' ')} |"
        )
    n_usable = sum(t.usable for t in library.raw)
    head = f"{plural(len(library.raw), 'demo')} of {library.task}, {n_usable} usable"
    lines = [f"{head} (★ best, ⚠ flagged or worth a look, ⊘ excluded)", "", *rows]
    if len(ranked) > max_rows:
        lines.append(f"… and {len(ranked) - max_rows} more")
    if library.cleaned and library.cleaned_stale:
        lines += ["", "The recordings changed since the last Clean: press **Clean** again."]
    elif library.cleaned:
        scores = [t.utility for t in library.cleaned if t.utility is not None]
        mean = f": mean Ũ {np.mean(scores):.2f}" if scores else ""
        lines += ["", f"Cleaned: {plural(len(library.cleaned), 'demo')}{mean}"]
    return "\n".join(lines)
