"""Live Rerun logging of teleop sessions, off the control loop.

One :class:`RerunHub` per app decides where data goes (``--rerun``):

* ``serve`` (default): a hub stream hosts Rerun's gRPC server and Rerun's bundled web viewer
  is served over HTTP (``rr.serve_grpc`` + ``rr.serve_web_viewer``); every session streams its
  own recording (recording id = session id) to that server, so the viewer lists one recording
  per browser tab. :attr:`RerunHub.viewer_url` is the link the UI shows.
* ``save``: every session writes ``<recordings>/rerun/<UTC time>_<session>.rrd`` (the footer is
  written when the session ends). Nothing is served.
* ``off``: nothing is logged.

Each session gets a :class:`SessionLogger`: the UI's publisher thread hands it snapshots and
events, which only enqueue; a worker thread does the Rerun calls::

    publisher thread --put_nowait--> bounded queue (drops when full) --> worker --> RecordingStream

Entities of a session's recording (timeline ``sim_time``, simulation seconds of the session):
``/ee/position`` (Points3D) and ``/joints`` (Scalars, fr3_joint1..7), sent as columns;
``/demos/<file stem>`` (static LineStrips3D) when a demo is saved; and after Clean everything
:func:`bt_pipeline.viz.rerun_clean.log_clean_result` logs under ``/<task>``.
"""

from __future__ import annotations

import logging
import queue
import socket
import threading
import urllib.parse
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Literal, get_args

import numpy as np
import rerun as rr

from bt_pipeline.clean.pipeline import TaskCleanResult
from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError
from bt_teleop.naming import utc_stamp

RerunMode = Literal["serve", "save", "off"]
"""Where sessions log: a live viewer, .rrd files, or nowhere."""
RERUN_MODES: tuple[RerunMode, ...] = get_args(RerunMode)
APP_ID = "bt_teleop"
"""Rerun application id of every teleop recording."""
SIM_TIMELINE = "sim_time"
"""Duration timeline: a session's simulation time [s]."""
RRD_DIRNAME = "rerun"
"""Folder under the recordings root for ``save`` mode's .rrd files."""

LOGGER = logging.getLogger("bt.teleop")
_Job = Callable[[rr.RecordingStream], None]
_STOP = object()
_MAX_PENDING_STATES = 512


class SessionLogger:
    """Logs one session to its own RecordingStream from a worker thread; never blocks callers."""

    def __init__(self, rec: rr.RecordingStream | None, queue_size: int = 64) -> None:
        """Start the worker for `rec` (None: a logger that drops everything, for ``off``)."""
        self.rec = rec
        self.dropped = 0
        """Items dropped because the queue was full."""
        self._queue: queue.Queue[object] = queue.Queue(maxsize=queue_size)
        self._states: list[tuple[float, FloatArray, FloatArray]] = []
        self._flush_pending = False
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        if rec is not None:
            self._thread = threading.Thread(target=self._run, name="bt-rerun-log", daemon=True)
            self._thread.start()

    @property
    def enabled(self) -> bool:
        """Whether anything is logged."""
        return self.rec is not None

    def log_state(self, sim_time_s: float, ee_pos: FloatArray, joint_pos: FloatArray) -> None:
        """Queue one robot snapshot: end-effector position (3,) [m], arm joints (7,) [rad]."""
        if self.rec is None:
            return
        with self._lock:
            self._states.append((float(sim_time_s), np.array(ee_pos), np.array(joint_pos)))
            if len(self._states) > _MAX_PENDING_STATES:  # the worker is far behind: drop
                del self._states[0]
                self.dropped += 1
            submit = not self._flush_pending
            self._flush_pending = True
        if submit and not self._submit(self._flush_states):  # one job per batch of snapshots
            with self._lock:
                self._flush_pending = False

    def log_demo(self, name: str, ee_pos: FloatArray) -> None:
        """Queue a saved demo's end-effector path (T, 3) [m] as ``/demos/<name>`` (static)."""
        path = np.array(ee_pos, dtype=np.float32)
        entity = f"demos/{rr.escape_entity_path_part(name)}"
        self._submit(lambda rec: rec.log(entity, rr.LineStrips3D([path]), static=True))

    def log_clean_result(self, result: TaskCleanResult) -> None:
        """Queue a Clean job's result (scores, value map, aligned references, cleaned demos)."""
        from bt_pipeline.viz.rerun_clean import log_clean_result

        self._submit(lambda rec: log_clean_result(rec, result))

    def close(self, timeout_s: float = 5.0) -> None:
        """Log what is queued, then flush and close the stream (writes an .rrd footer)."""
        if self._thread is None:
            return
        try:
            self._queue.put(_STOP, timeout=timeout_s)
        except queue.Full:
            LOGGER.warning("Rerun logger did not drain in %.1f s; closing anyway", timeout_s)
        self._thread.join(timeout_s)
        self._thread = None
        assert self.rec is not None
        try:
            self.rec.flush(timeout_sec=timeout_s)
        except Exception as exc:  # a viewer that went away must not fail the shutdown
            LOGGER.warning("Rerun flush failed: %s", exc)
        self.rec.disconnect()

    def _submit(self, job: _Job) -> bool:
        """Queue `job` unless the queue is full; whether it was queued."""
        if self.rec is None:
            return False
        try:
            self._queue.put_nowait(job)
        except queue.Full:
            self.dropped += 1
            return False
        return True

    def _flush_states(self, rec: rr.RecordingStream) -> None:
        with self._lock:
            states, self._states = self._states, []
            self._flush_pending = False
        if not states:
            return
        times = np.array([s[0] for s in states])
        index = [rr.TimeColumn(SIM_TIMELINE, duration=times)]
        ee = np.stack([s[1] for s in states])
        joints = np.stack([s[2] for s in states])
        rec.send_columns("ee/position", indexes=index, columns=rr.Points3D.columns(positions=ee))
        rec.send_columns("joints", indexes=index, columns=rr.Scalars.columns(scalars=joints))

    def _run(self) -> None:
        assert self.rec is not None
        while True:
            job = self._queue.get()
            if job is _STOP:
                return
            try:
                job(self.rec)  # type: ignore[operator]  # only _Job and _STOP are queued
            except Exception:  # logging must never take a session down
                LOGGER.exception("Rerun logging failed")


