"""A task's demos on disk, as the page lists them: raw and cleaned, scored, flagged, moderated.

:func:`load_library` lists ``<recordings>/<task>/`` (raw, one file per demo) and
``<recordings>/.cleaned/<task>.cleaned.hdf5`` (see :mod:`bt_teleop.clean.runner`) as
:class:`~bt_teleop.library.tracks.ReplayTrack` records: the demonstrator and preference, the
duration, the take-check flags (demo attr ``flags``), whether the file is excluded
(:mod:`bt_pipeline.data.moderation`), the utility score Ũ, and the file's identity. No samples:
a track's path is read from its file when it is played (:mod:`bt_teleop.library.track_samples`), so
the library of a task with thousands of takes stays small (about 1 KiB a take).

Scores (paper Eq. 8) are computed over the *usable* raw demos only: neither flagged nor
excluded. A junk take therefore never shifts the others' scores and is never the best demo (★).
They are read as ``bt clean`` and ``bt score`` read them (:mod:`bt_pipeline.clean.selection`):
each take on its periodic part (its rest, approach and retreat left out), and the best is the
take with the highest Ũ among those that follow the guide about as closely as any, so the ★ is
the demo the Clean button takes as its best, and a line under the table says why when another
take has the higher Ũ. Ũ is relative to the set: the first Ũ each take read is kept
(:mod:`bt_teleop.takes.saved_utility`) and the table marks one that has moved since ("0.36 (was
0.56)"). :func:`library_markdown` renders the table every tab shows, its rows by rank or by
Ũ, escaping every text a browser typed (:mod:`bt_teleop.takes.escape`).
"""

from __future__ import annotations

import heapq
import logging
import math
import os
from array import array
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from bt_pipeline.data.moderation import is_excluded
from bt_pipeline.data.paths import RECORDING_SUFFIXES
from bt_pipeline.data.tasks import GuidedTask, parse_guided_task
from bt_pipeline.exceptions import BtError, ConfigError
from bt_pipeline.viz.demo_style import who_when
from bt_teleop.clean.runner import cleaned_path, task_dir
from bt_teleop.library.reading import read_file_tracks
from bt_teleop.library.tracks import (
    FileTracks,
    ReplayTrack,
    TrackKind,
    track_when,
    track_who_when,
)
from bt_teleop.takes.escape import markdown_text
from bt_teleop.takes.saved_utility import remember

if TYPE_CHECKING:
    from bt_pipeline.clean.selection import TakeScore

__all__ = [
    "ReplayTrack",
    "RowOrder",
    "TaskLibrary",
    "TrackKind",
    "library_markdown",
    "load_library",
    "plural",
    "ranked",
    "task_files",
]

LOGGER = logging.getLogger("bt.teleop")
_WARNING_TEXT = {"off_guide": "off the guide: kept and cleaned"}  # a take-check remark


@dataclass(frozen=True)
class TaskLibrary:
    """Everything replayable for one task (listed, not loaded: see
    :mod:`bt_teleop.library.tracks`)."""

    task: GuidedTask
    raw: tuple[ReplayTrack, ...]
    """Raw demos, oldest file first (flagged and excluded ones included)."""
    cleaned: tuple[ReplayTrack, ...]
    """Cleaned demos of the last Clean (empty before one)."""
    cleaned_stale: bool = False
    """A raw file changed after the last Clean (its output misses the newest takes)."""
    best_reason: str = ""
    """Why the ★ take is the best when another usable take has a higher Ũ (the line ``bt
    score`` prints, :func:`~bt_pipeline.clean.shape_gate.gate_reason`); empty when it is not."""
    ranks: array = field(default_factory=lambda: array("l"))
    """Each raw demo's rank as ``bt score`` ranks it (1: the best, ★; 0: not ranked), in
    :attr:`raw`'s order (8 bytes a take: a rank in each track would make a save that moves
    the ranks below it a new object for each of those takes)."""

    @property
    def tracks(self) -> tuple[ReplayTrack, ...]:
        """Raw then cleaned."""
        return self.raw + self.cleaned

    @property
    def best(self) -> ReplayTrack | None:
        """The first usable raw demo in the ranking: the highest Ũ among those that follow the
        guide about as closely as any (never a flagged or excluded one)."""
        scored = [t for t in self.raw if t.usable and t.utility is not None]
        return min(scored, key=_order) if scored else None

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


