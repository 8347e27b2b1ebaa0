"""One clean of a task's recordings in the app, and where its files go.

::

    <recordings>/<task>/*.hdf5                 raw demos, one file per demo (the input)
    <recordings>/.cleaned/<task>.cleaned.hdf5  the cleaned demos of the task (format v1)
    <recordings>/.cleaned/<task>.rrd           the cleaning result for the Rerun viewer
    <recordings>/.cleaned/bt-outputs.json      the manifest of the output set

:class:`bt_teleop.clean.runner.CleanRunner` runs :func:`clean_task` in a background process.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from bt_pipeline.clean.pipeline import CleanOptions, TaskCleanResult
from bt_pipeline.data.tasks import parse_guided_task
from bt_pipeline.exceptions import DemoError

CLEANED_DIRNAME = ".cleaned"
"""Folder under the recordings root that holds cleaned output (hidden: never scanned as input)."""


def cleaned_dir(recordings_dir: str | Path) -> Path:
    """``<recordings>/.cleaned``."""
    return Path(recordings_dir) / CLEANED_DIRNAME


def cleaned_path(recordings_dir: str | Path, task: str) -> Path:
    """``<recordings>/.cleaned/<task>.cleaned.hdf5``."""
    return cleaned_dir(recordings_dir) / f"{parse_guided_task(task)}.cleaned.hdf5"


def task_dir(recordings_dir: str | Path, task: str) -> Path:
    """``<recordings>/<task>``: the raw demos of `task`."""
    return Path(recordings_dir) / parse_guided_task(task)


def clean_task(
    recordings_dir: str | Path,
    task: str,
    options: CleanOptions | None = None,
    on_epoch: Any = None,
    notes: list[str] | None = None,
) -> tuple[Path, TaskCleanResult]:
    """Clean the raw demos in ``<recordings>/<task>/`` and write the cleaned file (and .rrd).

    Excluded files, flagged demos, unreadable files and demos the cleaner cannot use are skipped
    (a line for each is appended to `notes`); the outputs are published as one set.

    Args:
        recordings_dir: Root folder of the recordings.
        task: The task.
        options: Cleaner settings; defaults when None. ``write_rrd`` also writes the .rrd.
        on_epoch: Called with the 1-based epoch number after every refinement epoch.
        notes: Receives one line per skipped file or demo.

    Returns:
        The cleaned file and the cleaner's result.

    Raises:
        DemoError: No usable demos (the skipped ones are listed).
    """
    from bt_pipeline.clean.driver import cleaned_recording
    from bt_pipeline.clean.skipping import clean_skipping
    from bt_pipeline.data.output_set import OutputSet
    from bt_pipeline.data.recording import write_recording
    from bt_pipeline.data.skipping import read_usable

    options = options or CleanOptions(progress=False)
    notes = notes if notes is not None else []
    parsed = parse_guided_task(task)
    source_dir = task_dir(recordings_dir, parsed)
    if not source_dir.is_dir():
        # Messages reach the page: they name no server path.
        raise DemoError(f"no recordings of {parsed} yet: record some demos first")
    usable = read_usable([source_dir], options.n_samples, strict=False)
    notes.extend(usable.notes)
    demos = [demo for demo in usable.demos if demo.task == parsed]
    notes.extend(
        f"skipped {d.file}: it holds {d.task} demos" for d in usable.demos if d.task != parsed
    )
    sources = {str(r.path) if r.path else "": r for r in usable.recordings}
    if not demos:
        raise DemoError(f"no usable demos of {parsed} to clean ({len(notes)} skipped)")
    result, skipped = clean_skipping(
        demos,
        replace(options, strict=False),
        on_epoch=None if on_epoch is None else lambda s: on_epoch(s.epoch),
    )
    notes.extend(skipped)
    if result is None:
        raise DemoError(f"no usable demos of {parsed} to clean ({len(notes)} skipped)")
    with OutputSet(cleaned_dir(recordings_dir)) as outputs:
        write_recording(
            outputs.path(f"{parsed}.cleaned.hdf5"),
            cleaned_recording(result, usable.records(), sources, options),
            overwrite=True,
        )
        if options.write_rrd:
            from bt_pipeline.viz.rerun_clean import save_clean_rrd

            save_clean_rrd(result, outputs.path(f"{parsed}.rrd"))
        outputs.commit()
    return cleaned_path(recordings_dir, parsed), result
