"""Rerun logging of ``bt evaluate``: rollouts, references and reward bars, with a blueprint."""

from __future__ import annotations

import hashlib
import uuid
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from bt_pipeline.evaluate.plots import LEARNER_TITLES
from bt_pipeline.evaluate.protocol import (
    DATASETS,
    TaskEvaluation,
)
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.viz.eval_table import markdown_table
from bt_pipeline.viz.rrd import save_rrd

APP_ID = "bt_evaluate"
_ROLLOUT_RGBA = {"noisy": (214, 39, 40, 110), "cleaned": (31, 119, 180, 110)}
_BAR_RGBA = {"noisy": (150, 150, 150, 255), "cleaned": (80, 200, 120, 255)}
_REFERENCE_RGBA = (235, 235, 235, 200)


def log_evaluations(rec: rr.RecordingStream, evaluations: Sequence[TaskEvaluation]) -> None:
    """Log references, rollouts, rewards and the table (all static) to `rec`.

    Entities: ``/<task>/plane`` (y-flip), ``/<task>/plane/references``,
    ``/<task>/plane/<dataset>/<learner>/{rollouts,starts}``, ``/<task>/rewards/<dataset>``
    (bar i is learner i, noisy at i - 0.2, cleaned at i + 0.2) and ``/summary``.
    """
    for e in evaluations:
        plane = f"/{e.task}/plane"
        rec.log(plane, rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
        refs = [np.vstack([r, r[:1]]) for r in e.yardstick.references]  # true loops or best demo
        rec.log(
            f"{plane}/references",
            rr.LineStrips2D(
                [r.astype(np.float32) for r in refs],
                colors=[_REFERENCE_RGBA] * len(refs),
                radii=rr.Radius.ui_points(0.75),
                draw_order=20.0,
            ),
            static=True,
        )
        for r in e.results:
            entity = f"{plane}/{r.dataset}/{r.learner}"
            rec.log(
                f"{entity}/rollouts",
                rr.LineStrips2D(
                    list(r.rollouts.astype(np.float32)),
                    colors=[_ROLLOUT_RGBA[r.dataset]] * r.rollouts.shape[0],
                    radii=rr.Radius.ui_points(0.5),
                    draw_order=30.0,
                ),
                static=True,
            )
            rec.log(
                f"{entity}/starts",
                rr.Points2D(r.rollouts[:, 0].astype(np.float32), radii=rr.Radius.ui_points(1.5)),
                static=True,
            )
        for k, dataset in enumerate(DATASETS):  # bt evaluate has no truth set
            means = [float(np.mean(e.result(learner, dataset).rewards)) for learner in e.learners]
            rec.log(
                f"/{e.task}/rewards/{dataset}",
                rr.BarChart(
                    np.array(means),
                    abscissa=np.arange(len(means), dtype=np.float64) + (k - 0.5) * 0.4,
                    widths=np.full(len(means), 0.4, dtype=np.float32),
                    color=_BAR_RGBA[dataset],
                ),
                static=True,
            )
    rec.log(
        "/summary",
        rr.TextDocument(markdown_table(evaluations), media_type="text/markdown"),
        static=True,
    )


def eval_blueprint(evaluations: Sequence[TaskEvaluation]) -> rrb.Blueprint:
    """A tab per task: a grid of rollout views (rows noisy / cleaned), the rewards and the table."""
    tabs = []
    for e in evaluations:
        root, plane = f"/{e.task}", f"/{e.task}/plane"
        views = [
            rrb.Spatial2DView(
                name=f"{LEARNER_TITLES.get(learner, learner)} {dataset}",
                origin=root,
                contents=[f"{plane}/references", f"{plane}/{dataset}/{learner}/**"],
            )
            for dataset in DATASETS
            for learner in e.learners
        ]
        tabs.append(
            rrb.Vertical(
                rrb.Grid(*views, grid_columns=len(e.learners)),
                rrb.Horizontal(
                    rrb.BarChartView(name="mean R̄: noisy | cleaned", origin=f"{root}/rewards"),
                    rrb.TextDocumentView(name="table", origin="/summary"),
                    column_shares=[1, 2],
                ),
                row_shares=[3, 1],
                name=e.task,
            )
        )
    return rrb.Blueprint(rrb.Tabs(*tabs), collapse_panels=True)


def save_eval_rrd(evaluations: Sequence[TaskEvaluation], path: str | Path) -> Path:
    """Write the evaluations and their blueprint to an .rrd file, atomically (as bt clean does).

    Raises:
        ConfigError: `path` does not end in .rrd, or Rerun is disabled (RERUN=off).
    """
    path = Path(path)
    if path.suffix != ".rrd":
        raise ConfigError(f"a Rerun recording must end in .rrd; got {path}")
    digest = hashlib.sha256()
    for e in evaluations:
        for r in e.results:
            digest.update(np.ascontiguousarray(r.rollouts).tobytes())
    return save_rrd(
        path,
        app_id=APP_ID,
        recording_id=str(uuid.UUID(bytes=digest.digest()[:16])),
        name="bt evaluate: " + ", ".join(e.task for e in evaluations),
        blueprint=eval_blueprint(evaluations),
        log=lambda rec: log_evaluations(rec, evaluations),
        disabled_hint="drop --rrd",
    )