RowOrder = Literal["rank", "utility"]
"""How the table orders the usable takes: by rank (★ first) or by Ũ."""

ReadTracks = Callable[[Path, TrackKind], FileTracks]
"""(file, raw or cleaned) -> its tracks (e.g. from a cache)."""


def load_library(
    recordings_dir: str | Path,
    task: str,
    read: ReadTracks | None = None,
    previous: TaskLibrary | None = None,
) -> TaskLibrary:
    """List `task`'s raw and cleaned demos (unreadable files are skipped with a warning).

    Args:
        recordings_dir: Root folder of the recordings.
        task: The task.
        read: Reads one file's tracks and raw metrics (e.g. from a cache:
            :class:`bt_teleop.library.loader.LibraryLoader`); :func:`read_file_tracks` when None.
            Ũ is then normalised over the task's usable demos (Eqs. 7-8), exactly as
            :func:`~bt_pipeline.clean.selection.select_demos` does.
        previous: The task's last library (from the same `read`): a raw demo whose file, Ũ
            and exclusion did not change is listed by that library's very object, so a load
            allocates new tracks only for what changed (Ũ is min-max normalised, Eq. 7: a new
            take changes the others' Ũ only when it moves a metric's min or max).
    """
    read = read or read_file_tracks
    parsed = parse_guided_task(task)
    folder = task_dir(recordings_dir, parsed)
    files: list[FileTracks] = []
    if folder.is_dir():
        for path in task_files(folder):
            try:
                files.append(read(path, "raw"))
            except BtError as exc:
                LOGGER.warning("skipping %s", exc)
    files = [f for f in files if f.task == parsed]
    raw, reason, ranks = _scored(
        files, {t.key: t for t in previous.raw} if previous is not None else {}, folder
    )
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
    return TaskLibrary(parsed, raw, cleaned, cleaned_stale=stale, best_reason=reason, ranks=ranks)


def task_files(folder: Path) -> list[Path]:
    """The recordings under `folder`, sorted: what :func:`bt_pipeline.data.paths.expand_paths`
    gives for a folder (``*.hdf5`` and ``*.h5`` below it, hidden files and folders skipped),
    from one directory scan without a stat or a resolve per file (a load after every save:
    expand_paths allocated 0.8 MiB for 1,000 takes, ``bench_save_growth.py``)."""
    found: list[Path] = []
    for directory, subdirs, names in os.walk(folder):
        subdirs[:] = sorted(d for d in subdirs if not d.startswith("."))
        found.extend(
            Path(directory, name)
            for name in names
            if name.endswith(RECORDING_SUFFIXES) and not name.startswith(".")
        )
    return sorted(found)


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


