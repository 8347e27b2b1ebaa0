"""The teleop app's Clean button: clean one task's recordings in a background process.

Where files go::

    <recordings>/<task>/*.hdf5                 raw demos, one file per demo (the input)
    <recordings>/.cleaned/<task>.cleaned.hdf5  the cleaned demos of the task (format v1)
    <recordings>/.cleaned/<task>.rrd           the cleaning result for the Rerun viewer

The output folder is hidden on purpose: every directory scan of bt
(:func:`bt_pipeline.data.recording.expand_paths`) skips hidden folders, so neither the app's list of
raw recordings nor ``bt score recordings`` / ``bt clean recordings`` ever takes cleaned demos for
raw input. Each clean replaces the task's previous output, atomically.

A job runs in a spawned process (torch training holds a core; the sessions' control loops keep
the other), with one thread in the app reading its progress queue::

    CleanRunner.start(task) -> process: read raw demos -> clean_demos(on_epoch -> queue)
                                         -> write <task>.cleaned.hdf5 (+ .rrd) -> queue(result)
                            -> thread:  queue -> CleanJob.progress() (the UI polls it)

At most one job runs at a time in an app (the machine has few cores); starting a second one
raises a ConfigError that names the task being cleaned.
"""

from __future__ import annotations

import logging
import multiprocessing
import queue
import threading
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

from bt_pipeline.clean.pipeline import CleanOptions, TaskCleanResult, clean_demos
from bt_pipeline.data.tasks import Task, parse_task
from bt_pipeline.exceptions import BtError, ConfigError, DemoError, RecordingError

CLEANED_DIRNAME = ".cleaned"
"""Folder under the recordings root that holds cleaned output (hidden: never scanned as input)."""
LOGGER = logging.getLogger("bt.teleop")

JobState = Literal["running", "done", "failed"]


def cleaned_dir(recordings_dir: str | Path) -> Path:
    """``<recordings>/.cleaned``."""
    return Path(recordings_dir) / CLEANED_DIRNAME


def cleaned_path(recordings_dir: str | Path, task: str) -> Path:
    """``<recordings>/.cleaned/<task>.cleaned.hdf5``."""
    return cleaned_dir(recordings_dir) / f"{parse_task(task)}.cleaned.hdf5"


def task_dir(recordings_dir: str | Path, task: str) -> Path:
    """``<recordings>/<task>``: the raw demos of `task`."""
    return Path(recordings_dir) / parse_task(task)


@dataclass(frozen=True)
class CleanProgress:
    """A snapshot of a clean job."""

    task: Task
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

    @property
    def fraction(self) -> float:
        """Progress in [0, 1] (1 when finished, successful or not)."""
        if self.state != "running":
            return 1.0
        return min(1.0, self.epoch / self.epochs) if self.epochs > 0 else 0.0


