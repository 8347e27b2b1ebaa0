"""Live Rerun logging of teleop sessions, off the control loop.

One :class:`RerunHub` per app decides where data goes (``--rerun``):

* ``serve`` (default): Rerun's web viewer runs as a child process bound to the app's
  ``--host``, and every session streams its own recording (recording id = session id) to a
  gRPC proxy of its own, another child process (:mod:`bt_teleop.rerun.proxy`).
  :meth:`RerunHub.session_url` is the link a tab shows: the web viewer connected to that
  session's proxy, which holds that session's recording and nothing else.
* ``save``: every session writes ``<recordings>/rerun/<UTC time>_<session>.rrd`` (the footer is
  written when the session ends). Nothing is served.
* ``off``: nothing is logged.

Each session gets a :class:`SessionLogger`: the UI's publisher thread hands it snapshots and
events, which only enqueue; a worker thread does the Rerun calls::

    publisher thread --put_nowait--> bounded queue (drops when full) --> worker --> RecordingStream

Robot states reach the stream at most :data:`MAX_STATE_HZ` times per second of simulation
time, batched: one ``send_columns`` per entity every :data:`STATE_BATCH_S` of simulation time.
A viewer opened at any time thus has few messages to catch up on (docs/teleop.md, "Live Rerun
latency").

Entities of a session's recording (timeline ``sim_time``, simulation seconds of the session):
``/ee/position`` (Points3D) and ``/joints`` (Scalars, fr3_joint1..7), sent as columns;
``/demos/<name>`` (static LineStrips3D) when a demo is saved, named as the page names it (who
and when, e.g. ``alice_12-06_120301``; :mod:`bt_pipeline.viz.demo_style`), one colour each,
and ``/legend`` (a TextDocument: each saved demo's colour and name); ``/replay/<raw|cleaned>``
(static LineStrips3D) when a demo is replayed on the robot (raw thin and light, cleaned wide); after
Clean everything
:func:`bt_pipeline.viz.rerun_clean.log_clean_result` logs under ``/<task>``, plus Stage 1's DMP
rollouts behind the value map V_E under ``/<task>/plane/rollouts``, sent by the Clean job's own
process (:mod:`bt_teleop.rerun.clean_log`; :meth:`SessionLogger.clean_target`). The blueprint
(:func:`session_blueprint`) puts the 3-D robot content in a 3-D view and each task's 2-D plane
content in 2-D views (:mod:`bt_teleop.rerun.blueprint`). It starts with the robot view alone and
grows a tab for each task whose Clean result is logged: every view costs the web viewer time,
on every frame and when it ingests the layout.
"""

from __future__ import annotations

import logging
import queue
import threading
import urllib.parse
from collections.abc import Callable
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Literal, get_args

import numpy as np
import rerun as rr

from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.viz.demo_style import (
    CLEANED_RADIUS_UI,
    RAW_RADIUS_UI,
    cleaned_color,
    demo_color,
    entity_part,
    legend_markdown,
    name_from_stem,
    raw_color,
    unique_names,
)
from bt_teleop.rerun.blueprint import SIM_TIMELINE, session_blueprint
from bt_teleop.rerun.clean_log import APP_ID, CleanLogTarget
from bt_teleop.rerun.proxy import RerunProxy
from bt_teleop.takes.escape import display_text
from bt_teleop.takes.naming import utc_stamp

RerunMode = Literal["serve", "save", "off"]
"""Where sessions log: a live viewer, .rrd files, or nowhere."""
RERUN_MODES: tuple[RerunMode, ...] = get_args(RerunMode)
RRD_DIRNAME = "rerun"
"""Folder under the recordings root for ``save`` mode's .rrd files."""

