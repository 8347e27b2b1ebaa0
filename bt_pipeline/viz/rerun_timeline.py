"""Demos on a ``time`` timeline in Rerun: scrub the end effector in 3-D and in the task plane.

Shared by ``bt view`` (:mod:`bt_pipeline.viz.view`) and ``bt clean``'s .rrd (raw and cleaned
side by side). Entity layout under a root such as ``/<task>/timeline``::

    <root>/world                      static: Transform3D (identity), the task plane (Mesh3D)
    <root>/world/<group>/<demo>/path  static: the whole 3-D path
    <root>/world/<group>/<demo>/ee    Points3D on ``time`` (seconds from the demo's start)
    <root>/plane/<group>/<demo>/path  static: the whole 2-D path in task coordinates [m]
    <root>/plane/<group>/<demo>/ee    Points2D on ``time``
    <root>/scores/utility             static BarChart of Ũ, one bar per demo (groups in order)
    <root>/legend                     static TextDocument: each demo's colour and name

``<group>`` is e.g. ``raw`` or ``cleaned``; ``<demo>`` is one entity per demo, named as the web
app's page names it (who and when, :mod:`bt_pipeline.viz.demo_style`). A raw path is thin and
lighter, a cleaned one wide in the demo's full colour. Whole trajectories are sent as columns
(``send_columns``), one row per sample, so the viewer's time slider moves every demo's end
effector at once.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.records import FloatArray
from bt_pipeline.viz.demo_style import (
    CLEANED_RADIUS_UI,
    RAW_RADIUS_UI,
    cleaned_color,
    demo_color,
    demo_names,
    legend_markdown,
    raw_color,
)

if TYPE_CHECKING:  # the cleaner's types only: `bt view` must not import torch
    from bt_pipeline.clean.pipeline import TaskCleanResult

TIME_TIMELINE = "time"
"""Duration timeline: seconds since each demo's first sample."""
_PLANE_MARGIN_M = 0.03


@dataclass(frozen=True)
class TimelineDemo:
    """One demo to put on the timeline."""

    name: str
    """Entity name (made path-safe by :func:`entity_name`)."""
    group: str
    """``raw``, ``cleaned`` or another group name."""
    ee_pos: FloatArray
    """End-effector positions in the world frame, shape (T, 3), in [m]."""
    timestamps: FloatArray
    """Sample times, shape (T,), in [s] (shifted to start at 0)."""
    color: tuple[int, int, int]
    """RGB of the demo (its hue: raw drawn lighter, cleaned in the full colour)."""
    utility: float | None = None
    """Ũ (Eq. 8), or None when not scored."""
    cleaned: bool = False
    """A cleaned demo: drawn wide in its full colour (a raw one thin and lighter)."""
    best: bool = False
    """The task's best demo (★ in the scores table)."""
    best_reason: str = ""
    """On the best demo: why it is the best though another has a higher Ũ (the shape gate's
    line, as ``bt score`` prints it), shown under the scores table; empty otherwise."""


def entity_name(text: str) -> str:
    """A Rerun path part from free text (file or demonstrator names): [A-Za-z0-9_-] only."""
    return re.sub(r"[^A-Za-z0-9_-]+", "_", text).strip("_") or "demo"