class CleanJob:
    """One clean job; its progress is updated by the runner's reader thread."""

    def __init__(self, task: Task, epochs: int, owner: object = None) -> None:
        self.task = task
        self.owner = owner
        """Who started it (the UI uses it to notify that session only)."""
        self.result: TaskCleanResult | None = None
        """The cleaner's full result, once done (for the Rerun log)."""
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
    """Runs clean jobs for the app, one at a time, each in its own process."""

    def __init__(
        self,
        recordings_dir: str | Path,
        options: CleanOptions | None = None,
        *,
        processes: bool = True,
        on_finish: Callable[[CleanJob], None] | None = None,
    ) -> None:
        """Prepare a runner.

        Args:
            recordings_dir: Root folder of the recordings.
            options: Cleaner settings (progress bars are turned off); defaults when None.
            processes: Run jobs in a spawned process (True) or in a thread of this process.
            on_finish: Called (from a runner thread) when a job ends, done or failed.
        """
        self.recordings_dir = Path(recordings_dir)
        self.options = replace(options or CleanOptions(), progress=False)
        self.processes = processes
        self.on_finish = on_finish
        self._lock = threading.Lock()
        self._job: CleanJob | None = None
        self._process: Any = None  # multiprocessing.Process (its type depends on the context)
        self._thread: threading.Thread | None = None
        self._closed = False

    @property
    def current(self) -> CleanJob | None:
        """The job running now, or the last one."""
        return self._job

    def start(self, task: str, owner: object = None) -> CleanJob:
        """Start cleaning `task`'s recordings in the background.

        Raises:
            ConfigError: A job is already running (its task is named), or the runner is closed.
            UnknownTaskError: `task` is unknown.
        """
        parsed = parse_task(task)
        epochs = self.options.refine_config().resolve().epochs
        with self._lock:
            if self._closed:
                raise ConfigError("the app is shutting down; no new clean jobs")
            if self._job is not None and not self._job.finished:
                raise ConfigError(
                    f"a clean job for {self._job.task} is running; try again when it finishes"
                )
            job = CleanJob(parsed, epochs, owner)
            self._job = job
            messages: Any
            if self.processes:
                context = multiprocessing.get_context("spawn")
                messages = context.Queue()
                self._process = context.Process(
                    target=run_clean_job,
                    args=(self.recordings_dir, parsed, self.options, messages, True),
                    name=f"bt-clean-{parsed}",
                    daemon=True,
                )
                self._process.start()
                target, args = self._read_process, (job, messages, self._process)
            else:
                messages = queue.Queue()
                target, args = self._run_inline, (job, messages)
            self._thread = threading.Thread(
                target=target, args=args, name=f"bt-clean-{parsed}", daemon=True
            )
            self._thread.start()
        return job

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop a running job (its output is not written) and join the threads."""
        with self._lock:
            self._closed = True
            process, thread = self._process, self._thread
        if process is not None and process.is_alive():
            process.terminate()
            process.join(timeout_s)
        if thread is not None:
            thread.join(timeout_s)

    def _run_inline(self, job: CleanJob, messages: queue.Queue[Any]) -> None:
        worker = threading.Thread(
            target=run_clean_job,
            args=(self.recordings_dir, job.task, self.options, messages, False),
            daemon=True,
        )
        worker.start()
        self._consume(job, messages, worker.is_alive)
        self._finished(job)

    def _read_process(self, job: CleanJob, messages: Any, process: Any) -> None:
        self._consume(job, messages, process.is_alive)
        process.join(5.0)
        self._finished(job)

    def _finished(self, job: CleanJob) -> None:
        if self.on_finish is not None:
            try:
                self.on_finish(job)
            except Exception:
                LOGGER.exception("on_finish of the clean job for %s failed", job.task)

    def _consume(self, job: CleanJob, messages: Any, alive: Any) -> None:
        while True:
            try:
                kind, *payload = messages.get(timeout=0.2)
            except queue.Empty:
                if not alive():
                    job._update(state="failed", message="the clean process stopped unexpectedly")
                    return
                continue
            if kind == "epoch":
                job._update(epoch=payload[0], message=f"refining: epoch {payload[0]}")
            elif kind == "stage":
                job._update(message=payload[0])
            elif kind == "done":
                job.result = payload[1]
                job._update(state="done", output=Path(payload[0]), message="done")
                return
            else:
                job._update(state="failed", message=str(payload[0]))
                return


def run_clean_job(
    recordings_dir: Path,
    task: Task,
    options: CleanOptions,
    messages: Any,
    single_thread: bool,
) -> None:
    """Clean `task`'s raw recordings and write the output; report through `messages`.

    Messages are tuples: ``("stage", text)``, ``("epoch", k)``, then ``("done", output path,
    TaskCleanResult)`` or ``("failed", message)``. Runs in the job's process (or thread).
    """
    try:
        if single_thread:
            import torch

            torch.set_num_threads(1)  # leave the other cores to the sessions
        messages.put(("stage", "reading recordings"))
        output, result = clean_task(
            recordings_dir, task, options, on_epoch=lambda k: messages.put(("epoch", k))
        )
        messages.put(("done", str(output), result))
    except BtError as exc:
        messages.put(("failed", str(exc)))
    except Exception as exc:  # reported in the UI; the app keeps running
        LOGGER.exception("clean job for %s failed", task)
        messages.put(("failed", f"{type(exc).__name__}: {exc}"))


def clean_task(
    recordings_dir: str | Path,
    task: str,
    options: CleanOptions | None = None,
    on_epoch: Any = None,
) -> tuple[Path, TaskCleanResult]:
    """Clean the raw demos in ``<recordings>/<task>/`` and write the cleaned file (and .rrd).

    Args:
        recordings_dir: Root folder of the recordings.
        task: The task.
        options: Cleaner settings; defaults when None. ``write_rrd`` also writes the .rrd.
        on_epoch: Called with the 1-based epoch number after every refinement epoch.

    Returns:
        The cleaned file and the cleaner's result.

    Demos flagged by the take checks (attr ``flags``) and excluded files are skipped (logged).

    Raises:
        RecordingError: No readable recordings.
        DemoError: No usable demos, or a demo that cannot be cleaned.
    """
    from bt_pipeline.clean.driver import cleaned_recording
    from bt_pipeline.data.demo import demos_from_recording
    from bt_pipeline.data.moderation import is_excluded
    from bt_pipeline.data.paths import expand_paths
    from bt_pipeline.data.recording import read_recordings, write_recording

    options = options or CleanOptions(progress=False)
    parsed = parse_task(task)
    source_dir = task_dir(recordings_dir, parsed)
    try:
        files = expand_paths([source_dir]) if source_dir.is_dir() else []
    except RecordingError:  # an empty folder
        files = []
    if not files:  # the message names no server path: the page shows it
        raise DemoError(f"no recordings of {parsed} yet: record some demos first")
    recordings = [r for r in read_recordings(files, strict=False)]
    sources = {}
    records = {}
    demos = []
    skipped: list[str] = []
    for recording in recordings:
        if recording.task != parsed:
            LOGGER.warning("skipping %s: it holds %s demos", recording.path, recording.task)
            continue
        label = str(recording.path) if recording.path else ""
        if recording.path is not None and is_excluded(recording.path):
            skipped.append(f"{recording.path.name} (excluded)")
            continue
        usable = {name: rec for name, rec in recording.demos.items() if not rec.flags}
        for name, rec in recording.demos.items():
            if rec.flags:  # a take that failed the app's checks (docs/teleop.md)
                skipped.append(f"{Path(label).name}:{name} ({','.join(rec.flags)})")
        if not usable:
            continue
        kept = replace(recording, demos=usable)
        sources[label] = kept
        records.update({(label, name): rec for name, rec in usable.items()})
        demos.extend(demos_from_recording(kept, options.n_samples, file=label))
    for note in skipped:
        LOGGER.info("clean %s: skipping %s", parsed, note)
    if not demos:
        why = f" ({len(skipped)} skipped: flagged or excluded)" if skipped else ""
        raise DemoError(f"no usable demos of {parsed} to clean{why}")
    result = clean_demos(
        demos, options, on_epoch=None if on_epoch is None else lambda s: on_epoch(s.epoch)
    )
    output = write_recording(
        cleaned_path(recordings_dir, parsed),
        cleaned_recording(result, records, sources, options),
        overwrite=True,
    )
    if options.write_rrd:
        from bt_pipeline.viz.rerun_clean import save_clean_rrd

        save_clean_rrd(result, output.with_name(f"{parsed}.rrd"))
    return output, result


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
