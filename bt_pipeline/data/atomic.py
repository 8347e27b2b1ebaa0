"""Atomic publication of an output file: temporary file beside it, fsync, rename, fsync dir.

A directory tree (a LeRobot dataset) is built in ``.<name>.tmp-<pid>-<hex>`` beside it and
renamed into place (:func:`publish_dir`); replacing an existing one takes two renames (old
aside to ``.<name>.old-<pid>-<hex>``, new into place), so :func:`recover_dir`, run before the
next write, puts a killed writer's old tree back (when the new one never arrived) or deletes it.
"""

from __future__ import annotations

import glob
import os
import re
import secrets
import shutil
from pathlib import Path

from bt_pipeline.exceptions import ConfigError, RecordingError


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
    prefix = f".{path.name}."
    # One fixed pattern, filtered by name: a pattern naming the file would be compiled and
    # kept in pathlib's and re's caches once per file written (~1 KiB each, up to their sizes).
    for candidate in path.parent.glob(".*tmp*"):
        if not candidate.name.startswith(prefix):
            continue
        rest = candidate.name[len(prefix) :]
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


def publish_dir(tmp: Path, out: Path, overwrite: bool) -> None:
    """Move the finished directory `tmp` to `out`; an existing `out` is replaced only at the
    end (without `overwrite` it is an error).

    Raises:
        ConfigError: `out` exists and `overwrite` is False.
    """
    if os.name == "posix":
        for folder in (p for p in tmp.rglob("*") if p.is_dir()):
            fsync_path(folder, os.O_RDONLY)
        for file in (p for p in tmp.rglob("*") if p.is_file()):
            fsync_path(file, os.O_RDONLY)
    if out.exists():
        if not overwrite:
            raise ConfigError(f"{out} exists; choose another --out or pass --overwrite")
        old = out.with_name(f".{out.name}.old-{os.getpid()}-{secrets.token_hex(4)}")
        os.rename(out, old)
        os.rename(tmp, out)  # a kill between the renames: recover_dir puts `old` back
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.rename(tmp, out)
    if os.name == "posix":
        fsync_path(out.parent, os.O_RDONLY)


def recover_dir(out: Path) -> list[str]:
    """Undo what killed writers of the directory `out` left: their unfinished trees are
    deleted, an old tree set aside is put back when `out` is missing (else deleted).

    Returns:
        One line per action, naming the path.
    """
    done: list[str] = []
    for candidate in sorted(out.parent.glob(f".{glob.escape(out.name)}.*")):
        match = _DIR_TEMP.fullmatch(candidate.name[len(out.name) + 2 :])
        if match is None or not candidate.is_dir() or pid_alive(int(match.group("pid"))):
            continue
        if match.group("kind") == "old" and not out.exists():
            os.rename(candidate, out)
            done.append(f"{out}: put back the previous output a killed writer had set aside")
        else:
            shutil.rmtree(candidate, ignore_errors=True)
            done.append(f"{candidate}: removed what a killed writer left")
    return done


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
_DIR_TEMP = re.compile(r"(?P<kind>tmp|old)-(?P<pid>\d{1,10})-[0-9a-f]+")
