"""Expand command-line PATH arguments (files, directories, globs) to recording files."""

from __future__ import annotations

import glob
from collections.abc import Sequence
from pathlib import Path

from bt_pipeline.exceptions import RecordingError

RECORDING_SUFFIXES = (".hdf5", ".h5")
"""File suffixes taken as recordings when a directory is searched."""


def _expand_one(item: str | Path) -> list[Path]:
    path = Path(item)
    if path.is_file():
        return [path]
    if path.is_dir():
        return _recordings_in(path)
    matches: list[Path] = []
    for candidate in sorted(Path(match) for match in glob.glob(str(item), recursive=True)):
        if candidate.is_dir():
            matches.extend(_recordings_in(candidate))
        elif candidate.is_file():
            matches.append(candidate)
    return matches


def _recordings_in(directory: Path) -> list[Path]:
    return sorted(
        p
        for p in directory.rglob("*")
        if p.suffix in RECORDING_SUFFIXES
        and p.is_file()
        and not any(part.startswith(".") for part in p.relative_to(directory).parts)
    )


def expand_paths(paths: Sequence[str | Path]) -> list[Path]:
    """Turn files, directories and glob patterns into a list of recording files.

    A file is taken as it is; a directory gives every ``*.hdf5`` and ``*.h5`` below it (hidden
    files and folders skipped), sorted; anything else is a glob pattern (``**`` recurses), its
    matches sorted and directories among them expanded. Items keep their order; a file found
    twice is kept at its first place.

    Raises:
        RecordingError: An item matches no recording.
    """
    found: list[Path] = []
    seen: set[Path] = set()
    for item in paths:
        matches = _expand_one(item)
        if not matches:
            raise RecordingError(f"no recordings found at {str(item)!r}")
        for match in matches:
            key = match.resolve()
            if key not in seen:
                seen.add(key)
                found.append(match)
    return found
