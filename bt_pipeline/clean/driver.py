"""``bt clean`` over files: read recordings, clean every task, write HDF5 and Rerun outputs.

Skip, don't stop: an excluded file (moderation sidecar), a flagged demo (``DemoRecord.flags``)
and, unless ``--strict``, an unreadable file or a demo the cleaner cannot use (no motion, not
periodic, degenerate) are skipped with a one-line note naming them, and the task is cleaned
without them. Each task's outputs are written as soon as the task is cleaned, into a staging
folder published as one set once every task has succeeded
(:class:`~bt_pipeline.data.output_set.OutputSet`), so an error, Ctrl-C or kill -9 leaves the
outputs of one whole run, and this process holds one task's result at a time, not the run's.
Inputs are opened read-only and never modified.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import sys
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from bt_pipeline.clean.pipeline import CleanOptions, TaskCleanResult
from bt_pipeline.clean.selection import span_attrs
from bt_pipeline.clean.skipping import clean_skipping
from bt_pipeline.clean.stage2.chunked import chunk_sizes
from bt_pipeline.clean.stage2.config import EpochStats
from bt_pipeline.clean.summary import DemoCleanSummary, TaskCleanSummary
from bt_pipeline.data.carry import carried_masks, carried_obs
from bt_pipeline.data.demo import Demo, group_by_task
from bt_pipeline.data.limits import ReadLimits
from bt_pipeline.data.output_set import OutputSet
from bt_pipeline.data.recording import write_recording
from bt_pipeline.data.records import DemoRecord, Recording, forward_difference_actions
from bt_pipeline.data.skipping import read_usable
from bt_pipeline.exceptions import ConfigError, DemoError
from bt_pipeline.execute import ExecutorConfig, iter_jobs, reuse_workers

log = logging.getLogger("bt")


def output_names(demos: Sequence[Demo]) -> list[str]:
    """Names of the cleaned demos: the input names when unique, else ``demo_0..demo_{M-1}``.

    Teleop writes one file per demo, each holding ``demo_0``; their cleaned versions share one
    file, so they are renumbered (``cleaned_from`` names each source).
    """
    names = [demo.name for demo in demos]
    return names if len(set(names)) == len(names) else [f"demo_{k}" for k in range(len(demos))]


def cleaned_recording(
    result: TaskCleanResult,
    records: dict[tuple[str, str], DemoRecord],
    sources: dict[str, Recording],
    options: CleanOptions,
) -> Recording:
    """The format-v1 recording of a task's cleaned demos (mapped back to 3-D)."""
    best = result.demos[result.best_index]
    plane = best.plane
    out: dict[str, DemoRecord] = {}
    for i, (demo, name) in enumerate(zip(result.demos, output_names(result.demos), strict=True)):
        record = records[(demo.file, demo.name)]
        # The cleaned span at the raw sample times inside it: the raw demo's own time base.
        timestamps, uv = result.on_raw_times(i)
        ee_pos = plane.to_world(uv)
        raw, cleaned = result.raw[i], result.cleaned[i]
        moved = result.moved(i)
        out[name] = DemoRecord(
            ee_pos=ee_pos,
            timestamps=timestamps,
            actions=forward_difference_actions(ee_pos, timestamps),
            demonstrator=demo.demonstrator,
            theta_deg=float(result.stage1.thetas[i]),
            rho=float(result.stage1.rhos[i]),
            source=record.source,
            created=record.created,
            ep_meta=record.ep_meta,
            **carried_obs(record, timestamps),  # orientation, gripper, extra obs: not cleaned
            attrs={
                "cleaned_from": f"{demo.file}:{demo.name}",
                "preference_estimated": bool(result.stage1.estimated[i]),
                "utility_raw": raw.utility,
                "utility_cleaned": cleaned.utility,
                "mutual_information": cleaned.mutual_information,
                "mutual_information_raw": raw.mutual_information,
                "loss_symmetry": cleaned.symmetry,
                "loss_closure": cleaned.closure,
                "loss_smoothness": cleaned.smoothness,
                "loss_shape": cleaned.shape,
                "loss_shape_raw": raw.shape,
                "moved_mean": moved[0],
                "moved_max": moved[1],
                "beta_final": float(result.refine.betas[i]),
                **_span_attrs(result, i),
            },
        )
    env_args = sources[best.file].env_args
    names = {(d.file, d.name): n for d, n in zip(result.demos, out, strict=True)}
    return Recording(
        task=result.task,
        plane=plane,
        demos=out,
        env_args=env_args,
        masks=carried_masks({f: r.masks for f, r in sources.items()}, names),
        attrs={
            "best_file": best.file,
            "best_demo": best.name,
            "cleaned_variant": result.refine.variant,
            "cleaned_seed": options.seed,
            "cleaned_epochs": result.refine.epochs,
            **(result.loop.attrs() if result.loop else {}),
        },
    )


