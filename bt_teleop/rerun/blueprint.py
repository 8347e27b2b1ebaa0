"""The layout (Rerun blueprint) of a teleop session's recording.

It is compact on purpose: every view of a blueprint costs the web viewer time on every frame,
and the layout itself is a few messages per view that a viewer ingests, one or a few per frame,
before the data behind them. With the cleaner's full layout per task for all three tasks (43
views), the web viewer in headless Chromium (software WebGL) stayed tens of seconds behind one
session. So a session starts with the robot view and its legend (a text view), and gains a tab
of six views for each task it cleans (:meth:`bt_teleop.rerun.live.SessionLogger.show_cleaned`).
The cleaner's full layout (every metric, the training curves, the notes) is in each Clean's
``<recordings>/.cleaned/<task>.rrd``.

Entities go to views of their own dimension: the robot's 3-D content (``/ee``, ``/demos``,
``/replay``) to the 3-D view, each task's plane content (``/<task>/plane/...``, 2-D) to 2-D
views rooted at ``/<task>``. A 2-D entity under a 3-D view makes the viewer report "2D
visualizers require a pinhole ancestor" and draw nothing.
"""

from __future__ import annotations

from collections.abc import Iterable

import rerun.blueprint as rrb

from bt_pipeline.viz.clean_blueprint import plane_views

__all__ = ["SIM_TIMELINE", "TRAIL_S", "session_blueprint"]

SIM_TIMELINE = "sim_time"
"""Duration timeline: a session's simulation time [s]."""
TRAIL_S = 10.0
"""The robot view draws the end effector's last this many seconds [s] (its trail)."""


def session_blueprint(tasks: Iterable[str] = ()) -> rrb.Blueprint:
    """A session's layout: the robot in 3-D (end effector with its last :data:`TRAIL_S`
    seconds, saved and replayed demos) beside the legend of the saved demos (``/legend``); then
    a tab per task of `tasks` (those cleaned so far): three 2-D views (raw demos, best, x^d,
    aligned references and V_E; cleaned demos over raw demos and their aligned references; the
    DMP rollouts behind V_E), the utility Ũ raw vs cleaned, the cleaner's summary and the
    task's legend. No 2-D entity sits under a 3-D view and no 3-D entity under a 2-D view."""
    live = rrb.Spatial3DView(
        name="robot: end effector, saved and replayed demos",
        origin="/",
        contents=["/ee/**", "/demos/**", "/replay/**"],
        time_ranges=rrb.VisibleTimeRange(
            SIM_TIMELINE,
            start=rrb.TimeRangeBoundary.cursor_relative(seconds=-TRAIL_S),
            end=rrb.TimeRangeBoundary.cursor_relative(),
        ),
    )
    robot = rrb.Horizontal(
        live,
        rrb.TextDocumentView(name="saved demos: legend", origin="/legend"),
        column_shares=[4, 1],
        name="robot",
    )
    return rrb.Blueprint(
        rrb.Tabs(robot, *(_task_tab(task) for task in tasks)),
        rrb.SelectionPanel(state="collapsed"),
    )


def _task_tab(task: str) -> rrb.Container:
    root = f"/{task}"
    plane = f"{root}/plane"
    views = rrb.Horizontal(
        *plane_views(task),
        rrb.Spatial2DView(
            name=f"{task}: DMP rollouts behind V_E",
            origin=root,
            contents=[f"{plane}/value_map", f"{plane}/rollouts/**"],
        ),
    )
    below = rrb.Horizontal(
        rrb.BarChartView(
            name="Ũ (Eq. 8): raw | cleaned",
            origin=f"{root}/scores/utility",
            plot_legend=rrb.PlotLegend(visible=False),
        ),
        rrb.TextDocumentView(name=f"{task}: summary", origin=f"{root}/summary"),
        rrb.TextDocumentView(name=f"{task}: legend", origin=f"{root}/legend"),
        column_shares=[2, 3, 1],
    )
    return rrb.Vertical(views, below, row_shares=[3, 2], name=task)
