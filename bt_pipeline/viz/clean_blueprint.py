"""The Rerun viewer layout of ``bt clean`` recordings: per task, the plane views, the score bars,
the training curves and the summary (:mod:`bt_pipeline.viz.rerun_clean` logs what they show)."""

from __future__ import annotations

from collections.abc import Iterable

import rerun.blueprint as rrb

from bt_pipeline.data.tasks import Task, parse_task
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.viz.rerun_timeline import timeline_views

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
            name=f"{task}: cleaned demos (wide) over raw (thin) and aligned references",
            origin=root,
            contents=[
                f"{plane}/cleaned/**",
                f"{plane}/raw/**",
                f"{plane}/aligned/**",
                f"{plane}/centre",
            ],
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
        rrb.TextDocumentView(name="legend", origin=f"{root}/legend"),
        rrb.TextLogView(name="notes", origin=f"{root}/notes"),
        column_shares=[3, 1, 2],
    )
    return rrb.Vertical(
        curves,
        rrb.Horizontal(bars, training, column_shares=[3, 2]),
        text,
        row_shares=[5, 4, 3],
        name=task,
    )