def _span_attrs(result: TaskCleanResult, i: int) -> dict[str, Any]:
    """The kept span, cycles and preference confidence of demo i (docs/refinement.md)."""
    if not result.segments:
        return {}
    return span_attrs(result.segments[i], result.preferences[i])


def _clean_task(
    task_demos: tuple[int, list[Demo], CleanOptions],
) -> tuple[TaskCleanResult | None, list[str]]:
    """Clean one task with a progress bar (runs in a worker process when ``workers > 1``).

    Returns:
        The result (None when no demo of the task is usable) and the notes of skipped demos.
    """
    position, demos, options = task_demos
    settings = options.refine_config().resolve()
    chunks = len(chunk_sizes(len(demos), options.chunk_size))
    # Chunks refined elsewhere report through run_jobs' bar over the chunks instead.
    epoch_bar = options.progress and (options.chunk_executor is None or chunks == 1)
    with tqdm(
        total=settings.epochs * chunks,
        desc=f"clean {demos[0].task}" + (f" ({chunks} chunks)" if chunks > 1 else ""),
        unit="epoch",
        position=position,
        leave=True,
        disable=None if epoch_bar else True,  # None: off when stderr is no TTY
        file=sys.stderr,
    ) as bar:

        def on_epoch(stats: EpochStats) -> None:
            bar.update(1)
            bar.set_postfix(loss=f"{stats.loss:.3f}", beta=f"{float(np.mean(stats.betas)):.2f}")

        return clean_skipping(demos, options, on_epoch)


def _iter_tasks(
    jobs: list[tuple[int, list[Demo], CleanOptions]],
    executor: ExecutorConfig,
    options: CleanOptions,
) -> Iterator[tuple[int, tuple[TaskCleanResult | None, list[str]]]]:
    """Clean every task; yield ``(position, outcome)`` as each task finishes.

    A task of at most K demos is one job. A large task (more than ``options.chunk_size`` demos)
    is cleaned here, in this process, one after another, its per-demo steps and Stage 2 chunks
    going out as jobs of `executor` (bt_pipeline.clean.fan_out; a process pool cannot take jobs
    from its own workers); the other tasks then run as one job each, and come back as they
    finish. Every round shares one pool of workers. Nothing is held here after a yield.
    """
    fan_out = executor.kind != "local"
    large = [job for job in jobs if fan_out and len(job[1]) > options.chunk_size]
    small = [job for job in jobs if not (fan_out and len(job[1]) > options.chunk_size)]
    with reuse_workers(executor):  # one pool for every round of jobs (spawn costs seconds)
        for position, demos, task_options in large:
            chunked = dataclasses.replace(task_options, chunk_executor=executor)
            yield position, _clean_task((position, demos, chunked))
        for k, outcome in iter_jobs(
            _clean_task,
            small,
            executor,
            desc="clean tasks",
            progress=options.progress,
            label=lambda job: str(job[1][0].task),
        ):
            yield small[k][0], outcome
            del outcome


def clean_paths(
    paths: Sequence[str | Path],
    out_dir: str | Path,
    options: CleanOptions | None = None,
    limits: ReadLimits | None = None,
    executor: ExecutorConfig | None = None,
) -> list[TaskCleanSummary]:
    """Clean every task found under `paths` and write the outputs into `out_dir`.

    Tasks run as jobs of `executor` (default: ``options.workers`` local processes); outputs are
    written here, in this process, so every executor writes the same files for a seed. Each
    task's outputs are written into the run's staging folder as soon as the task is cleaned and
    its result is then dropped (this process holds one task's result at a time, not M demos'
    worth); the set is published only once every task has succeeded.

    Args:
        paths: Recording files, directories or glob patterns.
        out_dir: Output folder (created if missing).
        options: Settings; defaults when None.
        limits: Read-time bounds on magnitudes and sizes; defaults when None.
        executor: Where the tasks run; ``options.workers`` local processes when None.

    Raises:
        RecordingError: No recordings found, or an unreadable file when strict.
        DemoError: No usable demos, or a demo that cannot be cleaned when strict (named).
        ConfigError: An output would overwrite an input.
    """
    options = options or CleanOptions()
    out_dir = Path(out_dir)
    start = time.perf_counter()
    usable = read_usable(paths, options.n_samples, strict=options.strict, limits=limits)
    files, demos, records = usable.files, list(usable.demos), usable.records()
    sources = {str(r.path) if r.path else "": r for r in usable.recordings}
    if not demos:
        raise DemoError(
            f"no usable demos found in {', '.join(str(p) for p in paths)}"
            + (f" ({'; '.join(usable.notes)})" if usable.notes else "")
        )
    groups = group_by_task(demos)
    read_seconds = time.perf_counter() - start
    inputs = {f.resolve() for f in files}
    for task in groups:
        for suffix in (".cleaned.hdf5", ".rrd"):
            if (out_dir / f"{task}{suffix}").resolve() in inputs:
                raise ConfigError(
                    f"output {out_dir / (task + suffix)} is also an input; choose another --out"
                )

    jobs = [(k, group, options) for k, group in enumerate(groups.values())]
    executor = executor or ExecutorConfig("processes", options.workers)
    # Outputs are staged as each task finishes and published as one set at the end: an error,
    # Ctrl-C or kill -9 before the commit leaves `out_dir` as it was (OutputSet).
    created = not out_dir.exists()
    try:
        summaries, skip_notes = _clean_and_stage(
            jobs, executor, options, out_dir, records, sources, [str(t) for t in groups]
        )
    except BaseException:
        if created:  # a folder this failed run made, now empty again, is removed too
            with contextlib.suppress(OSError):
                out_dir.rmdir()
        raise
    ordered = [summaries[k] for k in sorted(summaries)]
    # Excluded files belong to no known task: their notes go with the first task cleaned.
    task_notes = {group[0].task: skip_notes[k] for k, group, _ in jobs}
    for note in reversed(usable.notes):  # prepended: they keep their order, before the rest
        tasks = [d.task for d, _ in usable.flagged if note.startswith(f"skipped {d.label}:")]
        task = tasks[0] if tasks else ordered[0].task
        task_notes[task] = [note, *task_notes.get(task, [])]
    return [
        dataclasses.replace(
            summary,
            output=out_dir / summary.output.name,
            rrd=None if summary.rrd is None else out_dir / summary.rrd.name,
            seconds=summary.seconds + read_seconds / len(ordered),
            stage_seconds={"read": read_seconds / len(ordered), **summary.stage_seconds},
            notes=(*task_notes.get(summary.task, ()), *summary.notes),
        )
        for summary in ordered
    ]


