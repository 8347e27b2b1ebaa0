"""Atomic publication of an output file: temporary file beside it, fsync, rename, fsync dir."""

from __future__ import annotations

import glob
import os
import re
import secrets
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


def temp_name(path: Path) -> Path:
    """The hidden temporary file of `path` for this process: ``.<name>.tmp-<pid>-<hex>``."""
    return path.with_name(f".{path.name}.tmp-{os.getpid()}-{secrets.token_hex(4)}")


def remove_stale_temps(path: Path) -> list[Path]:
    """Remove temporary files of `path` left by a killed writer; return those removed.

    A temporary file ``.<name>.tmp-<pid>-<hex>`` is stale when process <pid> no longer runs
    (a live writer's file is left alone). ``.<name>.<hex>.tmp`` files of older bt versions'
    .rrd writer carry no pid and are always stale.
    """
    removed = []
    for candidate in path.parent.glob(f".{glob.escape(path.name)}.*tmp*"):
        rest = candidate.name[len(path.name) + 2 :]
        match = _TEMP.fullmatch(rest)
        if match is None:
            continue
        pid = match.group("pid")
        if pid is not None and pid_alive(int(pid)):
            continue
        try:
            candidate.unlink()
        except OSError:
            continue
        removed.append(candidate)
    return removed


def pid_alive(pid: int) -> bool:
    """Whether a process with id `pid` exists on this machine."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's process
    except OverflowError:
        return False  # no process has such an id
    return True


_TEMP = re.compile(r"tmp-(?P<pid>\d{1,10})-[0-9a-f]+|[0-9a-f]{8,32}\.tmp")
