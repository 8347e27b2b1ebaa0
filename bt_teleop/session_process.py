"""A session whose simulation runs in a child process of its own (one GIL per control loop).

The app's tabs share one interpreter: viser's event loop, the tabs' publishers, Rerun logging
and library loads. In it, 8 control loops ran at 219 of the 800 ticks/s they asked for, and a
tick waited up to 177 ms for the GIL (docs/security.md, soak). :class:`SessionProcess` moves a
tab's :class:`~bt_teleop.session.Session` (MuJoCo, mink IK, the control loop, the recorder and
the take saving) into a child process and keeps the part of its API the app uses::

    main process (the app)                      child process (one per tab)
    SessionProcess ──Pipe──────────────────────▶ main thread: serve commands
      set_target / set_gripper / set_stay_on_plane   one-way (validated here, never wait)
      status / trail / recording / start_recording   request → reply (pickled; errors raised
      stop_and_check / discard / close / tick_stats      again here, BtError messages kept)
      .scene: its own SceneModel (for drawing)  control thread: TimedSession at real time

Children are forked by a ``forkserver`` that has imported MuJoCo and mink once (never plain
``fork``: the app has many threads), so a child starts in well under a second and shares those
pages. A child ends with its tab (:meth:`SessionProcess.close`), when its pipe reaches EOF
(the app died: a take in progress is then saved flagged incomplete, as a closed tab's is), or
at SIGTERM, which it asks the kernel to send it when the forkserver (its parent, which exits
when the app does) dies, even after a ``kill -9`` of the app. SIGINT is ignored: Ctrl-C in the
terminal reaches the whole process group, and the app closes each session itself.

A child that dies or stops answering (no reply within ``timeout_s``) is killed and marked
lost: :meth:`SessionProcess.status` then returns the last status with the reason as its
warning (the tab's status line shows it), one-way commands are dropped, and every other call
raises :class:`~bt_pipeline.exceptions.SessionLostError` naming the session and the reason.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import multiprocessing
import multiprocessing.connection
import multiprocessing.forkserver
import multiprocessing.spawn
import secrets
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError, SessionLostError
from bt_teleop.native_memory import Hdf5FreeLists, HeapInfo
from bt_teleop.scene import SceneModel
from bt_teleop.session_child import serve_session
from bt_teleop.session_config import SessionConfig, SessionStatus
from bt_teleop.session_recording import SavedTake
from bt_teleop.tick_stats import TickReport, TimedSession
from bt_teleop.workspace import validate_position, validate_quat

__all__ = ["SessionProcess", "TabSession", "open_session", "start_forkserver"]

LOGGER = logging.getLogger("bt.teleop")
START_TIMEOUT_S = 60.0
"""Longest wait for a child to load its scene and answer [s] (Menagerie meshes: seconds)."""
SAVE_TIMEOUT_S = 60.0
"""Longest wait for a call that writes a take (Stop & save, close) [s]."""

_context_lock = threading.Lock()


def _context() -> Any:
    """The forkserver context, its server preloaded with MuJoCo, mink and the session code.

    A session child needs nothing of the app's main module, but ``multiprocessing`` makes every
    child import it again (the script's whole import graph: viser, ... for ~80 MiB of private
    memory per child in benchmarks/bench_soak.py; CPython 3.11's forkserver cannot preload it,
    as it asks for a ``main_path`` key the preparation data never has). So the children started
    here get preparation data without the main module (:func:`_preparation_data`).
    """
    with _context_lock:
        if multiprocessing.spawn.get_preparation_data is not _preparation_data:
            global _stdlib_preparation_data
            _stdlib_preparation_data = multiprocessing.spawn.get_preparation_data
            multiprocessing.spawn.get_preparation_data = _preparation_data
        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload(["bt_teleop.session_child"])  # no effect once it runs
        return context


def start_forkserver() -> None:
    """Start the server that forks session children now (it then imports MuJoCo and mink in
    the background), not when the first session is made; a no-op once it runs."""
    _context()
    multiprocessing.forkserver.ensure_running()


_starting = threading.local()
"""``_starting.session`` is True while this thread starts a session child."""
_stdlib_preparation_data: Callable[[str], dict[str, Any]] | None = None


def _preparation_data(name: str) -> dict[str, Any]:
    """multiprocessing's data for a new child; without the main module for a session child."""
    assert _stdlib_preparation_data is not None
    data = _stdlib_preparation_data(name)
    if getattr(_starting, "session", False):
        data.pop("init_main_from_path", None)
        data.pop("init_main_from_name", None)
    return data


