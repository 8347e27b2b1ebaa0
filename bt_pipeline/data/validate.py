"""Checks of format v1 shared by the reader and the writer of recordings.

Every check raises one :class:`~bt_pipeline.exceptions.RecordingError` whose message starts with
`where` (the file, or ``cannot write <file>``) and names the demo, the dataset or the attr at
fault, what it holds and what would be valid. The layout is described in
``docs/recording-format.md``.
"""

from __future__ import annotations

import json
import math
import re
from datetime import datetime
from typing import Any, get_args

import numpy as np

from bt_pipeline.data.limits import check_index_digits, check_text
from bt_pipeline.data.records import MIN_SAMPLES, DemoRecord, Recording, Source
from bt_pipeline.data.tasks import parse_task
from bt_pipeline.exceptions import RecordingError, UnknownTaskError

FORMAT = "bt-demos"
"""Value of the ``/data`` attr ``format``."""
FORMAT_VERSION = 1
"""Value of the ``/data`` attr ``format_version`` this module writes."""
SUPPORTED_VERSIONS: tuple[int, ...] = (1,)
"""Format versions the reader accepts."""
SOURCES: tuple[Source, ...] = get_args(Source)
ENV_ARGS_KEYS = ("env_name", "type", "env_kwargs")
"""Keys robomimic expects in ``env_args``."""
DATA_ATTRS = frozenset(
    ("format", "format_version", "task", "total", "env_args", "plane_origin", "plane_axes")
)
"""``/data`` attrs with a meaning in format v1 (not free for ``Recording.attrs``)."""
DEMO_ATTRS = frozenset(
    ("num_samples", "demonstrator", "theta_deg", "rho", "source", "created", "ep_meta")
)
"""Demo attrs with a meaning in format v1 (not free for ``DemoRecord.attrs``)."""
KNOWN_OBS = frozenset({"ee_pos", "ee_quat", "joint_pos", "gripper"})
"""``obs/<key>`` datasets bt reads into named fields; any other is kept in ``extra_obs``."""
OPTIONAL_DATASETS: tuple[tuple[str, str, int | None], ...] = (
    ("obs/ee_quat", "ee_quat", 4),
    ("obs/joint_pos", "joint_pos", 7),
    ("obs/gripper", "gripper", 1),
    ("states", "states", None),
)
"""Optional per-demo datasets: (path in the demo group, DemoRecord field, columns or None)."""
MAX_ATTR_BYTES = 60_000
"""Largest numeric array attr (HDF5 keeps attrs in the object header, 64 KiB at most)."""

_DEMO_NAME = re.compile(r"demo_(\d+)")


def demo_index(name: str) -> int | None:
    """The integer k of a demo name ``demo_<k>``, or None when `name` is not of that form."""
    match = _DEMO_NAME.fullmatch(name)
    if match is None or len(match.group(1)) > 4000:  # int() refuses > 4300 digits
        return None
    return int(match.group(1))


def sorted_demo_names(names: list[str], where: str) -> list[str]:
    """Demo names sorted by their integer k, as robomimic's readers sort them.

    Raises:
        RecordingError: A name is not ``demo_<k>``, two names share one k, or there are none.
    """
    if not names:
        raise RecordingError(f"{where}: no demos under /data; at least one demo_<k> is needed")
    by_index: dict[int, str] = {}
    for name in names:
        match = _DEMO_NAME.fullmatch(name)
        if match:
            check_index_digits(match.group(1), name, where)
        k = demo_index(name)
        if k is None:
            raise RecordingError(
                f"{where}: {name!r} is not a valid demo name; demos are named demo_<k> with k a "
                "non-negative integer (demo_0, demo_1, ...)"
            )
        if k in by_index:
            raise RecordingError(f"{where}: {by_index[k]} and {name} have the same index {k}")
        by_index[k] = name
    return [by_index[k] for k in sorted(by_index)]


def check_plane(origin: Any, axes: Any, where: str) -> None:
    """Check the task plane attrs: origin (3,), axes (2, 3) orthonormal rows, all finite."""
    for key, value, shape in (("plane_origin", origin, (3,)), ("plane_axes", axes, (2, 3))):
        array = np.asarray(value)
        if array.dtype.kind not in "fiu" or array.shape != shape:
            raise RecordingError(
                f"{where}: /data: attr {key} has shape {array.shape} and dtype {array.dtype}; "
                f"expected shape {shape} of float64"
            )
        if not np.all(np.isfinite(array)):
            raise RecordingError(f"{where}: /data: attr {key} has NaN or infinite values")
    gram = np.asarray(axes, dtype=np.float64) @ np.asarray(axes, dtype=np.float64).T
    if not np.allclose(gram, np.eye(2), atol=1e-6):
        raise RecordingError(
            f"{where}: /data: attr plane_axes must hold two orthonormal rows (axes @ axes.T = I); "
            f"got {np.asarray(axes).tolist()}"
        )