def _scored(
    files: list[FileTracks], before: dict[str, ReplayTrack], folder: Path
) -> tuple[tuple[ReplayTrack, ...], str, array]:
    """The raw tracks of `files`, marked excluded (moderation) and scored among the usable ones;
    why the best is the best when it is not the highest Ũ (empty otherwise); their ranks.

    Ũ and the ranks are those of :func:`bt_pipeline.clean.selection.rank_takes`, the set's Ũ
    (:func:`bt_pipeline.score.utility.set_utilities`) that ``bt score`` shows. Each scored
    take also carries the Ũ it read when first listed (:mod:`bt_teleop.takes.saved_utility`, kept in
    `folder`). A track listed in `before` (key -> track) from the same file version, with the
    same fields, is that very object: no new object for a demo that did not change. A usable
    demo whose raw metrics could not be computed stays unscored (Ũ None); the others are
    normalised without it.
    """
    from bt_pipeline.clean.selection import rank_takes
    from bt_pipeline.clean.shape_gate import gate_reason

    listed: list[tuple[ReplayTrack, bool]] = []
    scored: list[tuple[int, TakeScore]] = []
    for file in files:
        excluded = is_excluded(file.path)
        for track, metrics in zip(file.tracks, file.metrics, strict=True):
            if not track.flags and not excluded and metrics is not None:
                scored.append((len(listed), metrics))
            listed.append((track, excluded))
    utilities: dict[int, tuple[float, bool]] = {}
    ranks = array("l", bytes(8 * len(listed)))  # zeros: not ranked
    reason = ""
    if scored:
        try:
            values, allowed = rank_takes([metrics for _, metrics in scored])
        except BtError as exc:
            LOGGER.warning("cannot score the raw demos: %s", exc)
        else:
            order = np.lexsort((-values, ~allowed))  # as bt score ranks (shape_gate.gate_best)
            rank = np.empty(len(order), dtype=np.int64)
            rank[order] = np.arange(1, len(order) + 1)
            utilities = {
                i: (float(u), bool(ok))
                for (i, _), u, ok in zip(scored, values, allowed, strict=True)
            }
            for (i, _), r in zip(scored, rank, strict=True):
                ranks[i] = int(r)
            first, best = int(np.argmax(values)), int(order[0])
            if values[first] > values[best]:
                reason = gate_reason(
                    _who(listed[scored[first][0]][0]),
                    _who(listed[scored[best][0]][0]),
                    scored[first][1].misfit,
                    scored[best][1].misfit,
                    "guide",
                )
    saved = remember(
        folder,
        {listed[i][0].key: u for i, (u, _) in utilities.items()},
        {track.key for track, _ in listed},
    )
    tracks: list[ReplayTrack] = []
    for index, (track, excluded) in enumerate(listed):
        utility, eligible = utilities.get(index, (None, True))
        kept = saved.get(track.key) if utility is not None else None
        fields = (excluded, utility, eligible, kept)
        old = before.get(track.key)
        if (
            old is not None
            and (old.file, old.demo, old.stamp) == (track.file, track.demo, track.stamp)
            and (old.excluded, old.utility, old.eligible, old.utility_saved) == fields
        ):
            tracks.append(old)  # the same file version: the same fields
        elif excluded or utility is not None:
            tracks.append(
                replace(
                    track,
                    excluded=excluded,
                    utility=utility,
                    eligible=eligible,
                    utility_saved=kept,
                )
            )
        else:
            tracks.append(track)
    return tuple(tracks), reason, ranks


def _who(track: ReplayTrack) -> str:
    """A take as the ★ line names it: who and when, as the table does (escaped later)."""
    return track_who_when(track)


