"""Read and write recordings in format v1 (HDF5, robomimic layout; ``docs/recording-format.md``).

Reading opens a file read-only and turns every problem into one
:class:`~bt_pipeline.exceptions.RecordingError` that names the file, the demo and what would be
valid. Writing checks the recording first, then writes the whole file to a hidden temporary file
beside the destination, fsyncs it and renames it into place, so a crash leaves either the old
state or the complete new file at the destination, never a half-written one::

    Recording --check--> .<name>.tmp-<pid>-<hex> --flush+fsync--> rename --> <name> (+ fsync dir)
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from bt_pipeline.data.atomic import (
    exists_message,
    fsync_path,
    publish_atomic,
    remove_stale_temps,
    temp_name,
)
from bt_pipeline.data.h5_read import (
    decode,
    float_attr,
    int_attr,
    json_attr,
    read_attr,
    read_dataset,
    read_extra_attrs,
    str_attr,
)
from bt_pipeline.data.limits import (
    DEFAULT_LIMITS,
    ReadLimits,
    check_demo_count,
    check_demo_magnitudes,
    check_plane_origin,
    check_sample_count,
)
from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.records import DemoRecord, Recording
from bt_pipeline.data.tasks import Task, parse_task
from bt_pipeline.data.validate import (
    DATA_ATTRS,
    DEMO_ATTRS,
    FORMAT,
    FORMAT_VERSION,
    KNOWN_OBS,
    OPTIONAL_DATASETS,
    SUPPORTED_VERSIONS,
    check_env_args,
    check_plane,
    check_recording,
    parse_source,
    sorted_demo_names,
)
from bt_pipeline.exceptions import RecordingError, UnknownTaskError

LOGGER = logging.getLogger("bt")
DEFAULT_ENV_TYPE = 0
"""robomimic env ``type`` written when a recording has no ``env_args``: 0 is no robomimic env
class (robomimic's own are 1 robosuite, 2 gym, 3 iGibson); bt's scenes are its own."""


def read_recording(path: str | Path, limits: ReadLimits | None = None) -> Recording:
    """Read and check one format-v1 file; the file is opened read-only and never modified.

    Args:
        path: The file.
        limits: Magnitude and size bounds (:class:`~bt_pipeline.data.limits.ReadLimits`);
            the defaults when None.

    Raises:
        RecordingError: The file is missing, not HDF5, truncated, breaks format v1, or holds a
            value beyond `limits`. The message names the file, the demo and the dataset or attr
            at fault.
    """
    path = Path(path)
    where = str(path)
    if not path.exists():
        raise RecordingError(f"{where}: no such file")
    if path.is_dir():
        raise RecordingError(f"{where}: is a directory; expected a recording file (*.hdf5)")
    if not os.access(path, os.R_OK):
        raise RecordingError(f"{where}: permission denied")
    try:
        if not h5py.is_hdf5(path):
            raise RecordingError(
                f"{where}: not an HDF5 file ({path.stat().st_size} bytes without an HDF5 "
                "signature); recordings are HDF5 files in format v1"
            )
        with h5py.File(path, "r") as file:
            return _read_file(file, path, limits or DEFAULT_LIMITS)
    except (OSError, RuntimeError, KeyError) as exc:
        raise RecordingError(
            f"{where}: cannot read the file; it is truncated or corrupt (h5py: {exc})"
        ) from exc
    except (ValueError, TypeError, OverflowError) as exc:  # odd dtypes or shapes h5py accepts
        raise RecordingError(
            f"{where}: cannot read the file; it holds data of an unexpected kind "
            f"({type(exc).__name__}: {str(exc)[:200]})"
        ) from exc


def read_recordings(
    paths: Sequence[Path], strict: bool = True, limits: ReadLimits | None = None
) -> list[Recording]:
    """Read several files in order.

    Args:
        paths: Recording files, e.g. from :func:`expand_paths`.
        strict: Raise on the first bad file; otherwise log a warning on logger ``"bt"`` (stderr
            unless logging is configured otherwise) naming the file and the reason, and skip it.
        limits: Magnitude and size bounds; the defaults when None.

    Raises:
        RecordingError: A file cannot be read (strict only).
    """
    recordings = []
    for path in paths:
        try:
            recordings.append(read_recording(path, limits))
        except RecordingError as exc:
            if strict:
                raise
            LOGGER.warning("skipping %s", exc)
    return recordings


def write_recording(path: str | Path, recording: Recording, *, overwrite: bool = False) -> Path:
    """Check `recording` and write it atomically to `path`.

    The file is written to ``.<name>.tmp-<pid>-<hex>`` in the destination's folder, flushed,
    fsynced and renamed into place; the folder is then fsynced. On any exception (also
    KeyboardInterrupt) the temporary file is removed and the exception re-raised. A process killed
    with SIGKILL can leave only the hidden temporary file, which :func:`expand_paths` ignores.

    Args:
        path: Destination file (parent folders are created).
        recording: What to write; ``actions`` come from ``DemoRecord.resolved_actions()``.
        overwrite: Replace an existing file. By default an existing destination is an error:
            recorded data is never modified in place.

    Returns:
        `path`.

    Raises:
        RecordingError: The recording breaks format v1 (nothing is written), or the destination
            exists and `overwrite` is False.
    """
    path = Path(path)
    check_recording(recording, f"cannot write {path}")
    if path.is_dir():
        raise RecordingError(f"cannot write {path}: it is a directory")
    if path.exists() and not overwrite:
        raise RecordingError(exists_message(path))
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(path)
    tmp = temp_name(path)
    try:
        with h5py.File(tmp, "x") as file:
            _write_file(file, recording)
            file.flush()
        fsync_path(tmp, os.O_RDWR)
        publish_atomic(tmp, path, overwrite)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if os.name == "posix":  # a folder cannot be opened for fsync on Windows
        fsync_path(path.parent, os.O_RDONLY)
    return path


def data_group(file: h5py.File, where: str) -> tuple[h5py.Group, Task]:
    """The open file's ``/data`` group and its task, once its format, version and task are
    checked (every reader of format v1 starts here).

    Raises:
        RecordingError: No ``/data`` group, another format, an unsupported version or an
            invalid task name (any name :func:`~bt_pipeline.data.tasks.parse_task` accepts is
            read, with or without a built-in guide).
    """
    label = f"{where}: /data"
    data = file.get("data")
    if not isinstance(data, h5py.Group):
        raise RecordingError(f"{where}: missing group /data; not a bt recording (format v1)")
    attrs = data.attrs
    fmt = str_attr(attrs, "format", label)
    if fmt != FORMAT:
        raise RecordingError(f"{label}: attr format is {fmt!r}; expected {FORMAT!r}")
    version = int_attr(attrs, "format_version", label)
    if version not in SUPPORTED_VERSIONS:
        supported = ", ".join(str(v) for v in SUPPORTED_VERSIONS)
        raise RecordingError(
            f"{where}: format_version {version} is not supported; this bt reads format_version "
            f"{supported}"
        )
    try:
        task = parse_task(str_attr(attrs, "task", label))
    except UnknownTaskError as exc:
        raise RecordingError(f"{label}: attr task: {exc}") from None
    return data, task


def _read_file(file: h5py.File, path: Path, limits: ReadLimits) -> Recording:
    where = str(path)
    label = f"{where}: /data"
    data, task = data_group(file, where)
    attrs = data.attrs
    total = int_attr(attrs, "total", label)
    env_args = json_attr(attrs, "env_args", label)
    check_env_args(env_args, where)
    origin, axes = read_attr(attrs, "plane_origin", label), read_attr(attrs, "plane_axes", label)
    check_plane(origin, axes, where)
    check_plane_origin(np.asarray(origin), where, limits)
    check_demo_count(len(data), where, limits)
    names = sorted_demo_names(list(data.keys()), where)
    demos: dict[str, DemoRecord] = {}
    num_samples: dict[str, int] = {}
    for name in names:
        demos[name], num_samples[name] = _read_demo(data, name, f"{where}: {name}", limits)
    recording = Recording(
        task=task,
        plane=TaskPlane(origin=np.asarray(origin), axes=np.asarray(axes)),
        demos=demos,
        env_args=env_args,
        masks=_read_masks(file, where),
        attrs=read_extra_attrs(attrs, DATA_ATTRS),
        path=path,
    )
    # Extra attrs of other writers are kept as they are, even those bt could not write back.
    check_recording(recording, where, extra_attrs=False)
    for name, demo in demos.items():
        if num_samples[name] != demo.num_samples:
            raise RecordingError(
                f"{where}: {name}: attr num_samples is {num_samples[name]} but obs/ee_pos has "
                f"{demo.num_samples} rows"
            )
    if total != recording.total:
        raise RecordingError(
            f"{label}: attr total is {total} but the demos hold {recording.total} samples"
        )
    for name, demo in demos.items():
        check_demo_magnitudes(
            np.asarray(demo.ee_pos),
            np.asarray(demo.timestamps),
            demo.theta_deg,
            demo.rho,
            np.asarray(origin),
            f"{where}: {name}",
            limits,
        )
    return dataclasses.replace(
        recording, demos={name: _as_float64(demo) for name, demo in demos.items()}
    )


def _read_demo(
    data: h5py.Group, name: str, label: str, limits: ReadLimits
) -> tuple[DemoRecord, int]:
    """The raw (unchecked) demo ``name`` and its ``num_samples`` attr.

    Sizes are checked before any dataset is loaded, so a huge demo costs no memory.
    """
    group = data[name]
    if not isinstance(group, h5py.Group):
        raise RecordingError(f"{label} is a dataset; expected a group")
    attrs = group.attrs
    num_samples = int_attr(attrs, "num_samples", label)
    check_sample_count(num_samples, label, limits)
    rows = limits.max_samples
    ep_meta = json_attr(attrs, "ep_meta", label) if "ep_meta" in attrs else {}
    optional = {
        field: read_dataset(group, dataset, label, rows)
        for dataset, field, _ in OPTIONAL_DATASETS
        if dataset in group
    }
    demo = DemoRecord(
        ee_pos=read_dataset(group, "obs/ee_pos", label, rows),
        timestamps=read_dataset(group, "timestamps", label, rows),
        actions=read_dataset(group, "actions", label, rows),
        demonstrator=str_attr(attrs, "demonstrator", label),
        theta_deg=float_attr(attrs, "theta_deg", label),
        rho=float_attr(attrs, "rho", label),
        source=parse_source(str_attr(attrs, "source", label), label),
        created=str_attr(attrs, "created", label) if "created" in attrs else None,
        ep_meta=ep_meta,
        attrs=read_extra_attrs(attrs, DEMO_ATTRS),
        extra_obs=_read_extra_obs(group),
        **optional,
    )
    return demo, num_samples


def _read_extra_obs(group: h5py.Group) -> dict[str, np.ndarray]:
    """``obs/<key>`` datasets other than bt's own, as stored (checked with the demo)."""
    obs = group.get("obs")
    if not isinstance(obs, h5py.Group):
        return {}
    return {
        key: np.asarray(item[()])
        for key, item in obs.items()
        if key not in KNOWN_OBS and isinstance(item, h5py.Dataset)
    }


def _read_masks(file: h5py.File, where: str) -> dict[str, list[str]]:
    if "mask" not in file:
        return {}
    group = file["mask"]
    if not isinstance(group, h5py.Group):
        raise RecordingError(f"{where}: /mask is a dataset; expected a group of filter keys")
    masks: dict[str, list[str]] = {}
    for key, item in group.items():
        values = np.asarray(item[()]) if isinstance(item, h5py.Dataset) else None
        if values is None or values.ndim != 1 or values.dtype.kind not in "OSU":
            raise RecordingError(
                f"{where}: /mask/{key} must be a 1-D dataset of demo names as byte strings "
                '(np.array(names, dtype="S"))'
            )
        masks[key] = [decode(v) for v in values.tolist()]
    return masks


def _as_float64(demo: DemoRecord) -> DemoRecord:
    fields = ["ee_pos", "timestamps", "actions", *(field for _, field, _ in OPTIONAL_DATASETS)]
    return dataclasses.replace(
        demo,
        **{
            name: np.asarray(getattr(demo, name), dtype=np.float64)
            for name in fields
            if getattr(demo, name) is not None
        },
    )


def _write_file(file: h5py.File, recording: Recording) -> None:
    data = file.create_group("data")
    attrs = data.attrs
    attrs["format"] = FORMAT
    attrs["format_version"] = FORMAT_VERSION
    attrs["task"] = recording.task
    attrs["total"] = recording.total
    env_args = recording.env_args or {
        "env_name": f"bt_{recording.task}",
        "type": DEFAULT_ENV_TYPE,
        "env_kwargs": {"task": recording.task},
    }
    attrs["env_args"] = json.dumps(env_args)
    attrs["plane_origin"] = recording.plane.origin
    attrs["plane_axes"] = recording.plane.axes
    _write_extra_attrs(attrs, recording.attrs)
    for name in sorted_demo_names(list(recording.demos), str(file.filename)):
        demo = recording.demos[name]
        group = data.create_group(name)
        group.attrs["num_samples"] = demo.num_samples
        group.attrs["demonstrator"] = demo.demonstrator
        group.attrs["theta_deg"] = float(demo.theta_deg)
        group.attrs["rho"] = float(demo.rho)
        group.attrs["source"] = demo.source
        if demo.created is not None:
            group.attrs["created"] = demo.created
        if demo.ep_meta:
            group.attrs["ep_meta"] = json.dumps(demo.ep_meta)
        _write_extra_attrs(group.attrs, demo.attrs)
        _write_float(group, "obs/ee_pos", demo.ee_pos)
        _write_float(group, "actions", demo.resolved_actions())
        _write_float(group, "timestamps", demo.timestamps)
        for dataset, field, _ in OPTIONAL_DATASETS:
            value = getattr(demo, field)
            if value is not None:
                _write_float(group, dataset, value)
        for key, value in demo.extra_obs.items():
            group.create_dataset(f"obs/{key}", data=np.asarray(value))
    if recording.masks:
        masks = file.create_group("mask")
        for key, members in recording.masks.items():
            masks.create_dataset(key, data=np.array(members, dtype="S"))


def _write_float(group: h5py.Group, key: str, value: Any) -> None:
    group.create_dataset(key, data=np.asarray(value, dtype=np.float64))


def _write_extra_attrs(attrs: h5py.AttributeManager, extra: dict[str, Any]) -> None:
    for key, value in extra.items():
        if isinstance(value, list | tuple) and value and all(isinstance(v, str) for v in value):
            attrs[key] = np.array(value, dtype=h5py.string_dtype())
        elif isinstance(value, list | tuple):
            attrs[key] = np.asarray(value)
        else:
            attrs[key] = value