def check_env_args(env_args: Any, where: str) -> None:
    """Check robomimic's ``env_args``: a dict with env_name (str), type (int), env_kwargs (dict)."""
    if not isinstance(env_args, dict):
        raise RecordingError(
            f"{where}: env_args must be a JSON object; got {type(env_args).__name__}"
        )
    missing = [key for key in ENV_ARGS_KEYS if key not in env_args]
    if missing:
        raise RecordingError(
            f"{where}: env_args lacks {', '.join(missing)}; robomimic needs "
            f"{', '.join(ENV_ARGS_KEYS)}"
        )
    name, env_type, kwargs = (env_args[key] for key in ENV_ARGS_KEYS)
    if not isinstance(name, str) or not _is_int(env_type) or not isinstance(kwargs, dict):
        raise RecordingError(
            f"{where}: env_args needs env_name a string, type an integer and env_kwargs an "
            f"object; got {type(name).__name__}, {type(env_type).__name__}, "
            f"{type(kwargs).__name__}"
        )
    _check_json(env_args, "env_args", where)


def parse_source(value: str, label: str) -> Source:
    """Return `value` as a :data:`Source`, or raise an error that lists the valid sources."""
    for source in SOURCES:
        if value == source:
            return source
    raise RecordingError(
        f"{label}: unknown source {value!r}; valid sources are {', '.join(SOURCES)}"
    )


def check_recording(recording: Recording, where: str, *, extra_attrs: bool = True) -> None:
    """Check a whole in-memory recording against format v1 (the writer's gate).

    Args:
        recording: The recording.
        where: Start of every message (the file, or ``cannot write <file>``).
        extra_attrs: Also check that the extra attrs can be written back.

    Raises:
        RecordingError: The first problem found, naming the demo and the field.
    """
    try:
        parse_task(recording.task)
    except UnknownTaskError as exc:
        raise RecordingError(f"{where}: task: {exc}") from None
    check_plane(recording.plane.origin, recording.plane.axes, where)
    if recording.env_args:
        check_env_args(recording.env_args, where)
    if extra_attrs:
        check_attrs(recording.attrs, DATA_ATTRS, f"{where}: /data")
    for name in sorted_demo_names(list(recording.demos), where):
        check_demo(recording.demos[name], f"{where}: {name}", extra_attrs=extra_attrs)
    for key, members in recording.masks.items():
        if not key or "/" in key or key in (".", ".."):
            raise RecordingError(f"{where}: invalid mask name {key!r}; use a plain name")
        for member in members:
            if member not in recording.demos:
                raise RecordingError(
                    f"{where}: mask {key!r} names {member!r}, which is not a demo of this file"
                )


def check_demo(demo: DemoRecord, label: str, *, extra_attrs: bool = True) -> None:
    """Check one demo: datasets (shape, dtype, finite, timestamps) and attrs.

    Args:
        demo: The demo, as built in memory or read raw from a file.
        label: ``<file>: demo_<k>``, the start of every message.
        extra_attrs: Also check that ``demo.attrs`` can be written back.
    """
    ee_pos = _check_dataset(demo.ee_pos, "obs/ee_pos", None, 3, label)
    n = ee_pos.shape[0]
    if n < MIN_SAMPLES:
        raise RecordingError(f"{label} has {n} samples; at least {MIN_SAMPLES} are needed")
    timestamps = _check_dataset(demo.timestamps, "timestamps", n, 0, label)
    steps = np.diff(timestamps)
    bad = np.flatnonzero(steps <= 0.0)
    if bad.size:
        i = int(bad[0]) + 1
        raise RecordingError(
            f"{label}: timestamps must be strictly increasing; timestamps[{i}] = "
            f"{timestamps[i]:.6g} s is not after timestamps[{i - 1}] = {timestamps[i - 1]:.6g} s"
        )
    if demo.actions is not None:
        actions = _check_dataset(demo.actions, "actions", n, 3, label)
        if np.any(actions[-1] != 0.0):
            raise RecordingError(
                f"{label}: the last row of actions must be 0 (forward difference, a_T = 0); "
                f"got {actions[-1].tolist()}"
            )
    for dataset, field_name, columns in OPTIONAL_DATASETS:
        value = getattr(demo, field_name)
        if value is not None:
            _check_dataset(value, dataset, n, columns, label)
    for key, value in demo.extra_obs.items():
        array = np.asarray(value)
        if (
            key in KNOWN_OBS
            or "/" in key
            or array.dtype.kind not in "fiub"
            or array.shape[:1] != (n,)
        ):
            raise RecordingError(
                f"{label}: obs/{key} must be a numeric dataset of T = {n} rows with a name other "
                f"than {', '.join(sorted(KNOWN_OBS))}; got dtype {array.dtype}, shape {array.shape}"
            )
    _check_demo_attrs(demo, label)
    if extra_attrs:
        check_attrs(demo.attrs, DEMO_ATTRS, label)