def plural(n: int, noun: str) -> str:
    """``1 demo``, ``2 demos``, ``0 demos``."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def _order(track: ReplayTrack) -> tuple[int, bool, float]:
    """Usable demos first (those that may be the best first, then by Ũ), flagged, excluded."""
    group = 0 if track.usable else (1 if not track.excluded else 2)
    return group, not track.eligible, -(track.utility if track.utility is not None else -1.0)


def ranked(library: TaskLibrary, limit: int, order: RowOrder = "rank") -> list[ReplayTrack]:
    """The first `limit` raw demos in the table's order (``sorted(...)[:limit]`` without
    sorting them all): usable ones, then flagged, then excluded; the usable ones by rank (those
    that follow the guide about as closely as any first, each group by Ũ: ``bt score``'s
    ranks) or, with `order` ``"utility"``, by Ũ alone."""
    return [library.raw[i] for i in _ranked_indices(library, limit, order)]


def _ranked_indices(library: TaskLibrary, limit: int, order: RowOrder) -> list[int]:
    """:func:`ranked`, as indices into ``library.raw``."""
    key = _order if order == "rank" else _by_utility
    raw = library.raw
    return heapq.nsmallest(limit, range(len(raw)), key=lambda i: (key(raw[i]), i))


def _by_utility(track: ReplayTrack) -> tuple[int, float]:
    """Usable demos first, by Ũ; flagged; excluded."""
    group = 0 if track.usable else (1 if not track.excluded else 2)
    return group, -(track.utility if track.utility is not None else -1.0)


RELATIVE_NOTE = (
    "Ũ is relative to the task's current usable takes: it moves when takes are saved, excluded "
    "or restored (*was*: its Ũ when saved). # is the rank that `bt score` and **Clean** use."
)
"""The caption under the table (docs/teleop.md, "Ũ is relative to the set")."""


def library_markdown(library: TaskLibrary, max_rows: int = 12, order: RowOrder = "rank") -> str:
    """A Markdown table of the task's raw demos, and a line on the cleaned ones.

    Rows: usable demos by rank (`order` ``"rank"``: ★ first) or by Ũ (``"utility"``), then
    flagged ones, then excluded ones. Marks: ★ the best demo, ⚠ a flagged demo or one with
    warnings (both on the best demo when it has a warning), ⊘ excluded. A Ũ that moved since
    its take was saved reads "0.36 (was 0.56)". A take whose only flag is the remark
    ``off_guide`` is usable, its note "off the guide: kept and cleaned". Under the table: that
    Ũ is relative to the set, and why the ★ take is the best when it is not the highest Ũ.
    Every name and note is escaped (:func:`bt_teleop.takes.escape.markdown_text`).
    """
    if not library.raw:
        return f"No {library.task} recordings yet: press **Record**."
    best = library.best
    rows = ["| | # | who, when | θ, ρ | s | Ũ | note |", "|---|---|---|---|---|---|---|"]
    for index in _ranked_indices(library, max_rows, order):
        track = library.raw[index]
        mark = ("★" if track is best else "") + ("⚠" if track.flags or track.warnings else "")
        if track.excluded:
            mark = "⊘"
        pref = "?" if math.isnan(track.theta_deg) else f"{track.theta_deg:.0f}°, {track.rho:.2f}"
        # An en space before Ũ: the page draws the table's cells unpadded ("3.0 s0.50" without it)
        score = "\u2002" + _utility_text(track)
        unscored = ["no loop found"] if track.usable and track.utility is None else []
        note = ", ".join(
            (["excluded"] if track.excluded else [])
            + list(track.flags)
            + [_WARNING_TEXT.get(w, w) for w in track.warnings]
            + unscored
        )
        # who and when as the pickers and Rerun name them; the time on a line of its own
        who = who_when(markdown_text(track.demonstrator, 24), track_when(track), sep="<br>")
        note = markdown_text(note.replace("_", " "), 160)  # flags are a file's text, as names
        rank = library.ranks[index] if index < len(library.ranks) else 0
        number = str(rank) if rank else ""
        rows.append(
            f"| {mark} | {number} | {who} | {pref} | {track.duration_s:.1f} | {score} | {note} |"
        )
    n_usable = sum(t.usable for t in library.raw)
    head = f"{plural(len(library.raw), 'demo')} of {library.task}, {n_usable} usable"
    by = "by rank" if order == "rank" else "by Ũ"
    lines = [f"{head}, {by} (★ best, ⚠ flagged or worth a look, ⊘ excluded)", "", *rows]
    if len(library.raw) > max_rows:
        lines.append(f"… and {len(library.raw) - max_rows} more")
    lines += ["", RELATIVE_NOTE]
    if library.best_reason:
        lines += ["", "★ " + markdown_text(library.best_reason, 400)]
    if library.cleaned and library.cleaned_stale:
        lines += ["", "The recordings changed since the last Clean: press **Clean** again."]
    elif library.cleaned:
        lines += ["", cleaned_line(library.cleaned)]
    return "\n".join(lines)


def _utility_text(track: ReplayTrack) -> str:
    """``0.36``, ``0.36 (was 0.56)`` when it moved since its take was saved, or ``–``."""
    if track.utility is None:
        return "–"
    now = f"{track.utility:.2f}"
    saved = track.utility_saved
    return now if saved is None or f"{saved:.2f}" == now else f"{now} (was {saved:.2f})"


def cleaned_line(cleaned: tuple[ReplayTrack, ...]) -> str:
    """The line on the last Clean: how many demos, their mean Ũ (on the raw takes' scale) and
    how far cleaning moved them from their raw samples (mean over the demos, and the largest)."""
    scores = [t.utility for t in cleaned if t.utility is not None]
    mean = f": mean Ũ {np.mean(scores):.2f}" if scores else ""
    moved = [t.moved_mm for t in cleaned if t.moved_mm is not None]
    shift = ""
    if moved:
        shift = (
            f"; moved {np.mean([m[0] for m in moved]):.1f} mm from their raw samples on "
            f"average (at most {max(m[1] for m in moved):.1f} mm)"
        )
    return f"Cleaned: {plural(len(cleaned), 'demo')}{mean}{shift}"
