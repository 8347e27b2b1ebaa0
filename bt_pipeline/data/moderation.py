"""Moderation without data loss: exclude a recording file from scoring and cleaning, or restore it.

A recording is never modified to exclude it. Exclusion is a sidecar file beside it,
``<name>.hdf5.excluded`` (JSON: ``reason``, ``by``, ``at``), written atomically; restoring removes
the sidecar. ``bt score`` and ``bt clean`` skip excluded files with a note naming them, and the web
app offers exclude/restore per demo (docs/recording-format.md, "Moderation").
"""

from __future__ import annotations

import datetime as dt
import json
import os
from pathlib import Path

from bt_pipeline.exceptions import RecordingError

SIDECAR_SUFFIX = ".excluded"
"""Appended to a recording's file name to name its exclusion sidecar."""


def sidecar_path(recording: str | Path) -> Path:
    """The exclusion sidecar of `recording` (it may not exist)."""
    path = Path(recording)
    return path.with_name(path.name + SIDECAR_SUFFIX)


def is_excluded(recording: str | Path) -> bool:
    """Whether `recording` has an exclusion sidecar."""
    return sidecar_path(recording).is_file()


def exclusion(recording: str | Path) -> dict[str, str] | None:
    """The sidecar's content (``reason``, ``by``, ``at``), or None when not excluded.

    An unreadable sidecar still excludes: its content is then reported as unreadable.
    """
    side = sidecar_path(recording)
    if not side.is_file():
        return None
    try:
        data = json.loads(side.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {"reason": "(unreadable sidecar)", "by": "", "at": ""}
    if not isinstance(data, dict):
        return {"reason": "(unreadable sidecar)", "by": "", "at": ""}
    return {k: str(data.get(k, "")) for k in ("reason", "by", "at")}


def exclude(recording: str | Path, reason: str = "", by: str = "") -> Path:
    """Mark `recording` excluded (atomically); the recording itself is untouched.

    Raises:
        RecordingError: `recording` is not an existing file.
    """
    path = Path(recording)
    if not path.is_file():
        raise RecordingError(f"{path}: cannot exclude a recording that does not exist")
    side = sidecar_path(path)
    body = {"reason": reason, "by": by, "at": dt.datetime.now(dt.UTC).isoformat(timespec="seconds")}
    tmp = side.with_name(f".{side.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as out:
            json.dump(body, out, ensure_ascii=False)
            out.flush()
            os.fsync(out.fileno())
        os.replace(tmp, side)
    finally:
        tmp.unlink(missing_ok=True)
    return side


def restore(recording: str | Path) -> bool:
    """Remove `recording`'s exclusion; True when it was excluded."""
    side = sidecar_path(recording)
    try:
        side.unlink()
    except FileNotFoundError:
        return False
    return True
