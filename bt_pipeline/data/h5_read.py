"""Typed reads of format-v1 HDF5 attrs and datasets: one clear error naming the demo per problem."""

from __future__ import annotations

import json
from typing import Any

import h5py
import numpy as np

from bt_pipeline.data.limits import decode_utf8
from bt_pipeline.exceptions import RecordingError


def read_dataset(group: h5py.Group, key: str, label: str, max_rows: int | None = None) -> Any:
    """The raw contents of dataset `key` of `group`; an error when it is missing or a group.

    With `max_rows`, a dataset of more rows, or of more than ``64 * max_rows`` elements, is
    refused before it is loaded.
    """
    if key not in group:
        raise RecordingError(f"{label}: missing dataset {key}")
    item = group[key]
    if not isinstance(item, h5py.Dataset):
        raise RecordingError(f"{label}: {key} is a group; expected a dataset")
    shape, size = item.shape or (), item.size or 0  # None for an empty (null) dataspace
    if max_rows is not None and shape and (shape[0] > max_rows or size > 64 * max_rows):
        raise RecordingError(
            f"{label}: {key} has shape {item.shape}; at most {max_rows} rows are read"
        )
    return item[()]


def read_attr(attrs: h5py.AttributeManager, key: str, label: str) -> Any:
    """The raw value of attr `key`; an error naming it when it is missing."""
    if key not in attrs:
        raise RecordingError(f"{label}: missing attr {key!r}")
    return attrs[key]


def str_attr(attrs: h5py.AttributeManager, key: str, label: str) -> str:
    """Attr `key` as a string (UTF-8 byte strings decoded)."""
    value = read_attr(attrs, key, label)
    if isinstance(value, bytes | str):
        return decode_utf8(value, f"attr {key!r}", label)
    raise RecordingError(f"{label}: attr {key!r} must be a string; got {value!r:.200}")


def int_attr(attrs: h5py.AttributeManager, key: str, label: str) -> int:
    """Attr `key` as an int (booleans and floats refused)."""
    value = read_attr(attrs, key, label)
    if isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_):
        return int(value)
    raise RecordingError(f"{label}: attr {key!r} must be an integer; got {value!r}")


def float_attr(attrs: h5py.AttributeManager, key: str, label: str) -> float:
    """Attr `key` as a float (any real number, NaN included)."""
    value = read_attr(attrs, key, label)
    if isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_
    ):
        return float(value)
    raise RecordingError(f"{label}: attr {key} must be a number (NaN = unknown); got {value!r}")


def json_attr(attrs: h5py.AttributeManager, key: str, label: str) -> dict[str, Any]:
    """Attr `key`, a string holding a JSON object, decoded."""
    text = str_attr(attrs, key, label)
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise RecordingError(
            f"{label}: attr {key} is not valid JSON ({exc}): {text[:80]!r}"
        ) from None
    if not isinstance(value, dict):
        raise RecordingError(f"{label}: attr {key} must be a JSON object; got {text[:80]!r}")
    return value


def read_extra_attrs(attrs: h5py.AttributeManager, reserved: frozenset[str]) -> dict[str, Any]:
    """Attrs outside format v1, as Python scalars, strings, lists of strings or arrays."""
    extra: dict[str, Any] = {}
    for key in attrs:  # names first: reading a value costs far more, and reserved ones are read
        if key in reserved:  # by their typed readers already
            continue
        value = attrs[key]
        if isinstance(value, np.ndarray) and value.dtype.kind in "OSU":
            extra[key] = [decode(v) for v in value.ravel().tolist()]
        elif isinstance(value, bytes):
            extra[key] = decode(value)
        elif isinstance(value, np.generic):
            item = value.item()
            extra[key] = decode(item) if isinstance(item, bytes) else item
        else:
            extra[key] = value
    return extra


def decode(value: Any) -> str:
    """`value` as text: bytes decoded as UTF-8, anything else through ``str``."""
    return value.decode("utf-8", errors="replace") if isinstance(value, bytes) else str(value)
