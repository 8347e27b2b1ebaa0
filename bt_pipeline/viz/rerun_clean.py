"""Rerun logging of the cleaner's result: one task's demos, references, value map, scores, training.

Data flow (I/O at the edge: the cleaner never imports this module)::

    TaskCleanResult ──log_clean_result(rec)──▶ any RecordingStream (file, gRPC, web viewer)
        static:  /<task>/plane/{raw,best,reference,centre,aligned,cleaned,value_map}
                 /<task>/scores/<metric>/{raw,cleaned}, /<task>/summary
        columns: /<task>/training/{loss,beta/<demo>,reward/<demo>} on the ``epoch`` timeline,
                 /<task>/notes at epoch 0
    clean_blueprint(tasks) ──▶ the layout, declared up front and sent with the recording
    save_clean_rrd(result, path) ──▶ <path>.rrd, written to a temporary file then os.replace'd

Task coordinates stay in metres. Rerun's 2-D views draw +y downwards (image convention), so
``/<task>/plane`` carries a static Transform3D with scale (1, -1, 1): curves appear with +y up,
as in matplotlib plots, while every logged value (and hover read-out) is in task coordinates.
docs/rerun.md lists every entity path.
"""

from __future__ import annotations

import hashlib
import os
import re
import uuid
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from bt_pipeline.clean.pipeline import DemoMetrics, TaskCleanResult
from bt_pipeline.clean.stage2.config import EpochStats
from bt_pipeline.data.demo import Demo
from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.tasks import Task, parse_task
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.viz.rerun_timeline import log_clean_timeline, timeline_views
from bt_pipeline.viz.rrd import demo_colors, save_rrd

APP_ID = "bt_clean"
"""Rerun application id of every cleaner recording."""
EPOCH_TIMELINE = "epoch"
"""Sequence timeline of the refinement history; epoch k (1-based) is the state after epoch k."""
METRICS: tuple[tuple[str, str], ...] = (
    ("utility", "Ũ (Eq. 8)"),
    ("mutual_information", "I(S; A) [nats]"),
    ("symmetry", "L1 symmetry [m]"),
    ("closure", "L2 closure [m]"),
    ("smoothness", "L3 smoothness"),
    ("shape", "L4 shape [m]"),
)
"""(DemoMetrics attribute, chart title) of each per-demo bar chart."""

_ALIGNED_ALPHA = 110  # Aligned references: the demo's hue, translucent and thin.
_BEST_RGBA = (255, 215, 0, 200)  # Gold halo under the best raw demo (x^d drawn between).
_REFERENCE_RGBA = (245, 245, 245, 255)
_RAW_BAR_RGBA = (150, 150, 150, 255)
_CLEANED_BAR_RGBA = (80, 200, 120, 255)
_LOSS_RGBA = (230, 230, 230, 255)
_BAR_WIDTH = 0.4  # Raw bar at i - 0.2, cleaned bar at i + 0.2.
_ID_NAMESPACE = uuid.UUID("5b0c1c5e-7a3e-4c58-9c39-0d2b7f3e6a10")


def demo_entity_names(demos: Sequence[Demo]) -> tuple[str, ...]:
    """Entity-path-safe, unique names: the demo names, prefixed by the index if they repeat.

    Characters other than letters, digits, ``_`` and ``-`` become ``_``.
    """
    names = [re.sub(r"[^A-Za-z0-9_-]", "_", demo.name) or "demo" for demo in demos]
    if len(set(names)) < len(names):
        names = [f"{i}_{name}" for i, name in enumerate(names)]
    return tuple(names)


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


