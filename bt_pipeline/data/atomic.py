"""Atomic publication of an output file: temporary file beside it, fsync, rename, fsync dir."""

from __future__ import annotations

import os
from pathlib import Path

from bt_pipeline.exceptions import RecordingError


def publish_atomic(tmp: Path, path: Path, overwrite: bool) -> None:
    """Move the finished `tmp` to `path` in one step; without `overwrite`, never clobber."""
    if overwrite:
        os.replace(tmp, path)
        return
    try:
        os.link(tmp, path)  # fails if `path` appeared meanwhile: no race with another writer
    except FileExistsError:
        raise RecordingError(exists_message(path)) from None
    except OSError:  # file system without hard links
        if path.exists():
            raise RecordingError(exists_message(path)) from None
        os.replace(tmp, path)
        return
    tmp.unlink()


def fsync_path(path: Path, flags: int) -> None:
    fd = os.open(path, flags)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def exists_message(path: Path) -> str:
    return (
        f"cannot write {path}: the file exists; recordings are never modified in place (write "
        "to a new file, or pass overwrite=True to replace it)"
    )
