"""Rerun logging of the cleaner's result: one task's demos, references, value map, scores, training.

Data flow (I/O at the edge: the cleaner never imports this module)::

    TaskCleanResult ──log_clean_result(rec)──▶ any RecordingStream (file, gRPC, web viewer)
        static:  /<task>/plane/{raw,best,reference,centre,aligned,cleaned,value_map}
                 /<task>/scores/<metric>/{raw,cleaned}, /<task>/summary, /<task>/legend
        columns: /<task>/training/{loss,beta/<demo>,reward/<demo>} on the ``epoch`` timeline,
                 /<task>/notes at epoch 0
    clean_blueprint(tasks) ──▶ the layout, declared up front and sent with the recording
    save_clean_rrd(result, path) ──▶ <path>.rrd, written to a temporary file then os.replace'd

Task coordinates stay in metres. Rerun's 2-D views draw +y downwards (image convention), so
``/<task>/plane`` carries a static Transform3D with scale (1, -1, 1): curves appear with +y up,
as in matplotlib plots, while every logged value (and hover read-out) is in task coordinates.
Demos are named and coloured as everywhere in bt (:mod:`bt_pipeline.viz.demo_style`: who and
when, one colour each, raw thin and light, cleaned wide and saturated). docs/rerun.md lists every
entity path.
"""

from __future__ import annotations

import hashlib
import os
import uuid
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import rerun as rr

from bt_pipeline.clean.pipeline import DemoMetrics, TaskCleanResult
from bt_pipeline.clean.stage2.config import EpochStats
from bt_pipeline.data.demo import Demo
from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.tasks import Task
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.viz.clean_blueprint import (
    EPOCH_TIMELINE,
    METRICS,
    clean_blueprint,
    plane_views,
    task_layout,
)
from bt_pipeline.viz.demo_style import (
    CLEANED_RADIUS_UI,
    RAW_RADIUS_UI,
    cleaned_color,
    demo_colors,
    demo_names,
    legend_markdown,
    raw_color,
)
from bt_pipeline.viz.rerun_timeline import log_clean_timeline
from bt_pipeline.viz.rrd import save_rrd

APP_ID = "bt_clean"
"""Rerun application id of every cleaner recording."""

_ALIGNED_ALPHA = 90  # Aligned references: the demo's hue, translucent and thinnest.
_ALIGNED_RADIUS_UI = 0.5
_BEST_RGBA = (255, 215, 0, 200)  # Gold halo under the best raw demo (x^d drawn between).
_REFERENCE_RGBA = (245, 245, 245, 255)
_RAW_BAR_RGBA = (150, 150, 150, 255)
_CLEANED_BAR_RGBA = (80, 200, 120, 255)
_LOSS_RGBA = (230, 230, 230, 255)
_BAR_WIDTH = 0.4  # Raw bar at i - 0.2, cleaned bar at i + 0.2.
_ID_NAMESPACE = uuid.UUID("5b0c1c5e-7a3e-4c58-9c39-0d2b7f3e6a10")


def demo_entity_names(demos: Sequence[Demo]) -> tuple[str, ...]:
    """Entity-path-safe, unique names as the web app's page names the demos: who and when, e.g.
    ``alice_12-06_120301`` (:func:`bt_pipeline.viz.demo_style.demo_names`)."""
    return demo_names(demos)


def recording_id(result: TaskCleanResult) -> str:
    """A recording id that depends only on the task, its raw demos and its cleaned demos."""
    digest = hashlib.sha256(result.task.encode())
    for demo in result.demos:
        digest.update(demo.name.encode())
        digest.update(np.ascontiguousarray(demo.positions).tobytes())
    digest.update(np.ascontiguousarray(result.positions).tobytes())
    return str(uuid.uuid5(_ID_NAMESPACE, f"{result.task}:{digest.hexdigest()}"))


