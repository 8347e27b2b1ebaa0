"""Idle websockets are closed (bt_teleop/ui/connections.py): a silent tab is told and closed, its
server-side socket and file descriptor go away; a tab that talks, or records, stays."""

from __future__ import annotations

import threading

import msgspec
import psutil
import pytest

from bt_pipeline.exceptions import ConfigError
from bt_teleop.app import IDLE_TITLE, AppOptions
from bt_teleop.testing.harness import CAMERA_MESSAGE, FakeTab, wait_until
from bt_teleop.ui.connections import ConnectionWatch


def _closed(tab: FakeTab) -> bool:
    return not tab._thread.is_alive()  # its reader ends when the server closes the socket


def _server_sockets(port: int) -> int:
    """Established TCP sockets of this process on the app's port (the server's ends)."""
    return sum(
        1
        for c in psutil.Process().net_connections(kind="tcp")
        if c.laddr and c.laddr.port == port and c.status != psutil.CONN_LISTEN
    )


def test_a_silent_tab_is_told_then_closed_and_its_socket_released(make_app, tabs) -> None:
    app = make_app(idle_timeout_s=0.5)
    fds_before = psutil.Process().num_fds()
    tab = tabs(app)  # sends its first camera message, then nothing
    app.wait_for_sessions(1)
    wait_until(lambda: _closed(tab), 30.0, "the idle tab to be closed")
    assert IDLE_TITLE in tab.text()
    assert tab.ws.close_code == 1001
    wait_until(lambda: not app.sessions(), 10.0, "the idle session to end")
    wait_until(lambda: _server_sockets(app.port) == 0, 10.0, "the server's socket to close")
    assert app.connections.open_connections() == 0
    assert app.connections.closed_idle == 1
    tab.close()
    # generous: a loaded machine (the suite beside a soak) took over 10 s once
    wait_until(lambda: psutil.Process().num_fds() <= fds_before, 30.0, "fds back to baseline")


def test_a_tab_that_talks_stays_while_a_silent_one_is_closed(make_app, tabs) -> None:
    app = make_app(idle_timeout_s=2.0)
    talking, silent = tabs(app), tabs(app)
    app.wait_for_sessions(2)
    stop = threading.Event()

    def talk() -> None:  # what a page sends while someone moves the camera
        while not stop.wait(0.1):
            talking.ws.send(msgspec.msgpack.encode(CAMERA_MESSAGE))

    talker = threading.Thread(target=talk, daemon=True)
    talker.start()
    try:
        wait_until(lambda: _closed(silent), 30.0, "the silent tab to be closed")
        closed_at = app.connections.closed_idle
        wait_until(lambda: len(app.sessions()) == 1, 10.0, "the silent session to end")
        # two more timeouts: the talking tab is checked again and again
        assert not stop.wait(4.0)
        assert not _closed(talking) and len(app.sessions()) == 1
        assert app.connections.closed_idle == closed_at
    finally:
        stop.set()
        talker.join(5.0)


def test_a_tab_recording_a_take_is_never_idle(make_app, tabs) -> None:
    app = make_app(idle_timeout_s=0.5)
    tab = tabs(app)
    ui = next(iter(app.wait_for_sessions(1).values()))
    ui.controls.name_input.value = "alice"
    ui.record()  # as a click on Record would; then the tab says nothing for 4 timeouts
    wait_until(lambda: ui.session.recording, 10.0, "the take to start")
    assert not threading.Event().wait(2.0)
    assert not _closed(tab) and ui.session.recording
    ui.stop_and_save()
    wait_until(lambda: _closed(tab), 30.0, "the tab to be closed once the take is saved")
    assert list((app.options.recordings / "wiping").glob("*.hdf5")), "the take was not saved"


def test_the_idle_timeout_must_be_positive(tmp_path) -> None:
    with pytest.raises(ConfigError, match="--idle-timeout-s must be > 0"):
        AppOptions(recordings=tmp_path, idle_timeout_s=0.0)
    AppOptions(recordings=tmp_path, idle_timeout_s=float("inf"))  # never


def test_idle_clients_skips_busy_ones_and_restarts_their_clock() -> None:
    class _Ws:  # the attributes ConnectionWatch uses of viser's WebsockServer
        def __init__(self) -> None:
            self._live_connections: dict[int, object] = {}
            self._background_event_loop = None

        async def _handle_incoming_message(self, client_id, message) -> None:
            return None

    class _Server:
        _websock_server = _Ws()

    busy = {1}
    watch = ConnectionWatch(_Server(), float("inf"), busy=lambda c: c in busy)  # type: ignore[arg-type]
    watch.idle_timeout_s = 10.0
    watch.touch(1)
    watch.touch(2)
    later = watch._last[2] + 11.0
    assert watch.idle_clients(now=later) == [2]
    assert watch._last[1] == later  # busy: its silence starts again now
    busy.clear()
    assert watch.idle_clients(now=later + 5.0) == [2]
    assert watch.idle_clients(now=later + 10.5) == [1, 2]
