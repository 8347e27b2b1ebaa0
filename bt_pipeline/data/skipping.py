"""Skip, don't stop: the inputs ``bt score`` and ``bt clean`` leave out, each with a note.

Three kinds of input are left out with a one-line note naming them, and the rest is processed:

* an **excluded file** (a moderation sidecar beside it, :mod:`bt_pipeline.data.moderation`),
  always;
* a **flagged demo** (``DemoRecord.flags`` other than the remarks in
  :data:`~bt_pipeline.data.records.INFO_FLAGS`: a failed take check), always: a flagged demo is
  never the best demo. A demo whose only flag is ``off_guide`` (a loop of its own, not the
  guide's shape) is processed like an unflagged one;
* a demo a stage **cannot use** (no motion, not periodic, degenerate; :func:`skip_failing`),
  unless ``strict``, when the first one stops the run with a message naming it.

* an **unreadable file** (not format v1, or beyond :class:`~bt_pipeline.data.limits.ReadLimits`),
  unless ``strict``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np

from bt_pipeline.data.demo import Demo, demos_from_recording
from bt_pipeline.data.limits import ReadLimits
from bt_pipeline.data.moderation import exclusion
from bt_pipeline.data.paths import expand_paths
from bt_pipeline.data.recording import read_recording
from bt_pipeline.data.records import INFO_FLAGS, DemoRecord, Recording
from bt_pipeline.exceptions import ConfigError, DemoError, RecordingError

log = logging.getLogger("bt")
R = TypeVar("R")

NUMERIC_ERRORS = (DemoError, ArithmeticError, ValueError, np.linalg.LinAlgError)
"""What a degenerate demo can make the numerics raise (ConfigError, a settings error, is not
among them: it is re-raised)."""


@dataclass(frozen=True)
class UsableInput:
    """What is left to process after excluded files, unreadable files and flagged demos."""

    files: tuple[Path, ...]
    """Every input file (excluded ones too), as expanded."""
    recordings: tuple[Recording, ...]
    """The recordings read."""
    demos: tuple[Demo, ...]
    """Unflagged demos in the pipeline's view, input order."""
    flagged: tuple[tuple[Demo, tuple[str, ...]], ...]
    """Flagged demos and their failed checks (remarks such as ``off_guide`` left out)."""
    notes: tuple[str, ...]
    """One line per excluded file and flagged demo (``skipped <what>: <why>``)."""

    def records(self) -> dict[tuple[str, str], DemoRecord]:
        """Every demo record read, by (file label, demo name)."""
        return {
            (str(r.path) if r.path else "", name): record
            for r in self.recordings
            for name, record in r.demos.items()
        }


def read_usable(
    paths: Sequence[str | Path],
    n_samples: int,
    *,
    strict: bool = False,
    limits: ReadLimits | None = None,
) -> UsableInput:
    """Expand `paths`, leave out excluded files and flagged demos, read the rest.

    Args:
        paths: Files, directories or glob patterns.
        n_samples: N, samples per demo after resampling.
        strict: Stop at the first unreadable file instead of skipping it.
        limits: Read-time bounds; the defaults when None.

    Raises:
        RecordingError: No recordings found, or an unreadable file when strict.
    """
    files, notes, recordings = expand_paths(paths), [], []
    for file in files:
        excluded = exclusion(file)
        if excluded is not None:
            reason = f": {excluded['reason']}" if excluded["reason"] else ""
            notes.append(_note(f"{file}: excluded{reason}"))
            continue
        try:
            recordings.append(read_recording(file, limits))
        except RecordingError as exc:
            if strict:
                raise
            notes.append(_note(str(exc)))
    demos, flagged = [], []
    for recording in recordings:
        label = str(recording.path) if recording.path else ""
        for demo in demos_from_recording(recording, n_samples, file=label):
            flags = tuple(f for f in recording.demos[demo.name].flags if f not in INFO_FLAGS)
            if flags:
                flagged.append((demo, flags))
                notes.append(_note(f"{demo.label}: flagged {', '.join(flags)}"))
            else:
                demos.append(demo)
    return UsableInput(tuple(files), tuple(recordings), tuple(demos), tuple(flagged), tuple(notes))


def skip_failing(
    run: Callable[[list[Demo]], R],
    demos: Sequence[Demo],
    probe: Callable[[Demo], object],
    *,
    strict: bool = False,
) -> tuple[R | None, list[str]]:
    """``run(demos)``; a demo it fails on is dropped with a note and the rest run again.

    The demo at fault is the one the error message names (its label ``file:demo_<k>``) or, for
    an error naming none, the first demo on which ``probe`` alone fails. At most ``len(demos)``
    retries.

    Returns:
        ``run``'s result (None when every demo was dropped) and one note per dropped demo.

    Raises:
        DemoError: strict (naming the demo), or an error no single demo explains (naming the
            task and its files).
        ConfigError: A settings error, as raised.
    """
    remaining, notes = list(demos), []
    while remaining:
        try:
            return run(remaining), notes
        except ConfigError:
            raise
        except NUMERIC_ERRORS as exc:
            message = str(exc) if isinstance(exc, DemoError) else f"{type(exc).__name__}: {exc}"
            culprit = named_demo(message, remaining) or _first_failing(remaining, probe)
            if culprit is None:
                files = sorted({demo.file for demo in remaining if demo.file})
                raise DemoError(
                    f"task {remaining[0].task} ({', '.join(files) or 'in memory'}): {message}"
                ) from None
            if culprit.label not in message:
                message = f"{culprit.label}: {message}"
            if strict:
                raise DemoError(message) from None
            notes.append(_note(message))
            remaining = [demo for demo in remaining if demo is not culprit]
    return None, notes


def named_demo(message: str, demos: Sequence[Demo]) -> Demo | None:
    """The demo whose label (``file:demo_<k>``) `message` names; the longest match wins."""
    named = [demo for demo in demos if demo.label and demo.label in message]
    return max(named, key=lambda demo: len(demo.label)) if named else None


def _first_failing(demos: Sequence[Demo], probe: Callable[[Demo], object]) -> Demo | None:
    for demo in demos:
        try:
            probe(demo)
        except ConfigError:
            raise
        except NUMERIC_ERRORS:
            return demo
    return None


def _note(what: str) -> str:
    log.warning("skipping %s", what)
    return f"skipped {what}"
