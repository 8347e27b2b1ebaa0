"""Loading a task's library for every tab at once, reading each file only once.

Every Stop & save bumps the task's version (:class:`~bt_teleop.ui.context.TaskVersions`) and
every tab on that task then wants the new library. Loaded per tab, from scratch, 8 tabs saving
a take every few seconds made the app read every file of the task 8 times per save: in the soak
benchmark, 140 s of a 120 s run went into those reads, on the app's CPU, beside the control
loops. :class:`LibraryLoader` makes that cost one incremental load per change::

    tab._poll: version changed -> loader.request(task) -> Future[TaskLibrary]
        a load of `task` queued and not yet started?  share it (it reads the files as they
                                                        are when it starts: newer than asked)
        otherwise                                      queue a new one on the app's reader
    the load: load_library(dir, task, read=cached read)
        a file whose (size, mtime, inode) did not change is not read again, nor are its
        demos' ranking inputs (I, L1-L3 on the periodic part and the guide misfit: ~24 ms a
        browser take, ``bench_take_score.py``) computed again; only the normalisation over
        the task's demos (Eqs. 7-8) and the shape gate are redone

Loads of a task are also spaced out: the next one starts no sooner than ``max(min_interval_s,
duty × the CPU time the last load took in the app)`` after the last one ended, so with thousands
of takes on a loaded machine the loader thread still leaves the app's CPU and GIL to the tabs
most of the time; the table then lags the saves by that much (the save notice itself is
immediate). The time a load waits for the reader child is not counted: spacing by wall time (as
before 2026-12-03) made a load slowed by a Clean job (the child and the job share the CPU at
nice +10) push the next one back three times as long, and a 30-minute soak's table lagged its
saves by up to 85 s.

Each load also reuses the last library's track objects for the demos that did not change
(same file version, same Ũ, same exclusion): a save then allocates objects for its own take and
for the demos whose Ũ it moved, not for every take of the task (:func:`load_library`'s
``previous``; ``bench_save_growth.py``).

The cache holds, per file, what the tabs' libraries list
(:class:`~bt_teleop.library.tracks.FileTracks`: names, flags, durations, ranking inputs, the file's
identity; about 1 KiB a take), never its samples, or the error its read gave (a file that cannot be
read, or whose read timed out, is not read again until it changes); the entries of files that are
gone are dropped at each load.

The app reads files in a process of its own
(:class:`bt_teleop.library.reader_process.ReaderProcess`, the loader's `read_file`), so what a read
allocates never stays in the app's heap.
"""

from __future__ import annotations

import concurrent.futures
import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path

from bt_pipeline.exceptions import BtError, RecordingError
from bt_teleop.clean.runner import cleaned_path, task_dir
from bt_teleop.library.listing import TaskLibrary, load_library
from bt_teleop.library.reader_process import ReaderLost
from bt_teleop.library.reading import read_file_tracks
from bt_teleop.library.tracks import FileStamp, FileTracks, TrackKind, file_stamp

__all__ = ["LibraryLoader"]

LOGGER = logging.getLogger("bt.teleop")


