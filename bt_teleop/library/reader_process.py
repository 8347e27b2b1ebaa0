"""Reading take files for the app's library in a process of its own (:class:`ReaderProcess`).

Every Stop & save makes the library loader (:mod:`bt_teleop.library.loader`) read the new file and
score its demos on their periodic part (:func:`bt_teleop.library.reading.read_file_tracks`: HDF5,
segmentation, guide fits; ~24 ms and a few MiB of short-lived arrays a browser take). Done in the
app's process, those allocations fragment the app's C heap and fill HDF5's free lists there, and the
app's memory grew with every take saved (docs/security.md, "Where the native memory went"). Here
they happen in a child forked from the forkserver (:mod:`bt_teleop.proc.forkserver`)::

    app, reader thread                         reader child (serve_reads)
    ReaderProcess.read(path, kind) --(path, kind)-->  read_file_tracks(path, kind)
                                   <--(ok, FileTracks | error)--  then release_free_memory()
        no reply within timeout_s: the child is killed, RecordingError naming the file
        the child died: ReaderLost naming the file; the next read starts a new child
        after max_reads reads the child exits and the next read starts a new one

The child runs at ``nice`` +10, as clean jobs do, and the app starts it as it starts (its imports
then run while the first tab connects). At nice 0 and started by the first save, a 10-minute
8-tab soak on the idle machine had 30 ticks more than 50 ms late, all in the first two minutes,
all during a library load, 28 of them waiting for a CPU (docs/security.md).

What crosses the pipe is what the library keeps of a file (names, flags, durations, ranking
inputs: about 1 KiB a take), never its samples. A file whose read timed out is not read again
until it changes (:class:`bt_teleop.library.loader.LibraryLoader` caches the failure; not a
:class:`ReaderLost`).
"""

from __future__ import annotations

import ctypes
import gc
import importlib
import logging
import multiprocessing.connection
import signal
import sys
import threading
from pathlib import Path
from typing import Any

from bt_pipeline.exceptions import RecordingError
from bt_teleop.library.reading import read_file_tracks
from bt_teleop.library.tracks import FileTracks, TrackKind
from bt_teleop.proc.child import die_with_parent, libc, portable_error
from bt_teleop.proc.forkserver import start_child
from bt_teleop.proc.native_memory import release_free_memory
from bt_teleop.proc.priority import CLEAN_NICE, lower_priority

__all__ = ["READER_NAME", "READER_NICE", "ReaderLost", "ReaderProcess", "serve_reads"]

LOGGER = logging.getLogger("bt.teleop")
_READ_IMPORTS = (
    "bt_pipeline.clean.selection",
    "bt_pipeline.data.demo",
    "bt_pipeline.data.recording",
    "bt_teleop.library.cleaned_listing",
)
"""What :func:`~bt_teleop.library.reading.read_file_tracks` imports when first called."""
READER_NAME = "bt-reader"
"""The child's process name (``comm``, as ps and psutil show it)."""
_PR_SET_NAME = 15  # linux/prctl.h
READER_NICE = CLEAN_NICE
"""The reader child runs at ``nice`` +10, as clean jobs do: it is background work."""


class ReaderLost(RecordingError):
    """The reader child ended while reading a file (the file may read fine next time)."""


class ReaderProcess:
    """Reads files' tracks in a child process (thread-safe: one read at a time)."""

    def __init__(self, *, timeout_s: float = 60.0, max_reads: int = 2000) -> None:
        """A reader whose child is started at the first read.

        Args:
            timeout_s: Longest wait for one file [s]; the child is then killed.
            max_reads: Reads after which the child exits and a new one takes over (what a
                long-lived process keeps of each read is then given back with the process).
        """
        if timeout_s <= 0 or max_reads < 1:
            raise ValueError("timeout_s must be > 0 and max_reads >= 1")
        self.timeout_s, self.max_reads = timeout_s, max_reads
        self._lock = threading.Lock()
        self._conn: Any = None
        self._process: Any = None
        self._reads = 0
        self.started = 0
        """Children started so far."""

    def read(self, path: Path, kind: TrackKind) -> FileTracks:
        """`path`'s tracks as :func:`~bt_teleop.library.reading.read_file_tracks` reads them.

        Raises:
            RecordingError: The file cannot be read, or its read took longer than `timeout_s`.
            ReaderLost: The child died while reading it.
        """
        with self._lock:
            conn = self._child()
            self._reads += 1
            try:
                conn.send((str(path), kind))
                if not conn.poll(self.timeout_s):
                    self._stop(kill=True)
                    raise RecordingError(
                        f"{path}: reading it took more than {self.timeout_s:g} s; skipped"
                    )
                ok, value = conn.recv()
            except (EOFError, OSError) as exc:
                process = self._process
                if process is not None:
                    process.join(timeout=1.0)  # reaped: its exit code is known
                code = process.exitcode if process is not None else None
                self._stop(kill=True)
                raise ReaderLost(
                    f"{path}: the reader process ended while reading it (exit code {code})"
                ) from exc
            if self._reads >= self.max_reads:
                self._stop(kill=False)
        if not ok:
            raise value
        tracks: FileTracks = value
        return tracks

    def start(self) -> None:
        """Start the child now (it imports the scoring code at once), not at the first read."""
        with self._lock:
            self._child()

    def close(self) -> None:
        """End the child (a later read starts a new one)."""
        with self._lock:
            self._stop(kill=False)

    @property
    def pid(self) -> int | None:
        """The running child's pid (None when none runs)."""
        process = self._process
        return process.pid if process is not None and process.is_alive() else None

    def _child(self) -> Any:
        if self._process is None or not self._process.is_alive():
            self._stop(kill=True)
            level = logging.getLogger("bt").getEffectiveLevel()
            self._conn, self._process = start_child(serve_reads, (level,), "bt-reader")
            self._reads = 0
            self.started += 1
        return self._conn

    def _stop(self, *, kill: bool) -> None:
        conn, process = self._conn, self._process
        self._conn = self._process = None
        if conn is not None:
            conn.close()  # EOF: a waiting child exits
        if process is None:
            return
        if kill:
            process.kill()
        process.join(timeout=5.0)
        if process.is_alive():
            process.kill()
            process.join(timeout=5.0)


def serve_reads(conn: multiprocessing.connection.Connection, log_level: int) -> None:
    """The reader child: read each (path, kind) asked for until EOF, replying (ok, value)."""
    logging.basicConfig(level=log_level, format="bt: %(message)s", stream=sys.stderr)
    gc.freeze()  # what the forkserver imported stays shared
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C: the app closes us itself
    die_with_parent()
    if sys.platform.startswith("linux"):  # its name in ps and top (comm): not a session child
        libc().prctl(_PR_SET_NAME, ctypes.c_char_p(READER_NAME.encode()), 0, 0, 0)
    lower_priority(READER_NICE)  # the control loops first: 30 late ticks at nice 0 (module doc)
    for module in _READ_IMPORTS:  # now, not during the first read
        importlib.import_module(module)
    while True:
        try:
            path, kind = conn.recv()
        except (EOFError, OSError):
            return
        try:
            reply: tuple[bool, Any] = (True, read_file_tracks(Path(path), kind))
        except Exception as exc:
            reply = (False, portable_error(exc))
        try:
            conn.send(reply)
        except (OSError, ValueError):
            return
        release_free_memory()
