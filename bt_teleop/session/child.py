"""The child process of a :class:`~bt_teleop.session.process.SessionProcess`: one tab's
session, served over a pipe.

::

    serve_session(conn, task, robot, recordings_dir, config, session_id, log_level)   main thread
        TimedSession(task, robot)  -> reply (0, True, dt_s), or (0, False, the error)
        loop: (seq, name, args) = conn.recv()
            one-way (set_target, set_gripper, set_stay_on_plane; seq None): applied, no reply
            request (status, trail, ...; seq 1, 2, ...): reply (seq, True, value) or
                (seq, False, error); the app matches a reply to its call by seq, so a reply
                that comes after the app stopped waiting for it is never taken for another's
            after stop_and_check / discard: release_free_memory() (HDF5's free lists, the C
                heap's free pages), once the reply is sent
            close: settle the take as asked, reply (seq, True, path), exit
        EOF (the app died), SIGTERM (its parent, the forkserver, died; or the app gave up on
            this child, session/process.py): the take is settled as a closed tab's (saved
            flagged incomplete), (None, True, path) is sent if anyone still listens, exit

The control loop runs in the session's own thread at real time; this process's GIL is shared
only by it and the command thread. SIGINT is ignored (Ctrl-C reaches the terminal's whole
process group; the app closes its sessions itself). SIGTERM ends the wait for a command at
once, but never a command being served or a reply being sent (a reply cut short would garble
the pipe): those finish first.
"""

from __future__ import annotations

import contextlib
import dataclasses
import gc
import logging
import multiprocessing.connection
import signal
import sys
from pathlib import Path
from typing import Any

from bt_pipeline.exceptions import ConfigError
from bt_teleop.proc.child import die_with_parent, portable_error
from bt_teleop.proc.native_memory import hdf5_free_lists, heap_info, release_free_memory
from bt_teleop.proc.priority import command_priority, raise_priority, use_realtime
from bt_teleop.session.config import SessionConfig
from bt_teleop.session.tick_stats import TimedSession

__all__ = [
    "CALLS",
    "ONE_WAY",
    "PROCESS_CALLS",
    "serve_session",
]

Reply = tuple[int | None, bool, Any]
"""(the request's seq, or None for the path saved at EOF or SIGTERM; ok; value or error)."""

LOGGER = logging.getLogger("bt.teleop")
ONE_WAY = frozenset({"set_target", "set_gripper", "set_stay_on_plane"})
"""Commands the child applies without a reply."""
CALLS = frozenset(
    {"status", "trail", "recording", "start", "stop", "start_recording", "stop_and_check"}
    | {"discard", "close", "tick_stats", "reset"}
)
"""Requests the child answers (methods, or properties read)."""
PROCESS_CALLS = {
    "heap_info": heap_info,
    "hdf5_free_lists": hdf5_free_lists,
    "allocated_blocks": sys.getallocatedblocks,
}
"""Requests about the child process itself, not its session (its C heap, HDF5's free lists,
the number of Python objects' memory blocks; for benchmarks and tests)."""
ENDS_A_TAKE = frozenset({"stop_and_check", "discard"})
"""Requests after which the child releases free memory (``release_memory_after_take``)."""


def serve_session(
    conn: multiprocessing.connection.Connection,
    task: str,
    robot: str,
    recordings_dir: Path,
    config: SessionConfig,
    session_id: str,
    log_level: int = logging.WARNING,
) -> None:
    """The child's main thread: make the session, then serve commands until close or EOF.

    Its log lines (saved takes, warnings) go to the app's stderr as the app's do, at the app's
    `log_level`.
    """
    logging.basicConfig(level=log_level, format="bt: %(message)s", stream=sys.stderr)
    gc.freeze()  # what the forkserver imported: never traversed here, so its pages stay shared
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C: the app closes us itself
    signal.signal(signal.SIGTERM, _Term.on_sigterm)
    die_with_parent()
    # The thread serving the app's requests takes the GIL the control loop needs: it runs at the
    # loop's raised priority too (the loop's thread, started from it, inherits it). At a lower
    # one, preempted while holding the GIL, it stalled the loop (a priority inversion).
    raise_priority(config.priority_boost)
    # The same for SCHED_RR (the GIL is shared), one step below the loop: a take's save here
    # (up to ~0.1 s on a CPU) must not queue other sessions' loops behind it for SCHED_RR's 0.1 s
    # quantum, as it did at one priority for all (docs/security.md, "Real-time by default").
    use_realtime(command_priority(config.realtime_priority), quiet=True)
    try:
        session = TimedSession(
            task,
            recordings_dir,
            robot=robot,
            config=dataclasses.replace(config, priority_boost=0),
            session_id=session_id,
        )
    except BaseException as exc:
        _send_reply(conn, 0, False, exc)
        return
    session.late_probe.watch_peer()  # this thread shares the loop's GIL: a late tick reads it
    _send_reply(conn, 0, True, session.dt_s)
    save_incomplete: bool | None = None  # EOF or SIGTERM: the app is gone; as a closed tab
    close_seq: int | None = None
    try:
        while True:
            seq, name, args = _Term.receive(conn)
            if name == "close":
                save_incomplete, close_seq = args[0], seq
                break
            try:
                attr = PROCESS_CALLS.get(name) or (
                    getattr(session, name) if name in ONE_WAY | CALLS else None
                )
                if attr is None:
                    raise ConfigError(f"unknown session command {name!r}")
                with session.late_probe.serving(name):
                    value = attr(*args) if callable(attr) else attr
            except Exception as exc:
                if seq is not None:
                    _send_reply(conn, seq, False, exc)
                continue
            if seq is not None:
                _send_reply(conn, seq, True, value)
            if name in ENDS_A_TAKE and config.release_memory_after_take:
                with session.late_probe.serving("release_memory"):  # after the reply: no wait
                    release_free_memory()
    except (EOFError, OSError, SystemExit):
        pass
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)  # let the take be saved
        path = _close_quietly(session, save_incomplete)
    _send_reply(conn, close_seq, True, path)


def _close_quietly(session: Any, save_incomplete: bool | None) -> Path | None:
    try:
        return session.close(save_incomplete=save_incomplete)
    except Exception:
        LOGGER.exception("session %s: closing failed", session.session_id)
        return None


def _send_reply(
    conn: multiprocessing.connection.Connection, seq: int | None, ok: bool, value: Any
) -> None:
    """Send (seq, ok, value), an error made portable first (:func:`portable_error`)."""
    if not ok:
        value = portable_error(value)
    reply: Reply = (seq, ok, value)
    with contextlib.suppress(OSError, ValueError):  # the app is gone
        conn.send(reply)


class _Term:
    """SIGTERM: ends the wait for a command at once; a command being served finishes first."""

    waiting = False
    """Whether the main thread waits for a command (in :meth:`receive`)."""
    asked = False
    """Whether SIGTERM came."""

    @classmethod
    def on_sigterm(cls, _signum: int, _frame: object) -> None:
        cls.asked = True
        if cls.waiting:
            raise SystemExit(0)

    @classmethod
    def receive(cls, conn: multiprocessing.connection.Connection) -> tuple[int | None, str, Any]:
        """The next command (seq, name, args); SystemExit once SIGTERM came."""
        cls.waiting = True
        try:
            if cls.asked:
                raise SystemExit(0)
            return conn.recv()
        finally:
            cls.waiting = False
