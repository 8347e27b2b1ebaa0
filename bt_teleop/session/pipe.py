"""The app's end of a session child's pipe (:class:`~bt_teleop.session.process.SessionProcess`):
calls matched to their replies by sequence number, one-way commands that never block, and the
line between a child that is slow and one that is gone.

::

    request(name, args, timeout_s, quick)       one caller at a time (a quick one waits for the
        send held one-way commands, then (seq, name, args)     others at most timeout_s)
        read replies in order:   seq < ours   a late reply (its caller gave up) -> on_late
                                 seq == ours  the value, or the child's error raised here
        nothing by timeout_s:    quick   SessionBusyError (its reply is dropped when it comes)
                                 else    ChildGone
        EOF, the process ended, or the oldest unanswered request older than its limit
            (unresponsive_s; a save's own timeout when longer)  -> ChildGone
    send_one_way(name, args)    never blocks: while the child does not read (stopped, starved)
        and its pipe is full, the latest value of each command is held and sent first next time
    drain(timeout_s)            the child was told to end: read its last replies until EOF

A child whose replies come late is slow, not lost: a late reply is recognised by its sequence
number and never taken as the answer to a later call (replies come in order over one pipe).
The child's side: :mod:`bt_teleop.session.child`.
"""

from __future__ import annotations

import collections
import logging
import multiprocessing.connection
import select
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from bt_pipeline.exceptions import SessionBusyError

__all__ = ["BUSY_WARNING", "ChildGone", "ChildPipe"]

LOGGER = logging.getLogger("bt.teleop")
BUSY_WARNING = "the simulation is not answering (busy machine?); its last state is shown"
"""The status line's warning while a child is slow to answer."""
POLL_S = 0.25
"""How often a waiting call checks that the child still runs [s]."""

OnLate = Callable[[str, bool, Any], None]
"""Called with (the call's name, ok, value) for a late reply; name "exit" for the file the
child reports when it ends without being asked to close (SIGTERM, EOF)."""


class ChildGone(Exception):
    """The child died or stopped answering (the message says which); it is lost."""


@dataclass(frozen=True)
class _Asked:
    seq: int
    name: str
    sent_s: float
    """When it was sent (time.monotonic) [s]."""
    limit_s: float
    """Longest the child may take to answer it before it is gone [s]."""