class RerunHub:
    """The app's Rerun endpoint: the live viewer (serve), .rrd files (save), or nothing (off)."""

    def __init__(
        self,
        mode: RerunMode,
        recordings_dir: str | Path,
        *,
        grpc_port: int = 9876,
        web_port: int = 9090,
        memory_limit: str = "512MiB",
    ) -> None:
        """Start serving (``serve``); nothing is started for ``save`` and ``off``.

        Args:
            mode: serve, save or off.
            recordings_dir: Root folder of the recordings (``save`` writes under it).
            grpc_port: Preferred port of the gRPC server (a free one when busy).
            web_port: Preferred port of the web viewer (a free one when busy).
            memory_limit: Log data the gRPC server keeps for viewers that connect late.

        Raises:
            ConfigError: Unknown mode.
        """
        if mode not in RERUN_MODES:
            valid = ", ".join(RERUN_MODES)
            raise ConfigError(f"unknown --rerun {mode!r}; valid values are {valid}")
        self.mode: RerunMode = mode
        self.recordings_dir = Path(recordings_dir)
        self.grpc_url: str | None = None
        """``rerun+http://127.0.0.1:<port>/proxy`` in serve mode."""
        self.viewer_url: str | None = None
        """The web viewer, connected to the gRPC server, in serve mode."""
        self._hub: rr.RecordingStream | None = None
        if mode == "serve":
            self._hub = rr.RecordingStream(APP_ID, recording_id="bt_teleop_hub")
            grpc = _free_port(grpc_port)
            self.grpc_url = self._hub.serve_grpc(grpc_port=grpc, server_memory_limit=memory_limit)
            web = _free_port(web_port)
            rr.serve_web_viewer(web_port=web, open_browser=False, connect_to=self.grpc_url)
            query = urllib.parse.urlencode({"url": self.grpc_url})
            self.viewer_url = f"http://localhost:{web}/?{query}"

    def session_logger(self, session_id: str, queue_size: int = 64) -> SessionLogger:
        """A logger for one session (one recording, id `session_id`)."""
        if self.mode == "off":
            return SessionLogger(None)
        rec = rr.RecordingStream(APP_ID, recording_id=session_id, send_properties=False)
        if self.mode == "serve":
            assert self.grpc_url is not None
            rec.connect_grpc(self.grpc_url)
        else:
            rec.save(self.rrd_path(session_id))
        rec.send_recording_name(f"bt teleop session {session_id}")
        return SessionLogger(rec, queue_size)

    def rrd_path(self, session_id: str) -> Path:
        """Where ``save`` mode writes a session: ``<recordings>/rerun/<UTC time>_<id>.rrd``."""
        folder = self.recordings_dir / RRD_DIRNAME
        folder.mkdir(parents=True, exist_ok=True)
        safe = "".join(ch for ch in session_id if ch.isalnum() or ch in "-_") or "session"
        return folder / f"{utc_stamp(datetime.now(UTC))}_{safe}.rrd"

    def close(self) -> None:
        """Stop the gRPC server (the web viewer's HTTP server lives until the process exits)."""
        if self._hub is not None:
            self._hub.disconnect()
            self._hub = None


def _free_port(preferred: int) -> int:
    """`preferred` if it can be bound on every interface (as Rerun binds), else a free port."""
    for candidate in (preferred, 0):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
            try:
                probe.bind(("0.0.0.0", candidate))  # Rerun binds all interfaces
            except OSError:
                continue
            return int(probe.getsockname()[1])
    raise ConfigError("no free port for Rerun")


__all__ = ["APP_ID", "RERUN_MODES", "RerunHub", "RerunMode", "SessionLogger"]
