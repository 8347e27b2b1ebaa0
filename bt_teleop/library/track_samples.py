"""A listed demo's samples, read from its file when it is played.

The library (:mod:`bt_teleop.library.listing`) lists tracks without their samples; Play reads the
one
track it needs (and, for a cleaned demo, its raw source, drawn beside it)::

    Play "raw · take_7" --TrackReader.read(track)--> stat(file) == track.stamp?
        no file           -> RecordingError "… is gone since the list was built"
        another version   -> RecordingError "… changed since the list was built"
        same version      -> LRU cache (the last `max_tracks` tracks played) or read
                             /data/<demo>/obs/ee_pos and /timestamps only -> TrackSamples

The whole file was checked when it was listed (:func:`bt_teleop.library.reading.read_file_tracks`),
and its stamp (size, modification time, inode) shows it is still that file; the two datasets read
are checked again (shapes, finite values, increasing times) all the same. The cache is
:func:`functools.lru_cache` keyed by (file, demo, stamp), so it never serves another version.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from bt_pipeline.data.h5_read import read_dataset
from bt_pipeline.data.limits import DEFAULT_LIMITS
from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import RecordingError
from bt_teleop.library.tracks import FileStamp, ReplayTrack, file_stamp

__all__ = ["DEFAULT_MAX_TRACKS", "TrackReader", "TrackSamples"]

DEFAULT_MAX_TRACKS = 16
"""Tracks whose samples the app keeps after playing them (shared by every tab)."""


@dataclass(frozen=True, eq=False)  # holds arrays
class TrackSamples:
    """The samples of one track."""

    positions: FloatArray
    """End-effector path in the world frame, shape (T, 3), in [m]."""
    times_s: FloatArray
    """Timestamps from 0, strictly increasing, shape (T,), in [s]."""

    @property
    def duration_s(self) -> float:
        """Length [s]."""
        return float(self.times_s[-1])

    def target_at(self, t_s: float) -> FloatArray:
        """Linearly interpolated position at `t_s` [s] (held outside the track), shape (3,)."""
        return np.array([np.interp(t_s, self.times_s, self.positions[:, j]) for j in range(3)])


class TrackReader:
    """Reads tracks' samples for Play, keeping the last few (thread-safe)."""

    def __init__(self, max_tracks: int = DEFAULT_MAX_TRACKS) -> None:
        """Keep the samples of at most `max_tracks` tracks (least recently played dropped)."""
        self._cached = functools.lru_cache(maxsize=max_tracks)(_read_samples)

    def read(self, track: ReplayTrack) -> TrackSamples:
        """`track`'s samples, from the version of its file it was listed from.

        Raises:
            RecordingError: The file is gone, is another version now, or cannot be read; the
                message names the track and the file.
        """
        try:
            stamp = file_stamp(track.file)
        except RecordingError:
            raise RecordingError(
                f"cannot play {track.key}: its file {track.file.name} is gone since the list "
                "was built"
            ) from None
        if stamp != track.stamp:
            raise RecordingError(
                f"cannot play {track.key}: its file {track.file.name} changed since the list "
                "was built; play it again once the list is refreshed"
            )
        return self._cached(track.file, track.demo, stamp)

    @property
    def cached(self) -> int:
        """Tracks whose samples are held now."""
        return self._cached.cache_info().currsize

    def clear(self) -> None:
        """Drop every held track."""
        self._cached.cache_clear()


def _read_samples(path: Path, demo: str, stamp: FileStamp) -> TrackSamples:
    """The end-effector path and times of demo `demo` of `path`, which must have `stamp`."""
    label = f"{path}: {demo}"
    rows = DEFAULT_LIMITS.max_samples
    try:
        with h5py.File(path, "r") as file:
            group = file.get(f"data/{demo}")
            if not isinstance(group, h5py.Group):
                raise RecordingError(f"{label}: no such demo in the file")
            positions = np.asarray(read_dataset(group, "obs/ee_pos", label, rows), np.float64)
            times = np.asarray(read_dataset(group, "timestamps", label, rows), np.float64)
    except (OSError, ValueError, TypeError, KeyError) as exc:
        raise RecordingError(f"{label}: cannot read the file (h5py: {exc})") from None
    if file_stamp(path) != stamp:
        raise RecordingError(f"{label}: the file changed while it was read; play it again")
    n = len(times)
    if positions.shape != (n, 3) or times.shape != (n,) or n < 2:
        raise RecordingError(
            f"{label}: obs/ee_pos has shape {positions.shape} and timestamps {times.shape}; "
            "expected (T, 3) and (T,) with T ≥ 2"
        )
    steps = np.diff(times)
    if not (np.isfinite(positions).all() and np.isfinite(times).all() and (steps > 0).all()):
        raise RecordingError(f"{label}: non-finite samples or times that do not increase")
    times = times - times[0]
    for array in (positions, times):
        array.flags.writeable = False  # shared by every tab that plays it
    return TrackSamples(positions, times)
