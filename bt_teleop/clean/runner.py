"""The teleop app's Clean button: clean one task's recordings in a background process.

Where the files go is in :mod:`bt_teleop.clean.task`: ``<recordings>/.cleaned/`` is hidden on
purpose, so every directory scan of bt (:func:`bt_pipeline.data.paths.expand_paths`) skips it and
cleaned demos are never taken for raw input.

A job runs in a spawned process (torch training holds a core; the sessions' control loops keep the
other) at a lower CPU priority (``nice`` +10, :data:`~bt_teleop.proc.priority.CLEAN_NICE`), with one
thread in the app reading its progress queue::

    CleanRunner.start(task, rerun) -> process: read raw demos -> clean_demos(on_epoch -> queue)
                                      -> write <task>.cleaned.hdf5 (+ .rrd)
                                      -> log the result to the tab's Rerun recording
                                      -> queue("done", output, notes)
                                   -> thread:  queue -> CleanJob.progress() (the UI polls it)

At most one job runs per task; jobs of different tasks run side by side, so a slow or stuck job
never blocks another task or tab. Every job has a time limit (``timeout_s``, 15 min by default)
after which its process is stopped and the job fails with a message saying so, and a job can be
cancelled (the Cancel clean button). A job's outputs are published as one set
(:class:`~bt_pipeline.data.output_set.OutputSet`): a stopped job leaves the previous output.
Demos the cleaner cannot use, flagged and excluded demos are skipped with a note (as ``bt
clean`` does); the notes reach the tab that started the job.
"""

from __future__ import annotations

import logging
import multiprocessing
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

from bt_pipeline.clean.pipeline import CleanOptions
from bt_pipeline.data.tasks import GuidedTask, parse_guided_task
from bt_pipeline.exceptions import BtError, ConfigError
from bt_teleop.clean.task import CLEANED_DIRNAME, clean_task, cleaned_dir, cleaned_path, task_dir
from bt_teleop.proc.priority import lower_priority
from bt_teleop.rerun.clean_log import CleanLogTarget, log_clean_to

LOGGER = logging.getLogger("bt.teleop")

JobState = Literal["running", "done", "failed", "cancelled"]
DEFAULT_TIMEOUT_S = 900.0
"""Longest a clean job may run before it is stopped [s]."""


@dataclass(frozen=True)
class CleanProgress:
    """A snapshot of a clean job."""

    task: GuidedTask
    """The task being cleaned."""
    state: JobState
    """running, done or failed."""
    epoch: int
    """Refinement epochs done so far."""
    epochs: int
    """Most epochs the refinement runs (it may stop earlier on a plateau)."""
    message: str
    """What is happening, or why the job failed."""
    output: Path | None = None
    """The cleaned file, once done."""
    notes: tuple[str, ...] = ()
    """Demos skipped (flagged, excluded, unusable), one line each, once done."""

    @property
    def fraction(self) -> float:
        """Progress in [0, 1] (1 when finished, successful or not)."""
        if self.state != "running":
            return 1.0
        return min(1.0, self.epoch / self.epochs) if self.epochs > 0 else 0.0


class CleanJob:
    """One clean job; its progress is updated by the runner's reader thread."""

    def __init__(self, task: GuidedTask, epochs: int, owner: object = None) -> None:
        self.task = task
        self.owner = owner
        """Who started it (the UI uses it to notify that session only)."""
        self._lock = threading.Lock()
        self._done = threading.Event()
        self._progress = CleanProgress(task, "running", 0, epochs, "starting")

    def progress(self) -> CleanProgress:
        """The latest snapshot."""
        with self._lock:
            return self._progress

    def wait(self, timeout_s: float | None = None) -> CleanProgress:
        """Block until the job ends (or `timeout_s` [s] passes); the latest snapshot."""
        self._done.wait(timeout_s)
        return self.progress()

    @property
    def finished(self) -> bool:
        """Whether the job ended (done or failed)."""
        return self._done.is_set()

    def _update(self, **changes: Any) -> None:
        with self._lock:
            self._progress = replace(self._progress, **changes)
            if self._progress.state != "running":
                self._done.set()