LOGGER = logging.getLogger("bt.teleop")
_Job = Callable[[rr.RecordingStream], None]
_STOP = object()
_MAX_PENDING_STATES = 512
MAX_STATE_HZ = 30.0
"""Most robot states per second of simulation time that reach the stream."""
STATE_BATCH_S = 1.0
"""Robot states are sent in one message per entity per this much simulation time [s]. The web
viewer ingests messages for at most 10 ms per frame (at least one), and a frame takes hundreds
of ms in software WebGL: one message per state (60 a second per tab) left it minutes behind;
two a second keep it at the present (docs/teleop.md, "Live Rerun latency")."""
SESSION_MEMORY_LIMIT = "64MiB"
"""Log data a session's proxy keeps for viewers that open late (the oldest is dropped)."""
DEFAULT_GRPC_PORT = 9877
"""Preferred port of the app's web viewer's own gRPC proxy: not Rerun's default 9876, where a
user's ``rerun FILE`` looks for a running viewer and would stream the file into the app's."""
DEFAULT_WEB_PORT = 9091
"""Preferred port of the app's Rerun web viewer: not Rerun's default 9090 (``rerun FILE
--web-viewer`` binds it)."""
REPLAY_RGB = (255, 190, 0)
"""The hue of replayed paths in the robot view (raw thin and light, cleaned wide)."""
_REPLAY_NOTE = "Replays (`/replay`): gold; the raw path thin and light, the cleaned one wide.\n"


