"""A task's demos on disk, as the page lists them: raw and cleaned, scored, flagged, moderated.

:func:`load_library` lists ``<recordings>/<task>/`` (raw, one file per demo) and
``<recordings>/.cleaned/<task>.cleaned.hdf5`` (see :mod:`bt_teleop.cleaning`) as
:class:`~bt_teleop.tracks.ReplayTrack` records: the demonstrator and preference, the duration,
the take-check flags (demo attr ``flags``), whether the file is excluded
(:mod:`bt_pipeline.data.moderation`), the utility score Ũ, and the file's identity. No samples:
a track's path is read from its file when it is played (:mod:`bt_teleop.track_samples`), so the
library of a task with thousands of takes stays small (about 1 KiB a take).

Scores (paper Eq. 8, :func:`bt_pipeline.score.utility.score_demos`) are computed over the
*usable* raw demos only: neither flagged nor excluded. A junk take therefore never shifts the
others' scores and is never the best demo (★). :func:`library_markdown` renders the table every
tab shows, escaping every text a browser typed (:mod:`bt_teleop.escape`).
"""

from __future__ import annotations

import heapq
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from bt_pipeline.data.moderation import is_excluded
from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.tasks import Task, parse_task
from bt_pipeline.exceptions import BtError, ConfigError
from bt_teleop.cleaning import cleaned_path, task_dir
from bt_teleop.escape import markdown_text
from bt_teleop.tracks import FileTracks, ReplayTrack, TrackKind, read_file_tracks

if TYPE_CHECKING:
    from bt_pipeline.score.utility import RawMetrics

__all__ = [
    "ReplayTrack",
    "TaskLibrary",
    "TrackKind",
    "library_markdown",
    "load_library",
    "plural",
    "ranked",
]

LOGGER = logging.getLogger("bt.teleop")


@dataclass(frozen=True)
class TaskLibrary:
    """Everything replayable for one task (listed, not loaded: see :mod:`bt_teleop.tracks`)."""

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

    def source_of(self, track: ReplayTrack) -> ReplayTrack | None:
        """The raw demo a cleaned `track` was cleaned from (None: raw, or not listed)."""
        return next((t for t in self.raw if track.source and t.key == track.source), None)


ReadTracks = Callable[[Path, TrackKind], FileTracks]
"""(file, raw or cleaned) -> its tracks (e.g. from a cache)."""


def load_library(
    recordings_dir: str | Path, task: str, read: ReadTracks | None = None
) -> TaskLibrary:
    """List `task`'s raw and cleaned demos (unreadable files are skipped with a warning).

    Args:
        recordings_dir: Root folder of the recordings.
        task: The task.
        read: Reads one file's tracks and raw metrics (e.g. from a cache:
            :class:`bt_teleop.library_loader.LibraryLoader`); :func:`read_file_tracks` when None.
            Ũ is then normalised over the task's usable demos (Eqs. 7-8), exactly as
            :func:`~bt_pipeline.score.utility.score_demos` does.
    """
    from bt_pipeline.data.paths import expand_paths

    read = read or read_file_tracks
    parsed = parse_task(task)
    folder = task_dir(recordings_dir, parsed)
    files: list[FileTracks] = []
    if folder.is_dir():
        try:
            paths = expand_paths([folder])
        except BtError:  # an empty folder
            paths = []
        for path in paths:
            try:
                files.append(read(path, "raw"))
            except BtError as exc:
                LOGGER.warning("skipping %s", exc)
    files = [f for f in files if f.task == parsed]
    raw = _scored(files)
    cleaned: tuple[ReplayTrack, ...] = ()
    stale = False
    cleaned_file = cleaned_path(recordings_dir, parsed)
    if cleaned_file.is_file():
        try:
            cleaned_tracks = read(cleaned_file, "cleaned")
        except BtError as exc:
            LOGGER.warning("skipping %s", exc)
        else:
            cleaned = cleaned_tracks.tracks
            stale = _newest_change_ns(files) > cleaned_tracks.stamp.mtime_ns
    return TaskLibrary(parsed, raw, cleaned, cleaned_stale=stale)


