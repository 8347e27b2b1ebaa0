"""Loading a task's library for every tab at once, reading each file only once.

Every Stop & save bumps the task's version (:class:`~bt_teleop.ui_context.TaskVersions`) and
every tab on that task then wants the new library. Loaded per tab, from scratch, 8 tabs saving
a take every few seconds made the app read every file of the task 8 times per save: in the soak
benchmark, 140 s of a 120 s run went into those reads, on the app's CPU, beside the control
loops. :class:`LibraryLoader` makes that cost one incremental load per change::

    tab._poll: version changed -> loader.request(task) -> Future[TaskLibrary]
        a load of `task` queued and not yet started?  share it (it reads the files as they
                                                        are when it starts: newer than asked)
        otherwise                                      queue a new one on the app's reader
    the load: load_library(dir, task, read=cached read, metrics=cached metrics)
        a file whose (size, mtime, inode) did not change is not read again, nor are its
        demos' raw metrics (I, L1-L3: 14 ms a demo) computed again; only the normalisation
        over the task's demos (Eqs. 7-8) is redone

Loads of a task are also spaced out: the next one starts no sooner than ``max(min_interval_s,
duty × the last load's time)`` after the last one ended, so with a thousand takes on a loaded
machine (a load then takes seconds of wall time) the reader thread still leaves the CPU and the
GIL to the control loops most of the time; the table then lags the saves by that much (the save
notice itself is immediate).

The cache holds what the tabs' libraries hold anyway (the recordings of the task on disk); the
entries of files that are gone are dropped at each load.
"""

from __future__ import annotations

import concurrent.futures
import logging
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from bt_pipeline.data.records import Recording
from bt_pipeline.exceptions import RecordingError
from bt_teleop.cleaning import task_dir
from bt_teleop.library import TaskLibrary, load_library

if TYPE_CHECKING:
    from bt_pipeline.data.demo import Demo
    from bt_pipeline.score.utility import RawMetrics

__all__ = ["LibraryLoader"]

LOGGER = logging.getLogger("bt.teleop")
_Key = tuple[int, int, int]


class LibraryLoader:
    """Loads task libraries on a shared executor: one queued load per task, files cached."""

    def __init__(
        self,
        recordings_dir: Path,
        executor: concurrent.futures.Executor,
        *,
        min_interval_s: float = 1.0,
        duty: float = 3.0,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], object] | None = None,
    ) -> None:
        """Load `recordings_dir`'s tasks on `executor` (the app's one reader thread).

        Args:
            recordings_dir: Root folder of the recordings.
            executor: Where loads run.
            min_interval_s: Least time between the end of a task's load and the next [s].
            duty: The next load also waits `duty` × the last load's duration.
            clock: Monotonic time [s] (tests).
            sleep: Waits [s] (tests); by default a wait that :meth:`close` cuts short.
        """
        self.recordings_dir = Path(recordings_dir)
        self._executor = executor
        self.min_interval_s, self.duty = min_interval_s, duty
        self._closed = threading.Event()
        self._clock, self._sleep = clock, sleep or self._closed.wait
        self._next_start: dict[str, float] = {}
        self._lock = threading.Lock()
        self._queued: dict[str, tuple[object, concurrent.futures.Future[TaskLibrary]]] = {}
        self._files: dict[Path, tuple[_Key, Recording]] = {}
        self._metrics: dict[tuple[Path, str], tuple[_Key, RawMetrics]] = {}
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
        started = self._clock()
        seen: set[Path] = set()

        def read(path: Path) -> Recording:
            seen.add(path)
            return self._read(path)

        library = load_library(self.recordings_dir, task, read=read, metrics=self._raw_metrics)
        ended = self._clock()
        with self._lock:
            self.loads += 1
            pause = max(self.min_interval_s, self.duty * (ended - started))
            self._next_start[task] = ended + pause
            folder = task_dir(self.recordings_dir, library.task)
            for path in [p for p in self._files if p.parent == folder and p not in seen]:
                del self._files[path]  # deleted (or no longer listed) since the last load
            for key in [k for k in self._metrics if k[0] not in self._files]:
                del self._metrics[key]
        return library

    def _raw_metrics(self, path: Path, name: str, demo: Demo) -> RawMetrics:
        """The raw metrics of demo `name` of `path`, computed once per version of the file."""
        from bt_pipeline.score.utility import raw_metrics

        with self._lock:
            file_key = self._files[path][0] if path in self._files else None
            cached = self._metrics.get((path, name))
        if cached is not None and cached[0] == file_key:
            return cached[1]
        metrics = raw_metrics(demo.positions, demo.actions, demo.theta_deg)
        if file_key is not None:
            with self._lock:
                self._metrics[(path, name)] = (file_key, metrics)
        return metrics

    def _read(self, path: Path) -> Recording:
        """`path`'s recording, from the cache when the file did not change.

        Raises:
            RecordingError: The file cannot be read (not cached: a file being replaced may be
                readable next time).
        """
        from bt_pipeline.data.recording import read_recording

        try:
            stat = os.stat(path)
        except OSError as exc:
            raise RecordingError(f"{path}: cannot read it ({exc.strerror})") from exc
        key = (stat.st_size, stat.st_mtime_ns, stat.st_ino)
        with self._lock:
            cached = self._files.get(path)
        if cached is not None and cached[0] == key:
            return cached[1]
        recording = read_recording(path)
        with self._lock:
            self._files[path] = (key, recording)
            self.files_read += 1
        return recording