class ChildPipe:
    """The app's end of one child's pipe; thread-safe."""

    def __init__(
        self,
        conn: multiprocessing.connection.Connection,
        process: Any,
        *,
        unresponsive_s: float,
        on_late: OnLate,
    ) -> None:
        """Wrap `conn` to `process` (a started ``multiprocessing`` process), which answers
        seq 0 when its session is made (:meth:`started`).

        Args:
            unresponsive_s: A child that answers none of the requests sent to it for this long
                [s] is gone (a save may take its own, longer timeout).
            on_late: Gets each late reply (:data:`OnLate`).
        """
        self.conn = conn
        self.process = process
        self.unresponsive_s = float(unresponsive_s)
        self._on_late = on_late
        self._seq = 0
        self._asked: collections.deque[_Asked] = collections.deque()
        self._held: dict[str, tuple[Any, ...]] = {}
        self._lock = threading.Lock()  # one caller reads the replies
        self._send_lock = threading.Lock()  # whole messages (one-way ones come from any thread)

    def started(self, timeout_s: float) -> Any:
        """The child's first reply (seq 0: its control period, or its error raised here)."""
        with self._lock:
            self._asked.append(_Asked(0, "start", time.monotonic(), timeout_s))
            return self._await(0, "start", time.monotonic() + timeout_s, quick=False)

    def send_one_way(self, name: str, args: tuple[Any, ...]) -> None:
        """Send a command without reply; held (latest value only) while the pipe is full.

        Raises:
            ChildGone: The pipe broke.
        """
        with self._send_lock:
            self._held.pop(name, None)
            self._held[name] = args
            self._flush(0.0)

    def request(self, name: str, args: tuple[Any, ...], timeout_s: float, *, quick: bool) -> Any:
        """Send a request and wait for its reply.

        Args:
            timeout_s: Longest wait [s], for the pipe too.
            quick: On time out raise SessionBusyError (the child stays; its reply is dropped
                later), not ChildGone.

        Raises:
            SessionBusyError: `quick` and no reply in time.
            ChildGone: The child ended or did not answer in time (or `unresponsive_s`).
            BtError: The child's error (and any other it raised, with its traceback).
        """
        deadline = time.monotonic() + timeout_s
        if not self._lock.acquire(timeout=timeout_s if quick else -1):
            raise SessionBusyError(BUSY_WARNING)
        try:
            while True:  # the held commands, then ours, once the pipe has room for them
                with self._send_lock:  # never held while waiting: one-way senders never wait
                    if self._flush(0.0) and self._writable(0.0):
                        self._seq += 1
                        seq = self._seq
                        self._send((seq, name, args))
                        limit_s = max(self.unresponsive_s, timeout_s)
                        self._asked.append(_Asked(seq, name, time.monotonic(), limit_s))
                        break
                remaining = deadline - time.monotonic()
                if remaining <= 0.0:
                    if quick:
                        raise SessionBusyError(BUSY_WARNING)
                    raise ChildGone(f"it did not read its pipe for {timeout_s:g} s")
                try:  # read late replies meanwhile: the child may wait to send them
                    while self.conn.poll(0.0):
                        self._dispatch(self.conn.recv())
                except (EOFError, OSError):
                    raise ChildGone(self._ended()) from None
                self._writable(min(0.05, remaining))
            return self._await(seq, name, deadline, quick=quick)
        finally:
            self._lock.release()

    def drain(self, timeout_s: float) -> bool:
        """Read the replies left until the child closes its end (it was told to end), each to
        on_late; whether it did within `timeout_s` [s]."""
        deadline = time.monotonic() + timeout_s
        with self._lock:
            while True:
                try:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0.0:
                        return False
                    alive = self.process.is_alive()  # before: all it sent is in the pipe
                    if self.conn.poll(min(POLL_S, remaining)):
                        self._dispatch(self.conn.recv())
                    elif not alive:
                        return True
                except (EOFError, OSError):
                    return True
                except Exception:  # a reply cut short (killed while sending): nothing more
                    LOGGER.exception("reading a lost session child's last replies")
                    return False

    # -- internals -----------------------------------------------------------------------------

    def _await(self, seq: int, name: str, deadline: float, *, quick: bool) -> Any:
        """Read replies until `seq`'s (under the lock)."""
        while True:
            now = time.monotonic()
            oldest = self._asked[0]
            if now - oldest.sent_s > oldest.limit_s:
                raise ChildGone(f"it answered nothing for {oldest.limit_s:g} s")
            if now >= deadline:
                if quick:
                    raise SessionBusyError(BUSY_WARNING)
                raise ChildGone(f"it did not answer {name} in time")
            try:
                if not self.conn.poll(min(POLL_S, deadline - now)):
                    if not self.process.is_alive():
                        raise ChildGone(self._ended())
                    continue
                reply = self.conn.recv()
            except (EOFError, OSError):
                raise ChildGone(self._ended()) from None
            if reply[0] == seq:
                self._answered(seq)
                _, ok, value = reply
                if not ok:
                    raise value
                return value
            self._dispatch(reply)

    def _dispatch(self, reply: tuple[int | None, bool, Any]) -> None:
        """A reply nobody waits for: a late one, or the file saved as the child ended."""
        seq, ok, value = reply
        name = "exit" if seq is None else self._answered(seq)
        LOGGER.debug("a late reply to %s (seq %s)", name, seq)
        self._on_late(name, ok, value)

    def _answered(self, seq: int) -> str:
        """Forget the requests up to `seq` (answered in order); `seq`'s name."""
        name = "?"
        while self._asked and self._asked[0].seq <= seq:
            name = self._asked.popleft().name
        return name

    def _flush(self, wait_s: float) -> bool:
        """Send the held one-way commands (under the send lock); whether all went."""
        while self._held:
            if not self._writable(wait_s):
                return False
            name = next(iter(self._held))
            self._send((None, name, self._held.pop(name)))
        return True

    def _writable(self, wait_s: float) -> bool:
        """Whether a message fits in the pipe (a Unix socket: 3/4 of its buffer free), waiting
        up to `wait_s` [s]; True for a closed pipe (sending then says it broke)."""
        try:
            poller = select.poll()  # one per call: a poll object refuses concurrent use
            poller.register(self.conn.fileno(), select.POLLOUT)
        except (OSError, ValueError):
            return True
        return bool(poller.poll(max(0, round(1e3 * wait_s))))

    def _send(self, message: tuple[int | None, str, tuple[Any, ...]]) -> None:
        try:
            self.conn.send(message)
        except (OSError, ValueError) as exc:
            # Most often the child ended (killed): say so, with its exit code, as a read does.
            if self._exit_code() is None:
                raise ChildGone(f"its pipe broke ({exc})") from None
            raise ChildGone(self._ended()) from None

    def _exit_code(self) -> int | None:
        """The child's exit code, waiting up to 1 s for it to end; None: still running, or its
        process object already closed."""
        try:
            self.process.join(1.0)
            return self.process.exitcode
        except ValueError:  # closed by the owner (SessionProcess._end_process)
            return None

    def _ended(self) -> str:
        code = self._exit_code()
        return "its process ended" + (f" (exit code {code})" if code is not None else "")
