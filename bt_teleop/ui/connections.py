"""The app's websocket connections: when each last spoke, closing one, closing the idle ones.

::

    ConnectionWatch(server, idle_timeout_s, busy)
      every message a client sends      -> touch(client_id)   (viser's message dispatch, wrapped)
      a thread, every CHECK_EVERY_S     -> a client silent for idle_timeout_s and not busy(id)
                                           gets a notice, then its socket is closed (1001)
      close(client_id, code, reason)    -> closes one socket (refused tabs use it too)

viser 1.1 has no public call to close one client's socket nor a hook that sees every incoming
message, so both go through its ``WebsockServer`` (``_live_connections``, which viser's own
``disconnect_all_clients`` uses, and ``_handle_incoming_message``, which its connection handler
calls for every message). A closed tab's page retries only while it has the focus, so a tab
left in the background stays closed; a focused one reconnects as a new session.
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
import time
from collections.abc import Callable, Coroutine
from typing import Any, cast

import viser

LOGGER = logging.getLogger("bt.teleop")
CHECK_EVERY_S = 5.0
"""Longest time between two idle checks [s] (shorter for a shorter timeout)."""
IDLE_NOTICE_S = 1.0
"""How long an idle tab's socket stays open after its notice, so the notice arrives [s]."""
IDLE_CLOSE_CODE = 1001
"""Websocket close code of an idle tab ("going away")."""


class LoopSafeEvent(asyncio.Event):
    """An :class:`asyncio.Event` whose ``set()`` does nothing unless called on its own event
    loop's thread (:func:`loop_safe_wakeups` puts it under viser's message buffers).

    viser 1.1.1's ``AsyncMessageBuffer.push`` calls ``message_event.set()`` directly from
    whichever thread queues a message (our tabs' publisher threads), then again on the loop
    through ``call_soon_threadsafe`` (at once, or at the end of an ``atomic()`` block).
    ``asyncio.Event`` is not thread-safe: the direct call raced the loop adding a waiter
    ("RuntimeError: deque mutated during iteration" in a soak, 2026-12-03 19:20), and such a
    race can leave the waiter unresolved with the flag already set, after which every ``set()``
    is a no-op and that tab gets no message again. The loop-side call that always follows
    wakes the consumer; nothing in viser reads the flag off the loop."""

    _bt_loop: asyncio.AbstractEventLoop | None = None

    def set(self) -> None:
        try:
            running = asyncio.get_running_loop()
        except RuntimeError:
            return  # a thread without a loop: the loop-side set() that follows wakes it
        if self._bt_loop is None or running is self._bt_loop:
            super().set()


def loop_safe_wakeups(buffer: Any) -> None:
    """Make `buffer`'s (a viser ``AsyncMessageBuffer``) message wake-ups thread-safe
    (:class:`LoopSafeEvent`); a buffer without the attributes is left alone."""
    event, loop = getattr(buffer, "message_event", None), getattr(buffer, "event_loop", None)
    if type(event) is asyncio.Event:
        event.__class__ = LoopSafeEvent  # the same object: waiters already queued stay
        cast(LoopSafeEvent, event)._bt_loop = loop


class ConnectionWatch:
    """Notes when each client last sent a message and closes those idle for too long."""

    def __init__(
        self,
        server: viser.ViserServer,
        idle_timeout_s: float,
        busy: Callable[[int], bool],
        notify: Callable[[int], None] | None = None,
    ) -> None:
        """Start watching `server`'s connections.

        Args:
            server: The app's viser server.
            idle_timeout_s: A client that sends no message for this long is closed [s];
                ``math.inf`` never closes one.
            busy: Whether a client must stay open however long it is silent (e.g. its session
                is recording a take); called from the watch thread.
            notify: Tells a client it is about to be closed (called once, before the close).
        """
        self.idle_timeout_s = idle_timeout_s
        self._server = server
        self._ws = server._websock_server  # private: see the module docstring
        self._busy = busy
        self._notify = notify
        self._lock = threading.Lock()
        self._last: dict[int, float] = {}  # client id -> monotonic time of its last message
        self._closing: set[int] = set()
        self.closed_idle = 0
        """Connections closed for being idle so far."""
        original = self._ws._handle_incoming_message

        async def handle(client_id: Any, message: Any) -> None:
            self.touch(int(client_id))
            await original(client_id, message)

        self._ws._handle_incoming_message = handle  # type: ignore[method-assign]
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if math.isfinite(idle_timeout_s):
            self._thread = threading.Thread(target=self._run, name="bt-idle", daemon=True)
            self._thread.start()

    def touch(self, client_id: int, now: float | None = None) -> None:
        """Note that `client_id` sent a message (or connected) at `now` (monotonic [s])."""
        with self._lock:
            if client_id not in self._closing:
                self._last[client_id] = time.monotonic() if now is None else now

    def forget(self, client_id: int) -> None:
        """Stop watching `client_id` (its socket closed)."""
        with self._lock:
            self._last.pop(client_id, None)
            self._closing.discard(client_id)

    def open_connections(self) -> int:
        """Websockets open right now (tabs with a session, refused tabs, tabs being set up)."""
        return len(self._ws._live_connections)

    def close(self, client_id: int, code: int, reason: str) -> bool:
        """Close `client_id`'s websocket with `code` and `reason`; whether it was still open."""
        loop = self._ws._background_event_loop
        connection = self._ws._live_connections.get(client_id)
        if loop is None or connection is None or loop.is_closed():
            return False
        closing: Coroutine[Any, Any, None] = connection.close(code, reason)
        asyncio.run_coroutine_threadsafe(closing, loop)
        return True

    def stop(self) -> None:
        """Stop the watch thread."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)

    def idle_clients(self, now: float | None = None) -> list[int]:
        """Clients silent for longer than the timeout and not busy (a busy one counts as
        active: its silence starts when it stops being busy)."""
        now = time.monotonic() if now is None else now
        with self._lock:
            silent = [c for c, t in self._last.items() if now - t > self.idle_timeout_s]
        idle = []
        for client_id in silent:
            if self._busy(client_id):
                self.touch(client_id, now)
            else:
                idle.append(client_id)
        return idle

    def _run(self) -> None:
        period = min(CHECK_EVERY_S, max(self.idle_timeout_s / 4.0, 0.05))
        while not self._stop.wait(period):
            self._close_idle(self.idle_clients())

    def _close_idle(self, client_ids: list[int]) -> None:
        """Tell each idle client, wait for the notices to go out, then close them."""
        with self._lock:
            marked = [c for c in client_ids if c not in self._closing]
            self._closing.update(marked)
            for client_id in marked:
                self._last.pop(client_id, None)
        if not marked:
            return
        for client_id in marked:
            LOGGER.info("tab %d closed: idle for %.0f s", client_id, self.idle_timeout_s)
            if self._notify is not None:
                try:
                    self._notify(client_id)
                except Exception:  # the tab may be going already; close it all the same
                    LOGGER.debug("tab %d: idle notice not sent", client_id, exc_info=True)
        if self._notify is not None and self._stop.wait(IDLE_NOTICE_S):
            return
        for client_id in marked:
            if self.close(client_id, IDLE_CLOSE_CODE, "idle"):
                self.closed_idle += 1
            else:
                self.forget(client_id)


__all__ = ["IDLE_CLOSE_CODE", "ConnectionWatch"]