class LibraryLoader:
    """Loads task libraries on a shared executor: one queued load per task, files cached."""

    def __init__(
        self,
        recordings_dir: Path,
        executor: concurrent.futures.Executor,
        *,
        read_file: Callable[[Path, TrackKind], FileTracks] = read_file_tracks,
        min_interval_s: float = 1.0,
        duty: float = 3.0,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], object] | None = None,
        cpu_clock: Callable[[], float] = time.thread_time,
    ) -> None:
        """Load `recordings_dir`'s tasks on `executor` (the app's one reader thread).

        Args:
            recordings_dir: Root folder of the recordings.
            executor: Where loads run.
            read_file: Reads one file's tracks
                (:func:`~bt_teleop.library.reading.read_file_tracks`, or a
                :class:`~bt_teleop.library.reader_process.ReaderProcess`'s ``read``).
            min_interval_s: Least time between the end of a task's load and the next [s].
            duty: The next load also waits `duty` × the CPU time the last load took.
            clock: Monotonic time [s] (tests).
            sleep: Waits [s] (tests); by default a wait that :meth:`close` cuts short.
            cpu_clock: The loading thread's CPU time [s] (tests): what a load costs the app,
                without its waits for the reader child.
        """
        self.recordings_dir = Path(recordings_dir)
        self._executor = executor
        self.min_interval_s, self.duty = min_interval_s, duty
        self._closed = threading.Event()
        self._clock, self._sleep = clock, sleep or self._closed.wait
        self._cpu_clock = cpu_clock
        self._next_start: dict[str, float] = {}
        self._lock = threading.Lock()
        self._queued: dict[str, tuple[object, concurrent.futures.Future[TaskLibrary]]] = {}
        self._read_file = read_file
        self._files: dict[Path, FileTracks] = {}
        self._failed: dict[Path, tuple[FileStamp, str]] = {}
        """Files whose read failed: the version read and the error's message."""
        self._last: dict[str, TaskLibrary] = {}
        """Each task's last library: its unchanged tracks are reused by the next load."""
        self.loads = 0
        """Loads run so far."""
        self.files_read = 0
        """Files read from disk so far (a cached file is not counted again)."""

    def request(self, task: str) -> concurrent.futures.Future[TaskLibrary]:
        """A future of `task`'s library as it is on disk now or later.

        Raises:
            RuntimeError: The executor is shut down (the app is stopping).
        """
        with self._lock:
            queued = self._queued.get(task)
            if queued is not None:
                return queued[1]
            token = object()
            future = self._executor.submit(self._load, task, token)
            self._queued[task] = (token, future)
            return future

    def close(self) -> None:
        """Stop spacing loads out (the app is stopping: queued loads run at once)."""
        self._closed.set()

    def _load(self, task: str, token: object) -> TaskLibrary:
        with self._lock:
            delay = self._next_start.get(task, 0.0) - self._clock()
        if delay > 0.0 and not self._closed.is_set():
            self._sleep(delay)  # requests meanwhile still share this load
        with self._lock:  # reading from now on: later requests need a newer load
            if self._queued.get(task, (None,))[0] is token:
                del self._queued[task]
        started = self._cpu_clock()
        seen: set[Path] = set()

        def read(path: Path, kind: TrackKind) -> FileTracks:
            seen.add(path)
            return self._read(path, kind)

        with self._lock:
            previous = self._last.get(task)
        library = load_library(self.recordings_dir, task, read=read, previous=previous)
        busy = self._cpu_clock() - started
        with self._lock:
            self._last[task] = library
            self.loads += 1
            pause = max(self.min_interval_s, self.duty * busy)
            self._next_start[task] = self._clock() + pause
            folder = task_dir(self.recordings_dir, library.task)
            cleaned = cleaned_path(self.recordings_dir, library.task)
            for cache in (self._files, self._failed):
                for path in [p for p in cache if p.parent == folder or p == cleaned]:
                    if path not in seen:  # deleted (or no longer listed) since the last load
                        del cache[path]
        return library

    def _read(self, path: Path, kind: TrackKind) -> FileTracks:
        """`path`'s tracks, from the cache when the file did not change.

        Raises:
            BtError: The file cannot be read (again, when it did not change since).
        """
        stamp = file_stamp(path)
        with self._lock:
            cached, failed = self._files.get(path), self._failed.get(path)
        if cached is not None and cached.stamp == stamp:
            return cached
        if failed is not None and failed[0] == stamp:
            raise RecordingError(failed[1])  # a new error: one raised again keeps every traceback
        try:
            tracks = self._read_file(path, kind)
        except BtError as exc:
            if not isinstance(exc, ReaderLost):  # the same bytes give the same error
                with self._lock:
                    self._failed[path] = (stamp, str(exc))
            raise
        with self._lock:
            self._failed.pop(path, None)
            self._files[path] = tracks
            self.files_read += 1
        return tracks