def log_clean_result(rec: rr.RecordingStream, result: TaskCleanResult) -> None:
    """Log everything the cleaner computed for one task under ``/<task>`` on `rec`.

    Spatial data, scores and the summary are static; the β, reward and loss histories are sent
    as columns on the ``epoch`` timeline (epochs 1..K), the notes at epoch 0. The blueprint is
    not sent here (see :func:`clean_blueprint`): the same call serves a file or a live viewer.

    Args:
        rec: The recording stream to log to (never the global one).
        result: One task's cleaning result.
    """
    root = f"/{result.task}"
    names = demo_entity_names(result.demos)
    colors = demo_colors(len(result.demos))
    _log_plane(rec, root, result, names, colors)
    _log_scores(rec, root, result.raw, result.cleaned)
    _log_training(rec, root, result, names, colors)
    _log_text(rec, root, result, names)
    rec.log(
        f"{root}/legend",
        rr.TextDocument(legend_markdown(names, best=result.best_index), media_type="text/markdown"),
        static=True,
    )
    log_clean_timeline(rec, f"{root}/timeline", result)  # the `time` timeline of bt view


def log_epoch(rec: rr.RecordingStream, task: Task, stats: EpochStats, names: Sequence[str]) -> None:
    """Log one refinement epoch live (an ``on_epoch`` callback of ``clean_demos``).

    Writes the same entities as :func:`log_clean_result`'s training history, one row at a time.

    Args:
        rec: The recording stream to log to.
        task: The task being cleaned.
        stats: What the epoch did.
        names: Entity names of the demos, :func:`demo_entity_names` of the input demos.
    """
    root = f"/{task}/training"
    rec.set_time(EPOCH_TIMELINE, sequence=stats.epoch)
    rec.log(f"{root}/loss", rr.Scalars(stats.loss))
    for i, name in enumerate(names):
        rec.log(f"{root}/beta/{name}", rr.Scalars(float(stats.betas[i])))
        rec.log(f"{root}/reward/{name}", rr.Scalars(float(stats.rewards[i])))
    rec.disable_timeline(EPOCH_TIMELINE)


def save_clean_rrd(
    result: TaskCleanResult,
    path: str | os.PathLike[str],
    *,
    blueprint_tasks: Iterable[Task] | None = None,
) -> Path:
    """Write one task's result and its blueprint to an .rrd file, atomically.

    The stream has application id ``bt_clean``, a recording id from :func:`recording_id` and no
    wall-clock ``log_time`` timeline. It is written to a temporary file beside `path`, closed
    (footer written), fsynced, then moved into place; on any failure the temporary file is
    removed and `path` is left as it was.

    Args:
        result: One task's cleaning result.
        path: Destination, ending in ``.rrd``; missing parent directories are created.
        blueprint_tasks: Tasks the sent layout has tabs for; the result's task when None. Rerun
            keeps one active layout per application id, so the files of one run can all carry
            the run's tasks and be opened together.

    Returns:
        `path` as a Path.

    Raises:
        ConfigError: `path` does not end in .rrd, or Rerun is disabled (RERUN=off).
        UnknownTaskError: `blueprint_tasks` holds an invalid task name.
    """
    path = Path(path)
    if path.suffix != ".rrd":
        raise ConfigError(f"a Rerun recording must end in .rrd; got {path}")
    blueprint = clean_blueprint([result.task] if blueprint_tasks is None else blueprint_tasks)
    return save_rrd(
        path,
        app_id=APP_ID,
        recording_id=recording_id(result),
        name=f"bt clean: {result.task}",
        blueprint=blueprint,
        log=lambda rec: log_clean_result(rec, result),
        disabled_hint="pass --no-rrd",
    )


