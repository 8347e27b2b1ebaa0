"""The demos of one recording file as the page lists them: small records, no samples.

A crowdsourcing app collects thousands of takes, and every tab lists every take of its task, so
what the app keeps per take must stay small: per file a :class:`FileTracks`, per demo a
:class:`ReplayTrack` (about 1 KiB a take). They are read by :mod:`bt_teleop.library.reading`
(a take file) and :mod:`bt_teleop.library.cleaned_listing` (a task's cleaned file).

A track's samples are read from its file again when it is played
(:mod:`bt_teleop.library.track_samples`), and only if the file is still the one listed: its
:class:`FileStamp` (size, modification time, inode) is kept for that.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Literal, NamedTuple

from bt_pipeline.data.tasks import Task
from bt_pipeline.exceptions import RecordingError
from bt_pipeline.viz.demo_style import take_time, who_when
from bt_teleop.takes.escape import display_text

if TYPE_CHECKING:
    from bt_pipeline.clean.selection import TakeScore

__all__ = [
    "FileStamp",
    "FileTracks",
    "ReplayTrack",
    "TrackKind",
    "cleaned_key",
    "file_stamp",
    "track_when",
    "track_who_when",
]

TrackKind = Literal["raw", "cleaned"]


class FileStamp(NamedTuple):
    """Which version of a file: a file replaced or rewritten gets another stamp."""

    size: int
    """Size [bytes]."""
    mtime_ns: int
    """Last modification [ns since the epoch]."""
    inode: int
    """Inode number (an atomic replace by rename gives a new one)."""


def file_stamp(path: Path) -> FileStamp:
    """`path`'s current stamp.

    Raises:
        RecordingError: The file is gone or cannot be examined.
    """
    try:
        stat = os.stat(path)
    except FileNotFoundError:
        raise RecordingError(f"{path}: the file is gone") from None
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read it ({exc.strerror})") from exc
    return FileStamp(stat.st_size, stat.st_mtime_ns, stat.st_ino)


@dataclass(frozen=True, slots=True)  # one per take in every library: no __dict__
class ReplayTrack:
    """One replayable demo as listed: what the page shows, and where its samples are."""

    key: str
    """Unique label in the task's library (what the Replay picker shows)."""
    kind: TrackKind
    """raw or cleaned."""
    file: Path
    """The file it was read from."""
    demo: str
    """Its name in that file."""
    stamp: FileStamp
    """The version of `file` it was listed from (its samples are read only from that one)."""
    num_samples: int
    """Samples T."""
    duration_s: float
    """Length [s] (last timestamp minus the first)."""
    demonstrator: str
    """Who recorded it (as typed: escape it before showing it)."""
    theta_deg: float
    """θ [deg] (NaN when unknown)."""
    rho: float
    """ρ (NaN when unknown)."""
    utility: float | None = None
    """Ũ (raw: among the task's usable raw demos; cleaned: after cleaning), None if not scored."""
    eligible: bool = True
    """A raw demo that may be the best: it follows the guide about as closely as any usable
    demo (the shape gate, :mod:`bt_pipeline.clean.shape_gate`)."""
    flags: tuple[str, ...] = ()
    """Failed take checks (demo attr ``flags`` but its remarks, ``INFO_FLAGS``;
    ``closed_mid_take`` for ep_meta incomplete)."""
    excluded: bool = False
    """Its file is excluded by moderation (a sidecar; the file is untouched)."""
    session: str = ""
    """The app session that recorded it (ep_meta ``session``; empty when unknown)."""
    warnings: tuple[str, ...] = ()
    """Things worth a look that do not make it unusable (e.g. ``clamped``, ``ik_failures``, and
    the take checks' remark ``off_guide``)."""
    source: str = ""
    """For a cleaned demo, the key of the raw demo it was cleaned from (empty for raw ones)."""
    utility_saved: float | None = None
    """The Ũ it read when first listed after its save (:mod:`bt_teleop.takes.saved_utility`): the
    page marks a Ũ that has moved since ("0.36 (was 0.56)")."""
    moved_mm: tuple[float, float] | None = None
    """A cleaned demo: how far cleaning moved it from its raw samples, (mean, max) [mm]."""

    @property
    def usable(self) -> bool:
        """Neither flagged nor excluded: scored, rankable, cleaned."""
        return not self.flags and not self.excluded


def track_when(track: ReplayTrack, saved_ns: int | None = None) -> datetime:
    """When `track`'s take was recorded (UTC), as the page and Rerun name it: the time in its
    file's name (the app's ``<who>_<UTC time>_<hex>``; a cleaned demo: its raw take's), else
    `saved_ns` [ns since the epoch], else its file's modification time."""
    stem = track.file.stem if track.kind == "raw" else track.source.removeprefix("raw · ")
    when = take_time(stem.split(" · ")[0])
    if when is None:
        when_ns = track.stamp.mtime_ns if saved_ns is None else saved_ns
        when = datetime.fromtimestamp(when_ns / 1e9, UTC)
    return when


def track_who_when(track: ReplayTrack, saved_ns: int | None = None) -> str:
    """Who recorded `track` and when, as plain text (the name cut to 24 characters,
    :func:`bt_teleop.takes.escape.display_text`), as the page shows it (the pickers, the ★
    line) and Rerun names it (:func:`bt_pipeline.viz.demo_style.who_when`): ``Ada Lovelace
    12-06 12:03:15``. `saved_ns`: see :func:`track_when`."""
    return who_when(display_text(track.demonstrator, 24), track_when(track, saved_ns))


@dataclass(frozen=True, slots=True)  # one per take file in the app: no __dict__
class FileTracks:
    """What the app keeps of one recording file (no samples)."""

    path: Path
    """The file."""
    stamp: FileStamp
    """The version of the file read."""
    task: Task
    """The task of its demos, as the file says (the library keeps files of its own task only)."""
    tracks: tuple[ReplayTrack, ...]
    """Its demos, in file order (``utility`` and ``excluded`` unset: they depend on the task's
    other files and on the moderation sidecar, so the library sets them at each load)."""
    metrics: tuple[TakeScore | None, ...] = ()
    """What each raw demo without flags brings to the task's ranking: its metrics on its
    periodic part and its guide misfit (:func:`bt_pipeline.clean.selection.take_score`; None:
    flagged, or they could not be computed); empty for a cleaned file."""


def cleaned_key(name: str, cleaned_from: object) -> tuple[str, str]:
    """(key, source key) of cleaned demo `name` whose attr ``cleaned_from`` is `cleaned_from`
    (``<raw file>:<demo>``; the demo's own name when absent)."""
    origin = str(name if cleaned_from is None else cleaned_from)
    file, _, demo = origin.rpartition(":")
    label = Path(file).stem if file else name
    if demo and demo != "demo_0":
        label = f"{label} · {demo}"
    return f"cleaned · {label}", f"raw · {label}"
