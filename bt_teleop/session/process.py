"""A session whose simulation runs in a child process of its own (one GIL per control loop).

In the app's one interpreter, 8 control loops ran at 219 of the 800 ticks/s they asked for
(docs/security.md, soak). :class:`SessionProcess` moves a tab's
:class:`~bt_teleop.session.control_loop.Session` (MuJoCo, mink IK, the control loop, the recorder
and the take saving) into a child process and keeps the part of its API the app uses::

    main process (the app)                      child process (one per tab)
    SessionProcess ──Pipe──────────────────────▶ main thread: serve commands
      set_target / set_gripper / set_stay_on_plane   one-way (validated here, never wait)
      status / trail / recording                     quick request → reply (timeout_s)
      start_recording / discard / start / reset ...  request → reply (unresponsive_s)
      stop_and_check / close                         request → reply (SAVE_TIMEOUT_S)
      .scene: its own SceneModel (for drawing)  control thread: TimedSession at real time

Calls and replies carry a sequence number (:mod:`bt_teleop.session.pipe`; the child's side:
:mod:`bt_teleop.session.child`). Children are forked by a ``forkserver`` that has imported
MuJoCo and mink once (:mod:`bt_teleop.proc.forkserver`). A child ends with its tab
(:meth:`SessionProcess.close`), when its pipe reaches EOF (the app died: a take in progress is
then saved flagged incomplete, as a closed tab's is), or at SIGTERM, which it asks the kernel
to send it when the forkserver (its parent, which exits when the app does) dies, even after a
``kill -9`` of the app. SIGINT is ignored: Ctrl-C in the terminal reaches the whole process
group, and the app closes each session itself.

**Slow is not lost.** A quick call (status, trail, recording) with no reply within
``timeout_s`` returns the last state known (a status with the warning "the simulation is not
answering (busy machine?)"); its reply is dropped when it comes. One-way commands never block.
Actions (record, discard, start, reset) wait up to ``unresponsive_s`` for their reply, saves
SAVE_TIMEOUT_S. A child is **lost** only when its process ended, when it answered nothing for
``unresponsive_s`` (:data:`UNRESPONSIVE_S`) or a save got no reply in time. **A lost child is
replaced** (:meth:`SessionProcess.recover`; a tab does it at once, with a notice;
:mod:`bt_teleop.session.recovery`); until then :meth:`SessionProcess.status` returns the last
status, not running, with the reason as its warning, one-way commands are kept for the new
child, and other calls raise :class:`~bt_pipeline.exceptions.SessionLostError`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import os
import secrets
import signal
import threading
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import BtError, ConfigError, SessionBusyError, SessionLostError
from bt_teleop.proc import forkserver
from bt_teleop.proc.forkserver import start_child, start_forkserver
from bt_teleop.session.child import serve_session
from bt_teleop.session.config import SessionConfig, SessionStatus
from bt_teleop.session.pipe import ChildGone, ChildPipe
from bt_teleop.session.recording import SavedTake
from bt_teleop.session.recovery import ChildMemory, Recovery
from bt_teleop.session.tick_stats import TickReport, TimedSession
from bt_teleop.sim.scene import SceneModel
from bt_teleop.sim.workspace import validate_position, validate_quat

__all__ = ["SessionProcess", "TabSession", "open_session", "start_forkserver"]

LOGGER = logging.getLogger("bt.teleop")
forkserver.preload(serve_session.__module__)  # the server imports MuJoCo, mink and the session
START_TIMEOUT_S = 60.0
"""Longest wait for a child to load its scene and answer [s] (Menagerie meshes: seconds)."""
SAVE_TIMEOUT_S = 60.0
"""Longest wait for a call that writes a take (Stop & save, close), and for a lost child to
save its take in progress [s]."""
UNRESPONSIVE_S = 60.0
"""A child that answers nothing for this long [s] is lost: 12 times the 5 s after which two
starved children were killed at load 38 on 2 cores (docs/security.md; how long they would have
taken was not measured), and as long as a save may take."""
Kind = Literal["quick", "action", "save"]
"""A call's timeout: ``timeout_s`` and not fatal; ``unresponsive_s``; SAVE_TIMEOUT_S."""