class SessionProcess:
    """A :class:`~bt_teleop.session.Session` run in a child process (the app's tabs)."""

    def __init__(
        self,
        scene: SceneModel,
        recordings_dir: str | Path = "recordings",
        *,
        config: SessionConfig | None = None,
        session_id: str | None = None,
        timeout_s: float = 5.0,
    ) -> None:
        """Start the child, which loads `scene`'s task and robot by name, and wait until it
        answers (its loop is not started: :meth:`start`).

        Args:
            scene: This process's copy of the scene (for drawing; the child loads its own).
            recordings_dir: Root folder; demos go to ``<recordings_dir>/<task>/``.
            config: Rates and policies; defaults when None.
            session_id: Stored in each demo's ep_meta; random when None.
            timeout_s: Longest wait for a reply to a quick call [s] (status, trail, ...).

        Raises:
            BtError: The session cannot be made (the child's error, e.g. ConfigError).
            SessionLostError: The child died or did not answer within START_TIMEOUT_S.
        """
        self.scene = scene
        self.config = config or SessionConfig()
        self.recordings_dir = Path(recordings_dir)
        self.session_id = session_id or secrets.token_hex(4)
        self.timeout_s = float(timeout_s)
        self._lost: str | None = None
        self._closed = False
        self._last_status: SessionStatus | None = None
        self._call_lock = threading.Lock()  # one request in flight: replies come in order
        self._send_lock = threading.Lock()
        context = _context()
        self._conn, child_end = context.Pipe()
        args = (child_end, scene.task, scene.robot, self.recordings_dir, self.config)
        self._process = context.Process(
            target=serve_session,
            args=(*args, self.session_id, LOGGER.getEffectiveLevel()),
            name=f"bt-session-{self.session_id}",
            daemon=True,
        )
        _starting.session = True
        try:
            self._process.start()
        finally:
            _starting.session = False
        child_end.close()  # only the child holds it now: its death is EOF here
        self._pid = self._process.pid
        with self._call_lock:
            self.dt_s: float = self._reply(START_TIMEOUT_S)
            """Control period [s]."""
        self._last_status = self.status()

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

    def stop(self) -> None:
        """Stop the child's control loop (the child stays)."""
        self._call("stop")

    def reset(self) -> None:
        """Put the robot at the ready pose with the gripper open and the target on it."""
        self._call("reset")

    def start_recording(
        self, demonstrator: str = "anonymous", theta_deg: float = math.nan, rho: float = math.nan
    ) -> None:
        """:meth:`Session.start_recording <bt_teleop.session.Session.start_recording>`."""
        self._call("start_recording", demonstrator, theta_deg, rho)

    def stop_and_check(self) -> SavedTake:
        """Stop the demo in progress, check it and write it (in the child); what was saved."""
        return self._call("stop_and_check", timeout_s=SAVE_TIMEOUT_S)

    def stop_and_save(self) -> Path:
        """:meth:`stop_and_check`, the path only."""
        return self.stop_and_check().path

    def discard(self) -> bool:
        """Drop the demo in progress without writing anything; whether there was one."""
        return self._call("discard")

    @property
    def recording(self) -> bool:
        """Whether a demo is being recorded (False once the child is lost or closed)."""
        if self._closed:
            return False
        try:
            return self._call("recording")
        except SessionLostError:
            return False

    def status(self) -> SessionStatus:
        """A snapshot of the session; once the child is lost, the last one, not running and
        with the reason as its warning."""
        try:
            status: SessionStatus = self._call("status")
        except SessionLostError as exc:
            if self._last_status is None:
                raise
            return dataclasses.replace(self._last_status, warning=str(exc), running=False)
        self._last_status = status
        return status

    def trail(self) -> FloatArray:
        """End-effector positions of the demo in progress, shape (T, 3) [m] (empty if none or
        lost)."""
        if self._closed:
            return np.zeros((0, 3))
        try:
            return self._call("trail")
        except SessionLostError:
            return np.zeros((0, 3))

    def tick_stats(self) -> TickReport:
        """The control loop's tick timing so far (gaps, stalls; :mod:`bt_teleop.tick_stats`)."""
        return self._call("tick_stats")

    def heap_info(self) -> HeapInfo | None:
        """The child's C heap (:func:`bt_teleop.native_memory.heap_info`)."""
        return self._call("heap_info")

    def hdf5_free_lists(self) -> Hdf5FreeLists | None:
        """What HDF5's free lists hold in the child
        (:func:`bt_teleop.native_memory.hdf5_free_lists`)."""
        return self._call("hdf5_free_lists")

    def allocated_blocks(self) -> int:
        """Memory blocks Python's allocator has handed out in the child
        (``sys.getallocatedblocks``; Python objects kept show as a count that grows)."""
        return self._call("allocated_blocks")

    @property
    def pid(self) -> int | None:
        """The child's process id."""
        return self._pid

    @property
    def lost(self) -> str | None:
        """Why the child is gone (None while it answers)."""
        return self._lost

    def close(self, save_incomplete: bool | None = None) -> Path | None:
        """End the session and its child; a demo in progress is settled as
        :meth:`Session.close <bt_teleop.session.Session.close>` does. Returns the file saved."""
        if self._closed:
            return None
        self._closed = True
        path: Path | None = None
        with contextlib.suppress(SessionLostError):  # logged when it was lost
            path = self._call("close", save_incomplete, timeout_s=SAVE_TIMEOUT_S)
        self._process.join(5.0)
        if self._process.is_alive():
            self._process.kill()
            self._process.join(5.0)
        self._conn.close()
        if self._process.exitcode is not None:
            self._process.close()  # its sentinel fd (pid and exitcode stay readable here)
        return path

    def __enter__(self) -> SessionProcess:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # -- internals -----------------------------------------------------------------------------

    def _send_one_way(self, name: str, *args: Any) -> None:
        if self._lost is not None or self._closed:
            return  # the status line says why
        try:
            with self._send_lock:
                self._conn.send((name, args))
        except (OSError, ValueError) as exc:
            self._lose(f"its pipe broke ({exc})")

    def _call(self, name: str, *args: Any, timeout_s: float | None = None) -> Any:
        with self._call_lock:
            if self._lost is not None:
                raise SessionLostError(self._lost)
            if self._closed and name != "close":
                raise ConfigError(f"session {self.session_id} is closed")
            try:
                with self._send_lock:
                    self._conn.send((name, args))
            except (OSError, ValueError) as exc:
                raise self._lose(f"its pipe broke ({exc})") from None
            return self._reply(self.timeout_s if timeout_s is None else timeout_s)

    def _reply(self, timeout_s: float) -> Any:
        """The child's next reply (under the call lock): its value, or its error raised."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                if self._conn.poll(min(0.25, max(0.0, deadline - time.monotonic()))):
                    ok, value = self._conn.recv()
                    break
            except (EOFError, OSError):
                raise self._lose(f"its process ended (exit code {self._exit_code()})") from None
            if not self._process.is_alive():
                raise self._lose(f"its process ended (exit code {self._exit_code()})")
            if time.monotonic() >= deadline:
                raise self._lose(f"it did not answer within {timeout_s:g} s")
        if not ok:
            raise value
        return value

    def _exit_code(self) -> int | None:
        self._process.join(1.0)
        return self._process.exitcode

    def _lose(self, reason: str) -> SessionLostError:
        """Mark the child lost (killing it if it still runs); the error to raise."""
        if self._lost is None:
            self._lost = (
                f"the simulation of session {self.session_id} stopped: {reason}; "
                "reload the page to start a new one"
            )
            LOGGER.warning("%s", self._lost)
            if self._process.is_alive():
                self._process.kill()
        return SessionLostError(self._lost)


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
