"""Safe names for recordings: whatever a browser sends never becomes a path by itself.

A demo is saved as ``<recordings>/<task>/<name>_<UTC time>_<random>.hdf5`` where ``<name>`` is
the demonstrator's name reduced to a strict whitelist (letters, digits, ``_`` and ``-``; at most
:data:`MAX_NAME_CHARS` characters), so it can hold no path separator, no ``..`` and no control
character. The random suffix keeps concurrent sessions of one demonstrator apart.
"""

from __future__ import annotations

import re
import secrets
import unicodedata
from datetime import UTC, datetime
from pathlib import Path

from bt_pipeline.data.tasks import parse_guided_task
from bt_pipeline.exceptions import ConfigError

MAX_NAME_CHARS = 32
"""Longest demonstrator name in a file name."""
MAX_DEMONSTRATOR_CHARS = 64
"""Longest demonstrator name stored in a recording."""
ANONYMOUS = "anonymous"
"""Name used when nothing usable is left."""
RECORDING_SUFFIX = ".hdf5"

_NOT_ALLOWED = re.compile(r"[^A-Za-z0-9_-]+")


def sanitize_name(name: object) -> str:
    """Reduce `name` to ``[A-Za-z0-9_-]``, at most :data:`MAX_NAME_CHARS` characters.

    Runs of other characters (``/``, ``\\``, ``.``, spaces, accents, control characters) become
    one ``-``; leading and trailing ``-``/``_`` are dropped; nothing left gives ``anonymous``.

    Raises:
        ConfigError: `name` is not a string.
    """
    if not isinstance(name, str):
        raise ConfigError(f"a demonstrator name must be text; got {type(name).__name__}")
    ascii_name = unicodedata.normalize("NFKD", name).encode("ascii", "ignore").decode("ascii")
    slug = _NOT_ALLOWED.sub("-", ascii_name).strip("-_")[:MAX_NAME_CHARS].strip("-_")
    return slug or ANONYMOUS


def clean_demonstrator(name: object) -> str:
    """The demonstrator's name as stored in a recording: printable, trimmed, at most 64 chars.

    Raises:
        ConfigError: `name` is not a string.
    """
    if not isinstance(name, str):
        raise ConfigError(f"a demonstrator name must be text; got {type(name).__name__}")
    printable = "".join(ch if ch.isprintable() else " " for ch in name)
    text = " ".join(printable.split())[:MAX_DEMONSTRATOR_CHARS].strip()
    return text or ANONYMOUS


def utc_stamp(when: datetime) -> str:
    """`when` in UTC as ``YYYYmmddTHHMMSSZ`` (a naive `when` is taken to be UTC)."""
    if when.tzinfo is None:
        when = when.replace(tzinfo=UTC)
    return when.astimezone(UTC).strftime("%Y%m%dT%H%M%SZ")


def demo_path(
    recordings_dir: str | Path,
    task: str,
    demonstrator: str,
    when: datetime,
    suffix: str | None = None,
) -> Path:
    """Where a finished demo is saved: ``<recordings_dir>/<task>/<name>_<stamp>_<suffix>.hdf5``.

    Args:
        recordings_dir: Root folder of the recordings.
        task: The task (checked against the known tasks).
        demonstrator: Free-text name; sanitised with :func:`sanitize_name`.
        when: Creation time (UTC in the name).
        suffix: Random hex suffix; 6 fresh hex digits when None.

    Raises:
        UnknownTaskError: `task` is unknown.
        ConfigError: `suffix` is not hex, or the result would leave the task folder.
    """
    task_dir = Path(recordings_dir) / parse_guided_task(task)
    suffix = secrets.token_hex(3) if suffix is None else suffix
    if not re.fullmatch(r"[0-9a-f]{1,16}", suffix):
        raise ConfigError(f"file name suffix must be 1-16 lowercase hex digits; got {suffix!r}")
    name = f"{sanitize_name(demonstrator)}_{utc_stamp(when)}_{suffix}{RECORDING_SUFFIX}"
    path = task_dir / name
    if path.resolve().parent != task_dir.resolve():  # cannot happen with the whitelist; kept
        raise ConfigError(f"refusing to write outside {task_dir}: {name!r}")
    return path