def _newest_change_ns(files: list[FileTracks]) -> int:
    """Latest modification time [ns since the epoch] of the files and their sidecars."""
    from bt_pipeline.data.moderation import sidecar_path

    newest = 0
    for file in files:
        newest = max(newest, file.stamp.mtime_ns)
        try:
            newest = max(newest, sidecar_path(file.path).stat().st_mtime_ns)
        except OSError:
            continue
    return newest


def _utilities(metrics: list[RawMetrics]) -> FloatArray:
    """Ũ of each demo from its raw metrics, normalised over all of them (Eqs. 7-8)."""
    from bt_pipeline.score.utility import Normaliser, ScoreConfig, normalised_utility

    config = ScoreConfig()
    normaliser = Normaliser.from_raw_metrics(metrics, config.delta)
    normalised = normaliser.normalise(np.stack([m.as_array() for m in metrics]))
    return normalised_utility(normalised[:, 0], normalised[:, 1:], config.weights, config.beta)


def _scored(files: list[FileTracks]) -> tuple[ReplayTrack, ...]:
    """The raw tracks of `files`, marked excluded (moderation) and scored among the usable ones.

    A usable demo whose raw metrics could not be computed stays unscored (Ũ None); the others
    are normalised without it.
    """
    tracks: list[ReplayTrack] = []
    scored: list[tuple[int, RawMetrics]] = []
    for file in files:
        excluded = is_excluded(file.path)
        for track, metrics in zip(file.tracks, file.metrics, strict=True):
            track = replace(track, excluded=excluded) if excluded else track
            if track.usable and metrics is not None:
                scored.append((len(tracks), metrics))
            tracks.append(track)
    if not scored:
        return tuple(tracks)
    try:
        utilities = _utilities([metrics for _, metrics in scored])
    except BtError as exc:
        LOGGER.warning("cannot score the raw demos: %s", exc)
        return tuple(tracks)
    for (index, _), utility in zip(scored, utilities, strict=True):
        tracks[index] = replace(tracks[index], utility=float(utility))
    return tuple(tracks)


def plural(n: int, noun: str) -> str:
    """``1 demo``, ``2 demos``, ``0 demos``."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def _order(track: ReplayTrack) -> tuple[int, float]:
    group = 0 if track.usable else (1 if not track.excluded else 2)
    return group, -(track.utility if track.utility is not None else -1.0)


def ranked(library: TaskLibrary, limit: int) -> list[ReplayTrack]:
    """The first `limit` raw demos in the table's order: usable by Ũ (best first), flagged,
    excluded (``sorted(...)[:limit]`` without sorting them all)."""
    return heapq.nsmallest(limit, library.raw, key=_order)


def library_markdown(library: TaskLibrary, max_rows: int = 12) -> str:
    """A Markdown table of the task's raw demos, and a line on the cleaned ones.

    Rows: usable demos by Ũ (best first), then flagged ones, then excluded ones. Marks: ★ the
    best demo, ⚠ a flagged demo or one with warnings (both on the best demo when it has a
    warning), ⊘ excluded. Every name is escaped (:func:`bt_teleop.escape.markdown_text`).
    """
    if not library.raw:
        return f"No {library.task} recordings yet: press **Record**."
    best = library.best
    rows = ["| | who | θ, ρ | s | Ũ | note |", "|---|---|---|---|---|---|"]
    for track in ranked(library, max_rows):
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
    if len(library.raw) > max_rows:
        lines.append(f"… and {len(library.raw) - max_rows} more")
    if library.cleaned and library.cleaned_stale:
        lines += ["", "The recordings changed since the last Clean: press **Clean** again."]
    elif library.cleaned:
        scores = [t.utility for t in library.cleaned if t.utility is not None]
        mean = f": mean Ũ {np.mean(scores):.2f}" if scores else ""
        lines += ["", f"Cleaned: {plural(len(library.cleaned), 'demo')}{mean}"]
    return "\n".join(lines)
