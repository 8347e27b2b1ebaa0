"""The demos of one recording file as the page lists them: small records, no samples.

A crowdsourcing app collects thousands of takes, and every tab lists every take of its task, so
what the app keeps per take must stay small. :func:`read_file_tracks` reads a file once (fully
checked by :func:`~bt_pipeline.data.recording.read_recording`), keeps what the table and the
pickers show and what scoring needs, and drops the samples::

    <task>/<take>.hdf5 --read_recording--> Recording (all arrays)
        --> FileTracks: per demo a ReplayTrack (key, who, θ, ρ, duration, flags, warnings,
                        file identity) and its ranking inputs: I, L1-L3 (paper Eqs. 1,
                        4-6) on its periodic part and its guide misfit, as `bt clean` ranks
        (the Recording is dropped: ~1 KiB kept per take instead of its arrays)

A track's samples are read from its file again when it is played
(:mod:`bt_teleop.library.track_samples`), and only if the file is still the one listed: its
:class:`FileStamp` (size, modification time, inode) is kept for that.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, NamedTuple

from bt_pipeline.data.records import INFO_FLAGS, DemoRecord, Recording
from bt_pipeline.data.tasks import Task
from bt_pipeline.exceptions import BtError, RecordingError

if TYPE_CHECKING:
    from bt_pipeline.clean.selection import TakeScore
    from bt_pipeline.data.demo import Demo

__all__ = [
    "CLAMPED_WARNING_SHARE",
    "FileStamp",
    "FileTracks",
    "ReplayTrack",
    "TrackKind",
    "cleaned_key",
    "file_stamp",
    "read_file_tracks",
]

TrackKind = Literal["raw", "cleaned"]
LOGGER = logging.getLogger("bt.teleop")
CLAMPED_WARNING_SHARE = 0.05
"""A demo with more than this share of samples clamped to the workspace gets a ⚠ warning."""


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


def read_file_tracks(path: Path, kind: TrackKind) -> FileTracks:
    """Read `path` and keep its demos' tracks (and, for raw demos, their ranking inputs); a cleaned
    file's samples are not read (:mod:`bt_teleop.library.cleaned_listing`).

    Args:
        path: A raw take file, or a task's cleaned file.
        kind: Which of the two.

    Raises:
        RecordingError: The file cannot be read, breaks format v1, or kept changing while it
            was read.
    """
    from bt_pipeline.data.recording import read_recording
    from bt_teleop.library.cleaned_listing import read_cleaned_listing

    for _attempt in range(3):
        stamp = file_stamp(path)
        if kind == "cleaned":  # its attributes only: the task's every demo, samples not read
            tracks = read_cleaned_listing(path, stamp)
            if file_stamp(path) == stamp:
                return tracks
            continue
        recording = read_recording(path)
        if file_stamp(path) == stamp:  # not replaced while it was read
            return _raw_file(recording, path, stamp)
    raise RecordingError(f"{path}: the file kept changing while it was read; try again later")


def _raw_file(recording: Recording, path: Path, stamp: FileStamp) -> FileTracks:
    from bt_pipeline.data.demo import demos_from_recording

    several = len(recording.demos) > 1
    tracks: list[ReplayTrack] = []
    metrics: list[TakeScore | None] = []
    try:
        demos: list[Demo | None] = list(demos_from_recording(recording))
    except BtError as exc:  # listed all the same, unscored
        LOGGER.warning("cannot score %s: %s", path, exc)
        demos = [None] * len(recording.demos)
    for (name, record), demo in zip(recording.demos.items(), demos, strict=True):
        key = f"raw · {path.stem}" + (f" · {name}" if several else "")
        meta = record.ep_meta
        warnings = []
        clamped = meta.get("clamped_samples", 0)
        if isinstance(clamped, int) and clamped > CLAMPED_WARNING_SHARE * record.num_samples:
            warnings.append("clamped")
        if isinstance(meta.get("ik_failures"), int) and meta["ik_failures"] > 0:
            warnings.append("ik_failures")
        warnings += [flag for flag in record.flags if flag in INFO_FLAGS]  # off_guide: kept
        track = _track(
            key,
            "raw",
            path,
            name,
            record,
            stamp,
            flags=tuple(flag for flag in record.flags if flag not in INFO_FLAGS),
            session=str(meta.get("session", "")),
            warnings=tuple(warnings),
        )
        tracks.append(track)
        metrics.append(None if demo is None or track.flags else _score_or_none(demo, name))
    return FileTracks(path, stamp, recording.task, tuple(tracks), tuple(metrics))


def _score_or_none(demo: Demo, name: str) -> TakeScore | None:
    """`demo`'s part of its task's ranking, as ``bt clean`` reads it (its periodic part), or
    None (logged) when it has none (no loop, no motion) or the numerics fail."""
    from bt_pipeline.clean.selection import take_score
    from bt_pipeline.data.skipping import NUMERIC_ERRORS

    try:
        return take_score(demo)
    except (BtError, *NUMERIC_ERRORS) as exc:
        LOGGER.warning("cannot score %s: %s: %s", demo.file, name, exc)
        return None


def cleaned_key(name: str, cleaned_from: object) -> tuple[str, str]:
    """(key, source key) of cleaned demo `name` whose attr ``cleaned_from`` is `cleaned_from`
    (``<raw file>:<demo>``; the demo's own name when absent)."""
    origin = str(name if cleaned_from is None else cleaned_from)
    file, _, demo = origin.rpartition(":")
    label = Path(file).stem if file else name
    if demo and demo != "demo_0":
        label = f"{label} · {demo}"
    return f"cleaned · {label}", f"raw · {label}"


def _cleaned_tracks(recording: Recording, stamp: FileStamp) -> tuple[ReplayTrack, ...]:
    """The tracks of a cleaned file read in full (the reference that
    :func:`bt_teleop.library.cleaned_listing.read_cleaned_listing` is tested against)."""
    from bt_teleop.library.cleaned_listing import moved_from_attrs

    assert recording.path is not None
    tracks = []
    for name, record in recording.demos.items():
        key, source = cleaned_key(name, record.attrs.get("cleaned_from"))
        utility = record.attrs.get("utility_cleaned")
        utility = None if utility is None else float(utility)
        moved = moved_from_attrs(record.attrs.get("moved_mean"), record.attrs.get("moved_max"))
        tracks.append(
            _track(
                key,
                "cleaned",
                recording.path,
                name,
                record,
                stamp,
                utility=utility,
                source=source,
                moved_mm=moved,
            )
        )
    return tuple(tracks)


def _track(
    key: str,
    kind: TrackKind,
    file: Path,
    demo: str,
    record: DemoRecord,
    stamp: FileStamp,
    **extra: Any,
) -> ReplayTrack:
    """A track of `record` (demo `demo` of `file`); `extra` sets the other fields."""
    return ReplayTrack(
        key=key,
        kind=kind,
        file=file,
        demo=demo,
        stamp=stamp,
        num_samples=record.num_samples,
        duration_s=float(record.timestamps[-1] - record.timestamps[0]),
        demonstrator=record.demonstrator,
        theta_deg=float(record.theta_deg),
        rho=float(record.rho),
        **extra,
    )
