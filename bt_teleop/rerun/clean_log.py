"""A Clean job's result, logged to its tab's Rerun recording by the job itself.

The result holds every demo of the task (raw, aligned, cleaned) and can be many megabytes. It
used to travel to the app, pickled through the job's queue, and be logged there on the tab's
logger thread: each burst landed in another malloc arena of the long-running app and left its
pages resident, so the app grew with every Clean (docs/security.md, "The app's memory and the
Clean results"). Now the job's process logs it and exits; the app gets one line of summary::

    job process: clean -> write outputs -> log_clean_to(target, result) -> "done" (no result)
    app:         "done" -> SessionLogger.show_cleaned(task) (the layout grows the task's tab)

A :class:`CleanLogTarget` says where the tab's recording lives:

* ``--rerun serve``: the tab's own gRPC proxy. The job opens a second stream with the tab's
  recording id, so the viewer shows the result inside the tab's recording.
* ``--rerun save``: a file of its own beside the tab's ``.rrd``,
  ``<session file stem>_clean_<task>_<UTC time>.rrd``, with the same recording id (open both
  together to see them as one recording), written atomically.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import rerun as rr

from bt_pipeline.clean.pipeline import TaskCleanResult
from bt_pipeline.data.records import FloatArray
from bt_teleop.rerun.blueprint import session_blueprint
from bt_teleop.takes.escape import markdown_text
from bt_teleop.takes.naming import utc_stamp

__all__ = ["APP_ID", "ROLLOUTS_SHOWN", "CleanLogTarget", "log_clean_to"]

APP_ID = "bt_teleop"
"""Rerun application id of every teleop recording."""
ROLLOUTS_SHOWN = 20
"""DMP rollouts of the value map drawn per task (of its ``n_rollouts``)."""
FLUSH_TIMEOUT_S = 30.0
"""Longest the job waits for its result to reach the tab's proxy [s]."""


@dataclass(frozen=True)
class CleanLogTarget:
    """Where a Clean job logs its result: the recording of the tab that started it."""

    recording_id: str
    """The tab's recording id (its session id)."""
    grpc_url: str | None = None
    """``serve``: the tab's own proxy, ``rerun+http://<host>:<port>/proxy``."""
    session_rrd: Path | None = None
    """``save``: the tab's .rrd file (the result goes to a file of its own beside it)."""
    tasks: tuple[str, ...] = ()
    """Tasks the tab's layout has tabs for before this Clean (``save``: the file's layout)."""

    def rrd_for(self, task: str) -> Path:
        """``save``: the file a Clean of `task` writes now, beside the session's."""
        assert self.session_rrd is not None
        stamp = utc_stamp(datetime.now(UTC))
        return self.session_rrd.with_name(f"{self.session_rrd.stem}_clean_{task}_{stamp}.rrd")


def log_clean_to(target: CleanLogTarget, result: TaskCleanResult, seed: int) -> str:
    """Log `result` (scores, value map, aligned references, cleaned demos, and Stage 1's DMP
    rollouts behind V_E reproduced with the job's `seed`) to `target`; where it went.

    Raises:
        Exception: Rerun failed (the proxy went away, the file could not be written); the job
            reports it as a note and its outputs stand.
    """
    from bt_pipeline.viz.rrd import save_rrd

    task = str(result.task)
    if target.session_rrd is not None:
        path = target.rrd_for(task)
        save_rrd(
            path,
            app_id=APP_ID,
            recording_id=target.recording_id,
            name=f"bt teleop session {target.recording_id}: Clean of {task}",
            blueprint=session_blueprint(dict.fromkeys((*target.tasks, task))),
            log=lambda rec: _log(rec, result, seed),
            disabled_hint="use --rerun off",
        )
        return path.name
    rec = rr.RecordingStream(APP_ID, recording_id=target.recording_id, send_properties=False)
    try:
        rec.connect_grpc(target.grpc_url)
        _log(rec, result, seed)
        rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
    finally:
        rec.disconnect()
    return "the live viewer"


def _log(rec: rr.RecordingStream, result: TaskCleanResult, seed: int) -> None:
    from bt_pipeline.viz.rerun_clean import log_clean_result

    # Names typed in browsers reach the viewer's Markdown summary: escape them (takes/escape.py).
    demos = tuple(replace(d, demonstrator=markdown_text(d.demonstrator, 40)) for d in result.demos)
    log_clean_result(rec, replace(result, demos=demos))
    # White over V_E: in V_E's own colours they vanish into the ridge they made.
    strips = rr.LineStrips2D(_rollouts(result, seed), colors=[(255, 255, 255, 150)])
    rec.log(f"{result.task}/plane/rollouts", strips)


def _rollouts(result: TaskCleanResult, seed: int) -> list[FloatArray]:
    """Stage 1's DMP rollouts behind V_E (paper Sec. III-B step 3), as the cleaner ran them
    (default value-map settings, the job's seed): the first :data:`ROLLOUTS_SHOWN`, (spp, 2)."""
    from bt_pipeline.clean.stage1.value_map import ValueMapConfig, rollout_states

    config = ValueMapConfig()
    states = rollout_states(result.stage1.dmp, result.stage1.reference, config, seed)
    paths = states.reshape(config.n_rollouts, config.samples_per_period, 2)
    return [p.astype(np.float32) for p in paths[:ROLLOUTS_SHOWN]]