def _log_plane(
    rec: rr.RecordingStream,
    root: str,
    result: TaskCleanResult,
    names: Sequence[str],
    colors: np.ndarray,
) -> None:
    """Static 2-D content in task coordinates [m] under ``<root>/plane``."""
    plane = f"{root}/plane"
    stage1 = result.stage1
    rec.log(plane, rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
    vm = stage1.value_map
    dx = float(vm.x_centres[1] - vm.x_centres[0])
    dy = float(vm.y_centres[1] - vm.y_centres[0])
    rec.log(
        f"{plane}/value_map",
        # Pixel (i, j) covers [i, i+1] x [j, j+1]: its centre lands on node (x_i, y_j).
        rr.Transform3D(
            translation=[float(vm.x_centres[0]) - dx / 2, float(vm.y_centres[0]) - dy / 2, 0.0],
            scale=[dx, dy, 1.0],
        ),
        rr.DepthImage(
            vm.values.astype(np.float32),
            meter=1.0,
            colormap="viridis",
            depth_range=[0.0, 1.0],
            magnification_filter="linear",
            draw_order=-50.0,
        ),
        static=True,
    )
    best = result.best_index
    rec.log(
        f"{plane}/best",
        _strip(result.demos[best].positions, _BEST_RGBA, 4.0, 25.0, f"best: {names[best]}"),
        static=True,
    )
    rec.log(
        f"{plane}/reference",
        _strip(stage1.reference, _REFERENCE_RGBA, 0.75, 28.0, "x^d (DMP)"),
        static=True,
    )
    rec.log(
        f"{plane}/centre",
        rr.Points2D([stage1.centre], colors=[_REFERENCE_RGBA], radii=rr.Radius.ui_points(4.0)),
        static=True,
    )
    for i, (demo, name) in enumerate(zip(result.demos, names, strict=True)):
        rgb = tuple(int(c) for c in colors[i])
        raw = _strip(demo.positions, raw_color(rgb), RAW_RADIUS_UI, 30.0, f"raw {name}")
        rec.log(f"{plane}/raw/{name}", raw, static=True)
        aligned = (*rgb, _ALIGNED_ALPHA)
        rec.log(
            f"{plane}/aligned/{name}",
            _strip(stage1.aligned[i], aligned, _ALIGNED_RADIUS_UI, 20.0, f"aligned {name}"),
            static=True,
        )
        rec.log(
            f"{plane}/cleaned/{name}",
            _strip(
                result.positions[i], cleaned_color(rgb), CLEANED_RADIUS_UI, 31.0, f"cleaned {name}"
            ),
            static=True,
        )


def _strip(
    points: FloatArray, color: Sequence[int], radius_ui: float, draw_order: float, label: str
) -> rr.LineStrips2D:
    """One labelled line strip, shape (N, 2) [m], with a radius in UI points."""
    return rr.LineStrips2D(
        [np.asarray(points, dtype=np.float32)],
        colors=[color],
        radii=rr.Radius.ui_points(radius_ui),
        labels=[label],
        show_labels=False,
        draw_order=draw_order,
    )


def _log_scores(
    rec: rr.RecordingStream,
    root: str,
    raw: Sequence[DemoMetrics],
    cleaned: Sequence[DemoMetrics],
) -> None:
    """Per metric, two static bar charts: bar i is demo i, raw at i - 0.2, cleaned at i + 0.2."""
    index = np.arange(len(raw), dtype=np.float64)
    widths = np.full(len(raw), _BAR_WIDTH, dtype=np.float32)
    for metric, _ in METRICS:
        for kind, metrics, offset, color in (
            ("raw", raw, -_BAR_WIDTH / 2, _RAW_BAR_RGBA),
            ("cleaned", cleaned, _BAR_WIDTH / 2, _CLEANED_BAR_RGBA),
        ):
            values = np.array([getattr(m, metric) for m in metrics], dtype=np.float64)
            rec.log(
                f"{root}/scores/{metric}/{kind}",
                rr.BarChart(values, abscissa=index + offset, widths=widths, color=color),
                static=True,
            )


def _log_training(
    rec: rr.RecordingStream,
    root: str,
    result: TaskCleanResult,
    names: Sequence[str],
    colors: np.ndarray,
) -> None:
    """Loss, β_i and R̄_i per epoch as columns on the epoch timeline, plus static series styles."""
    refine = result.refine
    k = int(refine.loss_history.shape[0])
    epochs = rr.TimeColumn(EPOCH_TIMELINE, sequence=np.arange(1, k + 1))
    series: list[tuple[str, str, tuple[int, ...], FloatArray]] = [
        (f"{root}/training/loss", "loss", _LOSS_RGBA, refine.loss_history)
    ]
    for i, name in enumerate(names):
        rgb = tuple(int(c) for c in colors[i])
        series.append((f"{root}/training/beta/{name}", f"β {name}", rgb, refine.beta_history[:, i]))
        series.append(
            (f"{root}/training/reward/{name}", f"R̄ {name}", rgb, refine.reward_history[:, i])
        )
    for entity, label, color, values in series:
        rec.log(entity, rr.SeriesLines(names=[label], colors=[color]), static=True)
        if k:  # A one-demo task runs no epochs.
            rec.send_columns(
                entity,
                indexes=[epochs],
                columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=np.float64)),
            )