def clean_blueprint(tasks: Iterable[Task]) -> rrb.Blueprint:
    """The viewer layout for cleaner recordings of `tasks` (one tab per task when several).

    Per task: a 2-D view of raw demos, best demo, x^d, aligned references and V_E; a 2-D view of
    the cleaned demos over their aligned references; a grid of bar charts (raw vs cleaned per
    metric); time series of loss, β_i and R̄_i per epoch; the summary table and the notes.

    Raises:
        UnknownTaskError: An invalid task name (:func:`~bt_pipeline.data.tasks.parse_task`).
        ConfigError: No tasks.
    """
    parsed: list[Task] = [parse_task(str(name)) for name in tasks]
    if not parsed:
        raise ConfigError("clean_blueprint needs at least one task")
    unique: list[Task] = [t for i, t in enumerate(parsed) if t not in parsed[:i]]
    layouts = [task_layout(t) for t in unique]
    layouts += [timeline_views(f"/{t}/timeline", f"{t}: raw vs cleaned in time") for t in unique]
    main = rrb.Tabs(*layouts)
    return rrb.Blueprint(
        main,
        rrb.TimePanel(timeline=EPOCH_TIMELINE, state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
    )


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
        label = f"{name} ({demo.demonstrator})"
        rec.log(f"{plane}/raw/{name}", _strip(demo.positions, rgb, 1.0, 30.0, label), static=True)
        rec.log(
            f"{plane}/aligned/{name}",
            _strip(stage1.aligned[i], (*rgb, _ALIGNED_ALPHA), 0.75, 20.0, f"aligned {name}"),
            static=True,
        )
        rec.log(
            f"{plane}/cleaned/{name}",
            _strip(result.positions[i], rgb, 1.25, 30.0, f"cleaned {name}"),
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
        "| # | demo | demonstrator | θ [deg] | ρ | Ũ raw → cleaned | L4 raw → cleaned [mm] | β |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for i, name in enumerate(names):
        raw, cleaned = result.raw[i], result.cleaned[i]
        star = " (best)" if i == result.best_index else ""
        estimated = " (est.)" if stage1.estimated[i] else ""
        rows.append(
            f"| {i} | {name}{star} | {result.demos[i].demonstrator} | "
            f"{stage1.thetas[i]:.1f}{estimated} | {stage1.rhos[i]:.3f} | "
            f"{raw.utility:.3f} → {cleaned.utility:.3f} | "
            f"{1e3 * raw.shape:.2f} → {1e3 * cleaned.shape:.2f} | {refine.betas[i]:.3f} |"
        )
    timing = ", ".join(f"{stage} {seconds:.2f} s" for stage, seconds in result.seconds.items())
    text = (
        f"# {result.task}\n\n{len(result.demos)} demos, variant `{refine.variant}`, "
        f"{refine.epochs} epochs; {timing}.\n\nBars: demo i at x = i (raw left, cleaned "
        f"right).\n\n" + "\n".join(rows) + "\n"
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


def plane_views(task: Task) -> tuple[rrb.Spatial2DView, rrb.Spatial2DView]:
    """A task's two 2-D views: raw demos, best, x^d, aligned references, V_E; cleaned demos."""
    root = f"/{task}"
    plane = f"{root}/plane"
    return (
        rrb.Spatial2DView(
            name=f"{task}: raw demos, x^d, aligned references, V_E",
            origin=root,
            contents=[
                f"{plane}/{part}"
                for part in ("value_map", "raw/**", "best", "reference", "centre", "aligned/**")
            ],
        ),
        rrb.Spatial2DView(
            name=f"{task}: cleaned demos over aligned references",
            origin=root,
            contents=[f"{plane}/cleaned/**", f"{plane}/aligned/**", f"{plane}/centre"],
        ),
    )


def task_layout(task: Task) -> rrb.Container:
    """One task's views."""
    root = f"/{task}"
    curves = rrb.Horizontal(*plane_views(task))
    bars = rrb.Grid(
        *(
            rrb.BarChartView(
                name=f"{title}: raw | cleaned",
                origin=f"{root}/scores/{metric}",
                plot_legend=rrb.PlotLegend(visible=False),
            )
            for metric, title in METRICS
        ),
        grid_columns=3,
        name=f"{task}: scores, raw (grey) vs cleaned (green)",
    )
    training = rrb.Vertical(
        rrb.TimeSeriesView(name="loss −mean Ũ", origin=f"{root}/training/loss"),
        rrb.TimeSeriesView(name="β_i", origin=f"{root}/training/beta"),
        rrb.TimeSeriesView(name="R̄_i (Eq. 11)", origin=f"{root}/training/reward"),
    )
    text = rrb.Horizontal(
        rrb.TextDocumentView(name="summary", origin=f"{root}/summary"),
        rrb.TextLogView(name="notes", origin=f"{root}/notes"),
        column_shares=[3, 2],
    )
    return rrb.Vertical(
        curves,
        rrb.Horizontal(bars, training, column_shares=[3, 2]),
        text,
        row_shares=[5, 4, 3],
        name=task,
    )
