"""Reading one recording file into the records the page lists (:mod:`bt_teleop.library.tracks`).

:func:`read_file_tracks` reads a take file once (fully checked by
:func:`~bt_pipeline.data.recording.read_recording`), keeps what the table and the pickers show
and what scoring needs, and drops the samples::

    <task>/<take>.hdf5 --read_recording--> Recording (all arrays)
        --> FileTracks: per demo a ReplayTrack (key, who, θ, ρ, duration, flags, warnings,
                        file identity) and its ranking inputs: I, L1-L3 (paper Eqs. 1,
                        4-6) on its periodic part and its guide misfit, as `bt clean` ranks
        (the Recording is dropped: ~1 KiB kept per take instead of its arrays)

A task's cleaned file is listed from its attributes, its samples left on disk
(:mod:`bt_teleop.library.cleaned_listing`). In the app this runs in the reader child
(:mod:`bt_teleop.library.reader_process`); the scoring code is imported at the first read.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bt_pipeline.data.records import INFO_FLAGS, DemoRecord, Recording
from bt_pipeline.exceptions import BtError, RecordingError
from bt_teleop.library.tracks import (
    FileStamp,
    FileTracks,
    ReplayTrack,
    TrackKind,
    cleaned_key,
    file_stamp,
)

if TYPE_CHECKING:
    from bt_pipeline.clean.selection import TakeScore
    from bt_pipeline.data.demo import Demo

__all__ = ["CLAMPED_WARNING_SHARE", "read_file_tracks"]

LOGGER = logging.getLogger("bt.teleop")
CLAMPED_WARNING_SHARE = 0.05
"""A demo with more than this share of samples clamped to the workspace gets a ⚠ warning."""


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