def _log_text(
    rec: rr.RecordingStream, root: str, result: TaskCleanResult, names: Sequence[str]
) -> None:
    """The per-demo summary table (static TextDocument) and the notes (TextLog rows)."""
    stage1, refine = result.stage1, result.refine
    rows = [
        "| # | demo | demonstrator | θ [deg] | ρ | Ũ raw → cleaned | L4 raw → off ref. [mm] "
        "| moved mean / max [mm] | β |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for i, name in enumerate(names):
        raw, cleaned = result.raw[i], result.cleaned[i]
        star = " ★" if i == result.best_index else ""
        estimated = " (est.)" if stage1.estimated[i] else ""
        moved_mean, moved_max = result.moved(i)
        rows.append(
            f"| {i} | {name}{star} | {result.demos[i].demonstrator} | "
            f"{stage1.thetas[i]:.1f}{estimated} | {stage1.rhos[i]:.3f} | "
            f"{raw.utility:.3f} → {cleaned.utility:.3f} | "
            f"{1e3 * raw.shape:.2f} → {1e3 * cleaned.shape:.2f} | "
            f"{1e3 * moved_mean:.2f} / {1e3 * moved_max:.2f} | {refine.betas[i]:.3f} |"
        )
    timing = ", ".join(f"{stage} {seconds:.2f} s" for stage, seconds in result.seconds.items())
    safe = result.best_reason.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    reason = f"★ {safe}\n\n" if safe else ""
    text = (
        f"# {result.task}\n\n{len(result.demos)} demos, variant `{refine.variant}`, "
        f"{refine.epochs} epochs; {timing}.\n\nBars: demo i at x = i (raw left, cleaned "
        f"right).\n\n" + "\n".join(rows) + "\n\n" + reason + SUMMARY_LEGEND + "\n"
    )
    rec.log(f"{root}/summary", rr.TextDocument(text, media_type="text/markdown"), static=True)
    best = result.demos[result.best_index]
    texts = [
        f"{result.task}: best demo {best.label} ({best.demonstrator}); "
        f"{refine.epochs} epochs of the {refine.variant} variant",
        *result.notes,
    ]
    levels = [rr.TextLogLevel.INFO] + [rr.TextLogLevel.WARN] * len(result.notes)
    # At epoch 0 (before refinement): a text log view lists timeline rows, not static ones.
    rec.send_columns(
        f"{root}/notes",
        indexes=[rr.TimeColumn(EPOCH_TIMELINE, sequence=np.zeros(len(texts), dtype=np.int64))],
        columns=rr.TextLog.columns(text=texts, level=levels),
    )


SUMMARY_LEGEND = (
    "Ũ: over the task's raw demos, as `bt score` reads them (cleaned: against their scale). "
    "L4 raw: the raw demo's mean distance from its aligned reference (Eq. 9); off ref.: the "
    "cleaned demo's (0 when cleaning followed the reference fully). Moved: distance between "
    "each raw sample and the cleaned demo at the same time."
)
"""Under the summary table: what its columns measure (as under ``bt clean``'s table)."""


__all__ = [
    "APP_ID",
    "EPOCH_TIMELINE",
    "METRICS",
    "SUMMARY_LEGEND",
    "clean_blueprint",
    "log_clean_result",
    "log_epoch",
    "plane_views",
    "save_clean_rrd",
    "task_layout",
]
