"""The Ũ each take read when it was first listed after its save, kept beside the takes.

Ũ (paper Eq. 8) is relative to the task's current set: Eq. 7 normalises each metric over the
task's usable takes, so a take's Ũ moves when another take is saved, excluded or restored (a
take of 0.56 read 0.36 once a steadier take joined the set). The page says so and marks a
value that moved since its take was saved: ``0.36 (was 0.56)``.

A take's file is written once, by its session, before its Ũ over the set exists (that needs the
task's other takes, which the library holds), and it is never rewritten (a Clean may be reading
it; inputs are never modified). So the first Ũ the library computes for a take, in the load
right after its save, is kept in ``<recordings>/<task>/.utility_at_save.json``
(``{track key: Ũ}``), written atomically (temporary file, fsync, ``os.replace``) by the load
that adds entries; a hidden file, which the scans of recordings skip. Entries of takes no longer
listed are dropped when the file is next written.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import tempfile
from collections.abc import Mapping
from pathlib import Path

__all__ = ["SAVED_NAME", "read_saved", "remember"]

LOGGER = logging.getLogger("bt.teleop")
SAVED_NAME = ".utility_at_save.json"
"""The file, in a task's folder of raw takes."""


def read_saved(folder: Path) -> dict[str, float]:
    """The kept Ũ of `folder`'s takes by track key (empty when none, or unreadable: logged)."""
    path = folder / SAVED_NAME
    try:
        loaded = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return {}
    except (OSError, ValueError) as exc:
        LOGGER.warning("ignoring %s: %s", path, exc)
        return {}
    if not isinstance(loaded, dict):
        return {}
    return {
        str(k): float(v)
        for k, v in loaded.items()
        if isinstance(v, int | float) and math.isfinite(float(v))
    }


def remember(
    folder: Path, current: Mapping[str, float | None], listed: set[str] | None = None
) -> dict[str, float]:
    """Keep the Ũ of each take in `current` that has none kept yet; the kept values.

    Args:
        folder: The task's folder of raw takes.
        current: Each scored take's Ũ now, by track key (None: not scored; not kept).
        listed: Every track key of the task now (default: `current`'s): kept values of other
            keys are dropped when the file is written.

    Returns:
        The kept Ũ by track key (the earlier ones, and those kept now).
    """
    saved = read_saved(folder)
    listed = set(current) if listed is None else listed
    new = {k: float(v) for k, v in current.items() if v is not None and k not in saved}
    if not new:
        return saved
    kept = {k: v for k, v in saved.items() if k in listed} | new
    try:
        _write_atomically(folder / SAVED_NAME, json.dumps(kept, sort_keys=True, indent=0))
    except OSError as exc:  # a read-only folder: the marks are then made in memory only
        LOGGER.warning("cannot keep the takes' first Ũ in %s: %s", folder / SAVED_NAME, exc)
    return kept


def _write_atomically(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".utility-", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as file:
            file.write(text)
            file.flush()
            os.fsync(file.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