class CleanRunner:
    """Runs the app's clean jobs: one per task at a time, each in a process, time-limited."""

    def __init__(
        self,
        recordings_dir: str | Path,
        options: CleanOptions | None = None,
        *,
        processes: bool = True,
        on_finish: Callable[[CleanJob], None] | None = None,
        timeout_s: float = DEFAULT_TIMEOUT_S,
    ) -> None:
        """Prepare a runner.

        Args:
            recordings_dir: Root folder of the recordings.
            options: Cleaner settings (progress bars are turned off); defaults when None.
            processes: Run jobs in a spawned process (True) or in a thread of this process (a
                thread cannot be stopped: a cancelled or timed-out thread job is abandoned, its
                result ignored).
            on_finish: Called (from a runner thread) when a job ends, done or failed.
            timeout_s: Longest a job may run [s]; then it is stopped and fails.
        """
        if not (timeout_s > 0.0):
            raise ConfigError(f"clean timeout must be positive; got {timeout_s} s")
        self.recordings_dir = Path(recordings_dir)
        self.options = replace(options or CleanOptions(), progress=False)
        self.processes = processes
        self.on_finish = on_finish
        self.timeout_s = timeout_s
        self._lock = threading.Lock()
        self._jobs: dict[GuidedTask, CleanJob] = {}
        self._last: CleanJob | None = None
        # multiprocessing.Process (its type depends on the context)
        self._processes: dict[GuidedTask, Any] = {}
        self._threads: dict[GuidedTask, threading.Thread] = {}
        self._closed = False

    @property
    def current(self) -> CleanJob | None:
        """The job started last (running or not), or None."""
        return self._last

    def job_for(self, task: str) -> CleanJob | None:
        """The running or last job of `task`, or None."""
        with self._lock:
            return self._jobs.get(parse_guided_task(task))

    def jobs(self) -> list[CleanJob]:
        """The running or last job of every task that had one."""
        with self._lock:
            return list(self._jobs.values())

    def start(
        self, task: str, owner: object = None, rerun: CleanLogTarget | None = None
    ) -> CleanJob:
        """Start cleaning `task`'s recordings in the background; the job logs its result to
        `rerun` (the starting tab's recording) itself, and the app never holds it.

        Raises:
            ConfigError: A job for `task` is already running, or the runner is closed.
            UnknownTaskError: `task` is unknown.
        """
        parsed = parse_guided_task(task)
        epochs = self.options.refine_config().resolve().epochs
        with self._lock:
            if self._closed:
                raise ConfigError("the app is shutting down; no new clean jobs")
            running = self._jobs.get(parsed)
            if running is not None and not running.finished:
                raise ConfigError(
                    f"a clean job for {parsed} is running; try again when it finishes or cancel it"
                )
            job = CleanJob(parsed, epochs, owner)
            self._jobs[parsed] = self._last = job
            messages: Any
            if self.processes:
                context = multiprocessing.get_context("spawn")
                messages = context.Queue()
                process = context.Process(
                    target=run_clean_job,
                    args=(self.recordings_dir, parsed, self.options, messages, True, rerun),
                    name=f"bt-clean-{parsed}",
                    daemon=True,
                )
                process.start()
                self._processes[parsed] = process
                target, args = self._read_process, (job, messages, process)
            else:
                messages = queue.Queue()
                target, args = self._run_inline, (job, messages, rerun)
            thread = threading.Thread(
                target=target, args=args, name=f"bt-clean-{parsed}", daemon=True
            )
            self._threads[parsed] = thread
            thread.start()
        return job

    def cancel(self, task: str, reason: str = "cancelled") -> bool:
        """Stop `task`'s running job (its output is not written); True when one was running."""
        parsed = parse_guided_task(task)
        with self._lock:
            job, process = self._jobs.get(parsed), self._processes.get(parsed)
        if job is None or job.finished:
            return False
        job._update(state="cancelled", message=reason)
        if process is not None and process.is_alive():
            process.terminate()
        return True

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop every running job (their outputs are not written) and join the threads."""
        with self._lock:
            self._closed = True
            tasks = list(self._jobs)
            threads = list(self._threads.values())
        for task in tasks:
            self.cancel(task, "the app stopped")
        for process in list(self._processes.values()):
            process.join(timeout_s)
        for thread in threads:
            thread.join(timeout_s)

    def _run_inline(
        self, job: CleanJob, messages: queue.Queue[Any], rerun: CleanLogTarget | None
    ) -> None:
        worker = threading.Thread(
            target=run_clean_job,
            args=(self.recordings_dir, job.task, self.options, messages, False, rerun),
            daemon=True,
        )
        worker.start()
        self._consume(job, messages, worker.is_alive)
        self._finished(job)

    def _read_process(self, job: CleanJob, messages: Any, process: Any) -> None:
        self._consume(job, messages, process.is_alive)
        if process.is_alive() and job.progress().state != "done":
            process.terminate()  # timed out or cancelled
        process.join(5.0)
        self._finished(job)

    def _finished(self, job: CleanJob) -> None:
        if self.on_finish is not None:
            try:
                self.on_finish(job)
            except Exception:
                LOGGER.exception("on_finish of the clean job for %s failed", job.task)

    def _consume(self, job: CleanJob, messages: Any, alive: Any) -> None:
        deadline = time.monotonic() + self.timeout_s
        while not job.finished:
            if time.monotonic() > deadline:
                job._update(
                    state="failed",
                    message=f"stopped after {self.timeout_s:g} s (the clean time limit)",
                )
                return
            try:
                kind, *payload = messages.get(timeout=0.2)
            except queue.Empty:
                if not alive():
                    job._update(state="failed", message="the clean process stopped unexpectedly")
                    return
                continue
            if job.finished:  # cancelled meanwhile: its result is dropped
                return
            if kind == "epoch":
                job._update(epoch=payload[0], message=f"refining: epoch {payload[0]}")
            elif kind == "stage":
                job._update(message=payload[0])
            elif kind == "done":
                job._update(state="done", output=Path(payload[0]), message="done", notes=payload[1])
                return
            else:
                job._update(state="failed", message=str(payload[0]))
                return


def run_clean_job(
    recordings_dir: Path,
    task: GuidedTask,
    options: CleanOptions,
    messages: Any,
    single_thread: bool,
    rerun: CleanLogTarget | None = None,
) -> None:
    """Clean `task`'s raw recordings, write the output and log the result to `rerun` (a
    failure there is a note: the outputs stand); report through `messages`.

    Messages are tuples: ``("stage", text)``, ``("epoch", k)``, then ``("done", output path,
    notes)`` or ``("failed", message)``. Runs in the job's process (or thread). The result
    itself never goes back: it holds every demo of the task, and the app would keep the pages
    it was unpickled and logged in (:mod:`bt_teleop.rerun.clean_log`).
    """
    try:
        if single_thread:
            import torch

            torch.set_num_threads(1)  # leave the other cores to the sessions
            lower_priority()
        messages.put(("stage", "reading recordings"))
        notes: list[str] = []
        output, result = clean_task(
            recordings_dir,
            task,
            options,
            on_epoch=lambda k: messages.put(("epoch", k)),
            notes=notes,
        )
        if rerun is not None:
            messages.put(("stage", "sending the result to the Rerun viewer"))
            try:
                log_clean_to(rerun, result, options.seed)
            except Exception as exc:  # the viewer is optional: the cleaned file is written
                LOGGER.warning("clean job for %s: Rerun logging failed", task, exc_info=True)
                notes.append(f"the Rerun viewer did not get the result ({type(exc).__name__})")
        messages.put(("done", str(output), tuple(notes)))
    except BtError as exc:
        messages.put(("failed", str(exc)))
    except Exception as exc:  # reported in the UI; the app keeps running
        LOGGER.exception("clean job for %s failed", task)
        messages.put(("failed", f"{type(exc).__name__}: {exc}"))


__all__ = [
    "CLEANED_DIRNAME",
    "CleanJob",
    "CleanProgress",
    "CleanRunner",
    "clean_task",
    "cleaned_dir",
    "cleaned_path",
    "run_clean_job",
    "task_dir",
]
