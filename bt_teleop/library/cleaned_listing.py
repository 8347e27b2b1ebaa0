"""Listing a task's cleaned file without reading its samples.

After each Clean every tab lists the task's cleaned file (``.cleaned/<task>.cleaned.hdf5``): one
demo per usable take, so it grows with the task. Reading it with
:func:`~bt_pipeline.data.recording.read_recording` loads every demo's samples only to keep a
name, a duration and a score of each, and on the app's reader thread that left the process's
RSS at the high-water mark of the largest such read (+21 MiB for a 400-demo file, not given
back by ``malloc_trim``: ``benchmarks/soak/bench_read_high_water.py``, docs/security.md). The
listing needs, per demo, its attributes and its first and last timestamp; this module reads
only those, with the same checks of what it reads (format, version, task, demo names and count,
sample counts, attribute types), and builds the same tracks as from the full read
(``tests/teleop/library/test_cleaned_listing.py``). A demo is read in full, and fully checked,
when it is played (:mod:`bt_teleop.library.track_samples`).
"""

from __future__ import annotations

import math
from pathlib import Path

import h5py
import numpy as np

from bt_pipeline.data.h5_read import float_attr, int_attr, read_extra_attrs, str_attr
from bt_pipeline.data.limits import DEFAULT_LIMITS, check_demo_count, check_sample_count
from bt_pipeline.data.recording import data_group
from bt_pipeline.data.validate import DEMO_ATTRS, sorted_demo_names
from bt_pipeline.exceptions import RecordingError
from bt_teleop.library.tracks import FileStamp, FileTracks, ReplayTrack, cleaned_key

__all__ = ["moved_from_attrs", "read_cleaned_listing"]


def read_cleaned_listing(path: Path, stamp: FileStamp) -> FileTracks:
    """The tracks of the cleaned file `path` (version `stamp`), its samples left on disk.

    Raises:
        RecordingError: The file cannot be read, breaks format v1 where this reads it, or
            holds more demos or samples than the read limits allow.
    """
    where = str(path)
    try:
        with h5py.File(path, "r") as file:
            return _listing(file, path, stamp)
    except (OSError, RuntimeError, KeyError) as exc:
        raise RecordingError(
            f"{where}: cannot read the file; it is truncated or corrupt (h5py: {exc})"
        ) from exc
    except (ValueError, TypeError, OverflowError, IndexError) as exc:
        raise RecordingError(
            f"{where}: cannot read the file; it holds data of an unexpected kind "
            f"({type(exc).__name__}: {str(exc)[:200]})"
        ) from exc


def _listing(file: h5py.File, path: Path, stamp: FileStamp) -> FileTracks:
    where = str(path)
    data, task = data_group(file, where)
    check_demo_count(len(data), where, DEFAULT_LIMITS)
    tracks = []
    for name in sorted_demo_names(list(data.keys()), where):
        group = data[name]
        demo_label = f"{where}: {name}"
        if not isinstance(group, h5py.Group):
            raise RecordingError(f"{demo_label} is a dataset; expected a group")
        attrs = group.attrs
        num_samples = int_attr(attrs, "num_samples", demo_label)
        check_sample_count(num_samples, demo_label, DEFAULT_LIMITS)
        first, last = _time_span(group, num_samples, demo_label)
        extra = read_extra_attrs(attrs, DEMO_ATTRS)
        key, source = cleaned_key(name, extra.get("cleaned_from"))
        utility = extra.get("utility_cleaned")
        moved = extra.get("moved_mean"), extra.get("moved_max")
        tracks.append(
            ReplayTrack(
                key=key,
                kind="cleaned",
                file=path,
                demo=name,
                stamp=stamp,
                num_samples=num_samples,
                duration_s=float(last - first),
                demonstrator=str_attr(attrs, "demonstrator", demo_label),
                theta_deg=float_attr(attrs, "theta_deg", demo_label),
                rho=float_attr(attrs, "rho", demo_label),
                utility=None if utility is None else float(utility),
                source=source,
                moved_mm=moved_from_attrs(*moved),
            )
        )
    return FileTracks(path, stamp, task, tuple(tracks))


def moved_from_attrs(mean: object, most: object) -> tuple[float, float] | None:
    """A cleaned demo's attrs ``moved_mean`` and ``moved_max`` [m] as (mean, max) [mm]; None
    when the file (written before they were) lacks them or they are not finite numbers."""
    if not isinstance(mean, int | float) or not isinstance(most, int | float):
        return None
    values = (1e3 * float(mean), 1e3 * float(most))
    return values if all(math.isfinite(v) for v in values) else None


def _time_span(group: h5py.Group, num_samples: int, label: str) -> tuple[np.float64, np.float64]:
    """The first and last timestamp of a demo of `num_samples` samples (two values read)."""
    times = group.get("timestamps")
    if not isinstance(times, h5py.Dataset):
        raise RecordingError(f"{label}: missing dataset timestamps")
    if times.shape != (num_samples,) or num_samples < 1:
        raise RecordingError(
            f"{label}: timestamps has shape {times.shape}; expected ({num_samples},) as attr "
            "num_samples says"
        )
    first, last = np.float64(times[0]), np.float64(times[num_samples - 1])
    if not (math.isfinite(first) and math.isfinite(last)):
        raise RecordingError(f"{label}: timestamps are not finite")
    return first, last