def _clean_and_stage(
    jobs: list[tuple[int, list[Demo], CleanOptions]],
    executor: ExecutorConfig,
    options: CleanOptions,
    out_dir: Path,
    records: dict[tuple[str, str], DemoRecord],
    sources: dict[str, Recording],
    tasks: list[str],
) -> tuple[dict[int, TaskCleanSummary], dict[int, list[str]]]:
    """Clean every task, staging each one's outputs as it finishes; publish them as one set.

    Returns:
        Each cleaned task's summary and each task's skip notes, by the task's position in `jobs`.
    """
    summaries: dict[int, TaskCleanSummary] = {}
    skip_notes: dict[int, list[str]] = {}
    with OutputSet(out_dir) as outputs:
        for line in outputs.recovered:
            log.info("%s", line)
        for position, (result, notes) in _iter_tasks(jobs, executor, options):
            skip_notes[position] = notes
            if result is not None:
                summaries[position] = _write_task(result, outputs, records, sources, options, tasks)
            del result  # written: not held while the other tasks run
        if not summaries:
            notes = [n for k in sorted(skip_notes) for n in skip_notes[k]]
            raise DemoError(f"no task could be cleaned: {'; '.join(notes)}")
        outputs.commit()
    return summaries, skip_notes


def _write_task(
    result: TaskCleanResult,
    outputs: OutputSet,
    records: dict[tuple[str, str], DemoRecord],
    sources: dict[str, Recording],
    options: CleanOptions,
    tasks: list[str],
) -> TaskCleanSummary:
    """Stage one task's outputs in `outputs`; return its summary (paths are the staged ones,
    read time and the file's notes not yet added)."""
    write_start = time.perf_counter()
    output = outputs.path(f"{result.task}.cleaned.hdf5")
    write_recording(output, cleaned_recording(result, records, sources, options), overwrite=True)
    rrd = None
    if options.write_rrd:
        from bt_pipeline.viz.rerun_clean import save_clean_rrd

        # Rerun keeps one layout per app id: every file carries a tab for each task of the
        # run, so opening several of them together shows all tasks.
        rrd = outputs.path(f"{result.task}.rrd")
        save_clean_rrd(result, rrd, blueprint_tasks=tasks)
    stage_seconds = {**result.seconds, "write": time.perf_counter() - write_start}
    for note in result.notes:
        log.info("%s: %s", result.task, note)
    best = result.demos[result.best_index]
    return TaskCleanSummary(
        task=result.task,
        best_file=best.file,
        best_demo=best.name,
        output=output,
        rrd=rrd,
        seconds=sum(stage_seconds.values()),
        stage_seconds=stage_seconds,
        demos=tuple(
            DemoCleanSummary(
                file=demo.file,
                demo=demo.name,
                output_demo=name,
                demonstrator=demo.demonstrator,
                utility_raw=result.raw[i].utility,
                utility_cleaned=result.cleaned[i].utility,
                shape_loss_raw=result.raw[i].shape,
                shape_loss_cleaned=result.cleaned[i].shape,
                beta_final=float(result.refine.betas[i]),
                moved_mean=result.moved(i)[0],
                moved_max=result.moved(i)[1],
                objective_raw=result.raw[i].objective,
                objective_cleaned=result.cleaned[i].objective,
                best=i == result.best_index,
            )
            for i, (demo, name) in enumerate(
                zip(result.demos, output_names(result.demos), strict=True)
            )
        ),
        notes=result.notes,
        best_reason=result.best_reason,
    )