class SessionProcess:
    """A :class:`~bt_teleop.session.control_loop.Session` run in a child process (app tabs)."""

    def __init__(
        self,
        scene: SceneModel,
        recordings_dir: str | Path = "recordings",
        *,
        config: SessionConfig | None = None,
        session_id: str | None = None,
        timeout_s: float = 5.0,
        unresponsive_s: float = UNRESPONSIVE_S,
    ) -> None:
        """Start the child, which loads `scene`'s task and robot by name, and wait until it
        answers (its loop is not started: :meth:`start`).

        Args:
            scene: This process's copy of the scene (for drawing; the child loads its own).
            recordings_dir: Root folder; demos go to ``<recordings_dir>/<task>/``.
            config: Rates and policies; defaults when None.
            session_id: Stored in each demo's ep_meta; random when None.
            timeout_s: Longest wait for a reply to a quick call [s] (status, trail, recording;
                then the last state is returned, and the child stays).
            unresponsive_s: A child that answers nothing for this long [s] is lost; also the
                longest wait for an action's reply (start_recording, discard, ...).

        Raises:
            BtError: The session cannot be made (the child's error, e.g. ConfigError).
            SessionLostError: The child died or did not answer within START_TIMEOUT_S.
        """
        self.scene = scene
        self.config = config or SessionConfig()
        self.recordings_dir = Path(recordings_dir)
        self.session_id = session_id or secrets.token_hex(4)
        self.timeout_s = float(timeout_s)
        self.unresponsive_s = float(unresponsive_s)
        self.recoveries: list[Recovery] = []
        """Each lost child replaced (:meth:`recover`), oldest first."""
        self._lost: str | None = None
        self._can_recover = True
        self._closed = False
        self._memory = ChildMemory()  # the last answers, the take, the settings
        self._running = False  # start() asked (and no stop() since): a new child starts too
        self._recover_lock = threading.Lock()
        self._spawn()

    # -- commands (one-way: validated here, never wait for the child) --------------------------

    def set_target(self, pos: ArrayLike, quat: ArrayLike | None = None) -> None:
        """Set the end-effector target: position (3,) [m], orientation wxyz (4,) or None (keep).

        Raises:
            ConfigError: Not finite or of the wrong shape (the previous target stays).
        """
        p = validate_position(pos)
        self._send_one_way("set_target", p, None if quat is None else validate_quat(quat))

    def set_gripper(self, open: bool) -> None:
        """Open (True) or close (False) the gripper; ignored by scenes without one."""
        self._send_one_way("set_gripper", bool(open))

    def set_stay_on_plane(self, on: bool) -> None:
        """Project every target onto the task plane (True) or not (False)."""
        self._send_one_way("set_stay_on_plane", bool(on))

    # -- requests ------------------------------------------------------------------------------

    def start(self) -> None:
        """Run the control loop in the child at real time."""
        self._call("start")
        self._running = True

    def stop(self) -> None:
        """Stop the child's control loop (the child stays)."""
        self._call("stop")
        self._running = False

    def reset(self) -> None:
        """Put the robot at the ready pose with the gripper open and the target on it."""
        self._call("reset")

    def start_recording(
        self, demonstrator: str = "anonymous", theta_deg: float = math.nan, rho: float = math.nan
    ) -> None:
        """:meth:`bt_teleop.session.control_loop.Session.start_recording`."""
        self._call("start_recording", demonstrator, theta_deg, rho)
        self._memory.take_by = demonstrator

    def stop_and_check(self) -> SavedTake:
        """Stop the demo in progress, check it and write it (in the child); what was saved."""
        take: SavedTake = self._call("stop_and_check", kind="save")
        self._memory.take_by = None
        return take

    def stop_and_save(self) -> Path:
        """:meth:`stop_and_check`, the path only."""
        return self.stop_and_check().path

    def discard(self) -> bool:
        """Drop the demo in progress without writing anything; whether there was one."""
        dropped: bool = self._call("discard")
        self._memory.take_by = None
        return dropped

    @property
    def recording(self) -> bool:
        """Whether a demo is being recorded (the last known answer while the child is slow;
        False once it is lost or closed)."""
        if self._closed:
            return False
        try:
            return self._call("recording", kind="quick")
        except SessionBusyError:
            return self._memory.status is not None and self._memory.status.recording
        except SessionLostError:
            return False

    def status(self) -> SessionStatus:
        """A snapshot of the session. While the child is slow, the last one with a warning
        that says so; once it is lost, the last one, not running, with the reason."""
        try:
            status: SessionStatus = self._call("status", kind="quick")
        except (SessionBusyError, SessionLostError) as exc:
            last = self._memory.status
            if last is None:
                raise
            busy = isinstance(exc, SessionBusyError)
            return dataclasses.replace(last, warning=str(exc), running=last.running and busy)
        self._memory.note_status(status)
        return status

    def trail(self) -> FloatArray:
        """End-effector positions of the demo in progress, shape (T, 3) [m] (empty if none or
        lost; the last one received while the child is slow)."""
        if self._closed:
            return np.zeros((0, 3))
        try:
            self._memory.trail = self._call("trail", kind="quick")
        except SessionBusyError:
            pass
        except SessionLostError:
            return np.zeros((0, 3))
        return self._memory.trail

    def tick_stats(self) -> TickReport:
        """The control loop's tick timing so far (gaps, stalls;
        :mod:`bt_teleop.session.tick_stats`)."""
        return self._call("tick_stats")

    def process_info(self, name: str) -> Any:
        """What the child process reports about itself, not its session: ``heap_info``
        (HeapInfo | None), ``hdf5_free_lists`` (Hdf5FreeLists | None) or ``allocated_blocks``
        (int) (session_child.PROCESS_CALLS; for benchmarks and tests)."""
        return self._call(name)

    @property
    def pid(self) -> int | None:
        """The child's process id (a new one after :meth:`recover`)."""
        return self._pid

    @property
    def lost(self) -> str | None:
        """Why the child is gone (None while it runs, slow or not)."""
        return self._lost

    @property
    def can_recover(self) -> bool:
        """Whether :meth:`recover` may replace a lost child (False once starting one failed)."""
        return self._can_recover and not self._closed

    def recover(self) -> Recovery:
        """Replace the lost child: settle it (its take saved if it still can), then start a
        new one with the same task, robot, settings and session id, running if this was.

        Raises:
            ConfigError: Not lost, or closed.
            SessionLostError: The new child could not be started (:attr:`can_recover` is then
                False, and the reason says to reload the page).
        """
        with self._recover_lock:
            reason = self._lost
            if reason is None or self._closed:
                raise ConfigError(f"session {self.session_id} is not lost (or closed)")
            self._settle()
            recovery = self._memory.recovery(reason, self.scene.task)
            try:
                self._spawn()
            except BtError as exc:
                self._can_recover = False
                self._lost = f"{reason}; a new one did not start ({exc}); reload the page"
                self._lost += "".join(f". {line}" for line in recovery.take_lines())
                LOGGER.warning("%s", self._lost)
                raise SessionLostError(self._lost) from None
            self.recoveries.append(recovery)
            with self._memory.settings_lock:
                self._lost = None  # from here on one-way commands go to the new child
                for name, args in self._memory.settings.items():
                    self._pipe.send_one_way(name, args)
            if self._running:
                with contextlib.suppress(SessionLostError):  # lost again: the next recover
                    self.start()
        LOGGER.warning("%s", " ".join(recovery.notice()[1].split("\n")))
        return recovery

    def close(self, save_incomplete: bool | None = None) -> Path | None:
        """End the session and its child; a demo in progress is settled as
        :meth:`Session.close <bt_teleop.session.control_loop.Session.close>` does (a lost
        child's as a closed tab's). Returns the file saved."""
        with self._recover_lock:
            if self._closed:
                return None
            self._closed = True
            pipe, path = self._pipe, None
            if self._lost is None:
                try:
                    path = pipe.request("close", (save_incomplete,), SAVE_TIMEOUT_S, quick=False)
                    self._memory.take_by = None
                except (ChildGone, BtError) as exc:
                    self._lose(str(exc), pipe)
            if self._lost is not None:
                self._settle()
                path = self._memory.saved_late[-1] if self._memory.saved_late else None
            self._end_process()
            return path

    def __enter__(self) -> SessionProcess:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # -- internals -----------------------------------------------------------------------------

    def _spawn(self) -> None:
        """Start a child and wait for its first answers (dt_s, status)."""
        args = (self.scene.task, self.scene.robot, self.recordings_dir, self.config)
        conn, process = start_child(
            serve_session,
            (*args, self.session_id, LOGGER.getEffectiveLevel()),
            f"bt-session-{self.session_id}",
        )
        self._process, self._pid, self._ended = process, process.pid, False
        self._pipe = pipe = ChildPipe(
            conn, process, unresponsive_s=self.unresponsive_s, on_late=self._memory.on_late
        )
        try:
            self.dt_s: float = pipe.started(START_TIMEOUT_S)
            """Control period [s]."""
            self._memory.note_status(pipe.request("status", (), START_TIMEOUT_S, quick=False))
        except BaseException as exc:
            self._end_process()
            if isinstance(exc, ChildGone):
                raise SessionLostError(
                    f"the simulation of session {self.session_id} did not start: {exc}"
                ) from None
            raise

    def _send_one_way(self, name: str, *args: Any) -> None:
        if self._closed:
            return
        pipe = self._pipe
        with self._memory.settings_lock:
            self._memory.settings.pop(name, None)
            self._memory.settings[name] = args  # a new child gets it too
            if self._lost is not None:
                return  # the status line says why; recover() sends it on
            try:
                pipe.send_one_way(name, args)
            except ChildGone as exc:
                self._lose(str(exc), pipe)

    def _call(self, name: str, *args: Any, kind: Kind = "action") -> Any:
        if self._lost is not None:
            raise SessionLostError(self._lost)
        if self._closed:
            raise ConfigError(f"session {self.session_id} is closed")
        pipe = self._pipe
        timeout_s = {"quick": self.timeout_s, "action": self.unresponsive_s}.get(kind)
        try:
            return pipe.request(name, args, timeout_s or SAVE_TIMEOUT_S, quick=kind == "quick")
        except ChildGone as exc:
            raise self._lose(str(exc), pipe) from None

    def _lose(self, reason: str, pipe: ChildPipe) -> SessionLostError:
        """Mark the child behind `pipe` lost and tell it to end (it saves a take in progress
        if it still can); the error to raise. A no-op for a child already replaced."""
        if pipe is self._pipe and self._lost is None:
            self._lost = f"the simulation of session {self.session_id} stopped: {reason}"
            LOGGER.warning("%s", self._lost)
            with contextlib.suppress(ProcessLookupError, ValueError):  # ended, or closed
                if self._pid is not None and self._process.exitcode is None:
                    os.kill(self._pid, signal.SIGTERM)
                    os.kill(self._pid, signal.SIGCONT)  # if it was stopped
        return SessionLostError(self._lost or reason)

    def _settle(self) -> None:
        """A lost child: read its last replies (a take it saved) until it ends, or kill it
        after SAVE_TIMEOUT_S."""
        if not self._pipe.drain(SAVE_TIMEOUT_S):
            LOGGER.warning("session %s: the lost child did not end; killed", self.session_id)
        self._end_process()

    def _end_process(self) -> None:
        """End the child (killed if it does not within 5 s) and close its pipe; once."""
        process = self._process
        if self._ended:
            return
        self._ended = True
        if process.exitcode is None:
            process.join(5.0)
        if process.exitcode is None:
            process.kill()
            process.join(5.0)
        self._pipe.conn.close()
        if process.exitcode is not None:
            process.close()  # its sentinel fd (pid and exitcode stay readable here)


TabSession = TimedSession | SessionProcess
"""What a tab drives: its session in a child process, or in the app's own (both timed)."""


def open_session(
    scene: SceneModel,
    recordings_dir: Path,
    *,
    config: SessionConfig,
    session_id: str,
    in_process: bool = False,
) -> TabSession:
    """A tab's session on `scene`: in a child process (default) or in this one."""
    if in_process:
        return TimedSession(scene, recordings_dir, config=config, session_id=session_id)
    return SessionProcess(scene, recordings_dir, config=config, session_id=session_id)