class SessionLogger:
    """Logs one session to its own RecordingStream from a worker thread; never blocks callers."""

    def __init__(
        self,
        rec: rr.RecordingStream | None,
        queue_size: int = 64,
        on_close: Callable[[], None] | None = None,
        target: CleanLogTarget | None = None,
    ) -> None:
        """Start the worker for `rec` (None: a logger that drops everything, for ``off``);
        `on_close` runs after the stream is closed (e.g. stops the session's proxy); `target`
        is where the session's Clean jobs log their results (:meth:`clean_target`)."""
        self.rec = rec
        self.target = target
        self._on_close = on_close
        self.cleaned_tasks: list[str] = []
        """Tasks whose Clean result was logged (each has a tab in the layout), in order."""
        self.demo_names: dict[str, str] = {}
        """Saved demos' file stems and their entity names (``/demos/<name>``), in save order."""
        self.dropped = 0
        """Items dropped because the queue was full."""
        self._queue: queue.Queue[object] = queue.Queue(maxsize=queue_size)
        self._states: list[tuple[float, FloatArray, FloatArray]] = []
        self._next_state_s = -np.inf
        self._next_flush_s = -np.inf
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
        """Queue one robot snapshot: end-effector position (3,) [m], arm joints (7,) [rad].

        At most :data:`MAX_STATE_HZ` snapshots per second of simulation time are kept; the
        others are dropped (a bounded rate). They reach the stream together, one message per
        :data:`STATE_BATCH_S` of simulation time."""
        if self.rec is None:
            return
        with self._lock:
            if sim_time_s < self._next_state_s - 1e-9:
                return
            self._next_state_s = max(self._next_state_s + 1.0 / MAX_STATE_HZ, float(sim_time_s))
            self._states.append((float(sim_time_s), np.array(ee_pos), np.array(joint_pos)))
            if len(self._states) > _MAX_PENDING_STATES:  # the worker is far behind: drop
                del self._states[0]
                self.dropped += 1
            submit = not self._flush_pending and sim_time_s >= self._next_flush_s
            if submit:
                self._flush_pending = True
                self._next_flush_s = float(sim_time_s) + STATE_BATCH_S
        if submit and not self._submit(self._flush_states):  # one job per batch of snapshots
            with self._lock:
                self._flush_pending = False

    def log_demo(self, stem: str, ee_pos: FloatArray) -> None:
        """Queue a saved demo's end-effector path (T, 3) [m] as ``/demos/<name>`` (static) and
        the legend: `stem` is its file's stem, ``<who>_<UTC stamp>_<hex>``, and ``<name>`` is
        who and when as the page shows them, e.g. ``alice_12-06_120301`` (unique in the
        session: a repeat gets ``_2``); each demo has a colour of its own (save order)."""
        path = np.array(ee_pos, dtype=np.float32)
        with self._lock:
            if stem not in self.demo_names:
                base = name_from_stem(stem) or entity_part(stem) or "demo"
                taken = list(self.demo_names.values())
                self.demo_names[stem] = unique_names([*taken, base])[-1]
            name = self.demo_names[stem]
            names = list(self.demo_names.values())
        index = names.index(name)
        strips = rr.LineStrips3D(
            [path],
            colors=[raw_color(demo_color(index))],
            radii=rr.Radius.ui_points(RAW_RADIUS_UI * 2),
            labels=[name],
        )
        legend = rr.TextDocument(
            legend_markdown(names, cleaned=False) + "\n" + _REPLAY_NOTE,
            media_type="text/markdown",
        )

        def job(rec: rr.RecordingStream) -> None:
            rec.log(f"demos/{name}", strips, static=True)
            rec.log("legend", legend, static=True)

        self._submit(job)

    def log_replay(self, key: str, ee_pos: FloatArray, kind: str) -> None:
        """Queue a replayed demo's path (T, 3) [m] as ``/replay/<kind>`` (static, as
        ``/demos``: the last replay of each kind stays drawn), labelled `key` (the page's name
        of the demo: its kind, who and when)."""
        path = np.array(ee_pos, dtype=np.float32)
        label = display_text(key, 120)  # see takes/escape.py
        entity = f"replay/{rr.escape_entity_path_part(kind)}"
        if kind == "cleaned":
            color, radius = cleaned_color(REPLAY_RGB), CLEANED_RADIUS_UI
        else:
            color, radius = raw_color(REPLAY_RGB), RAW_RADIUS_UI
        strips = rr.LineStrips3D(
            [path], labels=[label], colors=[color], radii=rr.Radius.ui_points(radius)
        )
        # Static: logged on the worker thread it had no sim_time, and the robot view shows only
        # the last TRAIL_S of sim_time, so the viewer never drew a replay.
        self._submit(lambda rec: rec.log(entity, strips, static=True))

    def clean_target(self) -> CleanLogTarget | None:
        """Where a Clean job started by this session logs its result (None: ``off``): the
        job's process logs it there itself (:mod:`bt_teleop.rerun.clean_log`)."""
        if self.target is None:
            return None
        return replace(self.target, tasks=tuple(self.cleaned_tasks))

    def show_cleaned(self, task: str) -> None:
        """Grow the layout by a tab for `task`, whose Clean result the job logged."""

        def job(rec: rr.RecordingStream) -> None:
            if task not in self.cleaned_tasks:
                layout = session_blueprint([*self.cleaned_tasks, task])
                rec.send_blueprint(layout, make_active=True, make_default=True)
                self.cleaned_tasks.append(task)

        self._submit(job)

    def close(self, timeout_s: float = 5.0) -> None:
        """Log what is queued, then flush and close the stream (writes an .rrd footer)."""
        if self._thread is None:
            return
        try:
            self._queue.put(self._flush_states, timeout=timeout_s)  # the last, partial batch
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
        if self._on_close is not None:
            self._on_close()

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
        # One batch per worker pass, whatever its size: the stream gets columns, not rows.
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
        host: str = "127.0.0.1",
        grpc_port: int = DEFAULT_GRPC_PORT,
        web_port: int = DEFAULT_WEB_PORT,
        memory_limit: str = SESSION_MEMORY_LIMIT,
        newest_first: bool = False,
    ) -> None:
        """Start the web viewer (``serve``); nothing is started for ``save`` and ``off``.

        Args:
            mode: serve, save or off.
            recordings_dir: Root folder of the recordings (``save`` writes under it).
            host: Interface the proxies and the web viewer bind (the app's ``--host``).
            grpc_port: Preferred port of the web viewer's own gRPC proxy (a free one when
                busy); each session's proxy takes a free port. Not Rerun's default 9876, so a
                user's ``rerun FILE`` opens its own viewer instead of streaming into the app's.
            web_port: Preferred port of the web viewer (a free one when busy).
            memory_limit: Log data each session's proxy keeps for viewers that open late.
            newest_first: A viewer that opens late gets a session's newest data first.

        Raises:
            ConfigError: Unknown mode, or the web viewer did not start.
        """
        if mode not in RERUN_MODES:
            valid = ", ".join(RERUN_MODES)
            raise ConfigError(f"unknown --rerun {mode!r}; valid values are {valid}")
        self.mode: RerunMode = mode
        self.recordings_dir = Path(recordings_dir)
        self.host = host
        self.memory_limit = memory_limit
        self.newest_first = newest_first
        self.grpc_url: str | None = None
        """The web viewer process's own proxy, ``rerun+http://<host>:<port>/proxy`` (serve
        mode; sessions do not stream to it)."""
        self.viewer_url: str | None = None
        """The web viewer's page, with no recording (serve mode)."""
        self.proxy: RerunProxy | None = None
        """The web viewer process (serve mode)."""
        self._sessions: dict[str, RerunProxy] = {}
        self._lock = threading.Lock()
        if mode == "serve":
            self.proxy = RerunProxy(host, grpc_port, web_port, "16MiB")
            self.grpc_url = self.proxy.grpc_url
            self.viewer_url = self.proxy.web_url

    def session_proxy(self, session_id: str) -> RerunProxy | None:
        """The proxy session `session_id` streams to (serve mode, while its logger is open)."""
        with self._lock:
            return self._sessions.get(session_id)

    def session_url(self, session_id: str) -> str | None:
        """The web viewer opened on session `session_id`'s own proxy and recording (serve
        mode, while its logger is open)."""
        proxy = self.session_proxy(session_id)
        if self.proxy is None or proxy is None:
            return None
        route = "about:recording?" + urllib.parse.urlencode(
            {"app_id": APP_ID, "recording_id": session_id}
        )
        query = urllib.parse.urlencode([("url", proxy.grpc_url), ("url", route)])
        return f"{self.proxy.web_url}?{query}"

    def session_logger(self, session_id: str, queue_size: int = 64) -> SessionLogger:
        """A logger for one session (one recording, id `session_id`), its blueprint sent; in
        serve mode it streams to a proxy of its own, stopped when the logger closes.

        Raises:
            ConfigError: The session's proxy did not start.
        """
        if self.mode == "off":
            return SessionLogger(None)
        rec = rr.RecordingStream(APP_ID, recording_id=session_id, send_properties=False)
        on_close: Callable[[], None] | None = None
        if self.mode == "serve":
            proxy = RerunProxy(
                self.host, 0, None, self.memory_limit, newest_first=self.newest_first
            )
            with self._lock:
                self._sessions[session_id] = proxy
            rec.connect_grpc(proxy.grpc_url, default_blueprint=session_blueprint())
            on_close = lambda: self._end_session(session_id)  # noqa: E731
            target = CleanLogTarget(session_id, grpc_url=proxy.grpc_url)
        else:
            rrd = self.rrd_path(session_id)
            rec.save(rrd, default_blueprint=session_blueprint())
            target = CleanLogTarget(session_id, session_rrd=rrd)
        rec.send_recording_name(f"bt teleop session {session_id}")
        return SessionLogger(rec, queue_size, on_close, target)

    def rrd_path(self, session_id: str) -> Path:
        """Where ``save`` mode writes a session: ``<recordings>/rerun/<UTC time>_<id>.rrd``."""
        folder = self.recordings_dir / RRD_DIRNAME
        folder.mkdir(parents=True, exist_ok=True)
        safe = "".join(ch for ch in session_id if ch.isalnum() or ch in "-_") or "session"
        return folder / f"{utc_stamp(datetime.now(UTC))}_{safe}.rrd"

    def close(self) -> None:
        """Stop the web viewer and any session proxy still running (serve mode)."""
        with self._lock:
            sessions, self._sessions = list(self._sessions.values()), {}
        for proxy in sessions:
            proxy.close()
        if self.proxy is not None:
            self.proxy.close()
            self.proxy = None

    def _end_session(self, session_id: str) -> None:
        with self._lock:
            proxy = self._sessions.pop(session_id, None)
        if proxy is not None:
            proxy.close()


__all__ = ["APP_ID", "RERUN_MODES", "RerunHub", "RerunMode", "SessionLogger", "session_blueprint"]