def check_attrs(attrs: dict[str, Any], reserved: frozenset[str], label: str) -> None:
    """Check extra attrs: names free, values numbers, strings, lists of strings, small arrays."""
    for key, value in attrs.items():
        if not isinstance(key, str) or not key:
            raise RecordingError(f"{label}: attr names must be non-empty strings; got {key!r}")
        if key in reserved:
            raise RecordingError(
                f"{label}: extra attr {key!r} clashes with a format v1 attr; reserved names are "
                f"{', '.join(sorted(reserved))}"
            )
        if isinstance(value, str):
            check_text(value, f"attr {key!r}", label)
        if not attr_value_ok(value):
            raise RecordingError(
                f"{label}: attr {key!r} has unsupported value of type {type(value).__name__}; "
                "attrs may be numbers, strings, lists of strings or small numeric arrays (put "
                "nested data in ep_meta)"
            )


def attr_value_ok(value: Any) -> bool:
    """Whether `value` can be stored as an HDF5 attr and read back equal."""
    if isinstance(value, bool | int | float | str | np.bool_ | np.integer | np.floating):
        return True
    if isinstance(value, list | tuple) and value and all(isinstance(v, str) for v in value):
        return True
    if isinstance(value, list | tuple | np.ndarray):
        try:
            array = np.asarray(value)
        except ValueError:  # ragged nested lists
            return False
        return array.dtype.kind in "biuf" and array.nbytes <= MAX_ATTR_BYTES
    return False


# Typed reads from an open file: the reader's first pass, before the checks above.


def _check_dataset(
    value: Any, dataset: str, rows: int | None, columns: int | None, label: str
) -> np.ndarray:
    """Check a finite float dataset and return it as an array.

    Args:
        value: The data.
        dataset: Its path in the demo group, for messages.
        rows: Expected rows T; None when any number will do.
        columns: Expected columns; 0 for a 1-D dataset, None for any positive number.
        label: Start of messages.
    """
    array = np.asarray(value)
    if array.dtype.kind != "f":
        raise RecordingError(f"{label}: {dataset} has dtype {array.dtype}; expected float64")
    row_text = "T" if rows is None else str(rows)
    if columns == 0:
        expected = f"({row_text},)"
        ok = array.ndim == 1
    else:
        expected = f"({row_text}, {'S' if columns is None else columns})"
        ok = array.ndim == 2 and array.shape[1] > 0 and columns in (None, array.shape[1])
    if not ok or (rows is not None and array.shape[0] != rows):
        raise RecordingError(
            f"{label}: {dataset} has shape {array.shape}; expected {expected}"
            + ("" if rows is None else " (T = rows of obs/ee_pos)")
        )
    if not np.all(np.isfinite(array)):
        first = tuple(int(i) for i in np.argwhere(~np.isfinite(array))[0])
        raise RecordingError(
            f"{label}: {dataset} has NaN or infinite values (first at index {first})"
        )
    return array


def _check_demo_attrs(demo: DemoRecord, label: str) -> None:
    if not isinstance(demo.demonstrator, str):
        raise RecordingError(
            f"{label}: attr demonstrator must be a string; got {type(demo.demonstrator).__name__}"
        )
    check_text(demo.demonstrator, "attr demonstrator", label)
    for key in ("theta_deg", "rho"):
        value = getattr(demo, key)
        if not _is_real(value) or math.isinf(value):
            raise RecordingError(
                f"{label}: attr {key} must be a finite number or NaN (unknown); got {value!r}"
            )
    if not math.isnan(demo.rho) and demo.rho <= 0.0:
        raise RecordingError(f"{label}: attr rho must be positive or NaN (unknown); got {demo.rho}")
    parse_source(demo.source, label)
    if demo.created is not None:
        try:
            datetime.fromisoformat(demo.created)
        except (TypeError, ValueError):
            raise RecordingError(
                f"{label}: attr created must be an ISO 8601 time such as "
                f"'2025-01-31T14:05:00+00:00'; got {demo.created!r}"
            ) from None
    if not isinstance(demo.ep_meta, dict):
        raise RecordingError(
            f"{label}: ep_meta must be a JSON object; got {type(demo.ep_meta).__name__}"
        )
    _check_json(demo.ep_meta, "ep_meta", label)


def _check_json(value: Any, key: str, label: str) -> None:
    try:
        json.dumps(value, allow_nan=True)
    except (TypeError, ValueError) as exc:
        raise RecordingError(f"{label}: {key} cannot be stored as JSON ({exc})") from None


def _is_int(value: Any) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)


def _is_real(value: Any) -> bool:
    return _is_int(value) or isinstance(value, float | np.floating)