def log_timeline(
    rec: rr.RecordingStream,
    root: str,
    plane: TaskPlane,
    demos: Sequence[TimelineDemo],
    legend: str | None = None,
) -> None:
    """Log `demos` under `root` (layout in the module docstring); `legend`: the Markdown of
    ``<root>/legend`` (:func:`bt_pipeline.viz.demo_style.legend_markdown`)."""
    rec.log(f"{root}/plane", rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)  # +v up
    rec.log(f"{root}/world/task_plane", _plane_mesh(plane, demos), static=True)
    for demo in demos:
        name = f"{entity_name(demo.group)}/{entity_name(demo.name)}"
        uv = plane.to_plane(demo.ee_pos)
        t = np.asarray(demo.timestamps, dtype=np.float64) - float(demo.timestamps[0])
        if demo.cleaned:
            color, radius = cleaned_color(demo.color), rr.Radius.ui_points(CLEANED_RADIUS_UI)
        else:
            color, radius = raw_color(demo.color), rr.Radius.ui_points(RAW_RADIUS_UI)
        label = f"{demo.name} ({'cleaned' if demo.cleaned else 'raw'})"
        rec.log(
            f"{root}/world/{name}/path",
            rr.LineStrips3D(
                [demo.ee_pos.astype(np.float32)], colors=[color], radii=radius, labels=[label]
            ),
            static=True,
        )
        rec.log(
            f"{root}/plane/{name}/path",
            rr.LineStrips2D([uv.astype(np.float32)], colors=[color], radii=radius, labels=[label]),
            static=True,
        )
        index = [rr.TimeColumn(TIME_TIMELINE, duration=t)]
        rec.send_columns(
            f"{root}/world/{name}/ee",
            indexes=index,
            columns=rr.Points3D.columns(positions=demo.ee_pos.astype(np.float32)),
        )
        rec.send_columns(
            f"{root}/plane/{name}/ee",
            indexes=index,
            columns=rr.Points2D.columns(positions=uv.astype(np.float32)),
        )
        for kind in ("world", "plane"):
            point = rr.Points3D if kind == "world" else rr.Points2D
            rec.log(
                f"{root}/{kind}/{name}/ee",
                point.from_fields(colors=[color], radii=0.006, labels=[demo.name]),
                static=True,
            )
    if legend is not None:
        rec.log(
            f"{root}/legend",
            rr.TextDocument(legend, media_type=rr.MediaType.MARKDOWN),
            static=True,
        )
    scored = [d for d in demos if d.utility is not None]
    if scored:
        rec.log(
            f"{root}/scores/utility",
            rr.BarChart(np.array([d.utility for d in scored], dtype=np.float64)),
            static=True,
        )
    if demos:
        rows = [
            f"| {i} | {_md(d.group)} | {_md(d.name)}{' ★' if d.best else ''} | {d.utility:.3f} |"
            for i, d in enumerate(scored)
        ]
        # Flagged, excluded or unscorable demos: listed, not ranked (as bt score lists them).
        rows += [f"| – | {_md(d.group)} | {_md(d.name)} | – |" for d in demos if d.utility is None]
        reasons = "".join(f"\n★ {_md(d.best_reason)}\n" for d in scored if d.best_reason)
        rec.log(
            f"{root}/scores/table",
            rr.TextDocument(
                "| bar | group | demo | Ũ |\n|---|---|---|---|\n" + "\n".join(rows) + "\n"
                f"{reasons}\nŨ is relative to the task's raw demos shown here (a cleaned "
                "demo's: on their scale), as bt score reads them; – not scored (flagged, "
                "excluded or no loop).\n",
                media_type=rr.MediaType.MARKDOWN,
            ),
            static=True,
        )


def timeline_views(root: str, title: str) -> rrb.Container:
    """The 3-D view, the 2-D plane view and the scores of one timeline root."""
    return rrb.Horizontal(
        rrb.Spatial3DView(name=f"{title}: end effector (3-D)", origin=f"{root}/world"),
        rrb.Spatial2DView(name=f"{title}: task plane (u, v)", origin=f"{root}/plane"),
        rrb.Vertical(
            rrb.BarChartView(name=f"{title}: Ũ per demo", origin=f"{root}/scores/utility"),
            rrb.TextDocumentView(name=f"{title}: scores", origin=f"{root}/scores/table"),
            rrb.TextDocumentView(name=f"{title}: legend", origin=f"{root}/legend"),
        ),
        column_shares=[3, 3, 2],
        name=title,
    )


def _plane_mesh(plane: TaskPlane, demos: Sequence[TimelineDemo]) -> rr.Mesh3D:
    """A translucent rectangle of the task plane covering every demo's projection."""
    if demos:
        uv = np.concatenate([plane.to_plane(d.ee_pos) for d in demos])
        lo, hi = uv.min(axis=0) - _PLANE_MARGIN_M, uv.max(axis=0) + _PLANE_MARGIN_M
    else:
        lo, hi = np.array([-0.1, -0.1]), np.array([0.1, 0.1])
    corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    return rr.Mesh3D(
        vertex_positions=plane.to_world(corners).astype(np.float32),
        triangle_indices=np.array([[0, 1, 2], [0, 2, 3]], dtype=np.uint32),
        vertex_colors=np.tile(np.array([[120, 160, 220, 60]], dtype=np.uint8), (4, 1)),
    )


def _md(text: str) -> str:
    """Free text made safe in a Markdown table cell (no HTML, no pipes)."""
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace("|", "\\|")


def log_clean_timeline(rec: rr.RecordingStream, root: str, result: TaskCleanResult) -> None:
    """Each demo twice under `root`, raw (thin, lighter) and cleaned (wide, its full colour),
    on one time axis, with a legend.

    Both have the pipeline's N samples spread over the demo's recorded duration.
    """
    plane = result.demos[result.best_index].plane
    names = demo_names(result.demos)
    demos = []
    for group, paths, metrics in (
        ("raw", [d.positions for d in result.demos], result.raw),
        ("cleaned", list(result.positions), result.cleaned),
    ):
        for k, (demo, uv, metric) in enumerate(zip(result.demos, paths, metrics, strict=True)):
            is_best = group == "raw" and k == result.best_index
            demos.append(
                TimelineDemo(
                    name=names[k],
                    group=group,
                    ee_pos=plane.to_world(uv),
                    timestamps=np.linspace(0.0, demo.duration_s, len(uv)),
                    color=demo_color(k),
                    utility=float(metric.utility),
                    cleaned=group == "cleaned",
                    best=is_best,
                    best_reason=result.best_reason if is_best else "",
                )
            )
    log_timeline(rec, root, plane, demos, legend_markdown(names, best=result.best_index))
