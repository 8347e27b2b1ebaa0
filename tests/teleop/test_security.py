"""bt teleop against hostile or careless clients: loopback-only sockets, refused sockets closed,
values from a browser validated on the server, clean jobs time-limited, cancellable, per task."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import psutil
import pytest

from bt_pipeline.clean.pipeline import CleanOptions
from bt_pipeline.data.recording import read_recording
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.testing.sockets import is_loopback_address, listening
from bt_teleop import app as app_module
from bt_teleop.app import AppOptions, is_loopback, start_app
from bt_teleop.clean.runner import CleanRunner
from bt_teleop.library.reader_process import READER_NAME
from bt_teleop.session.script import run_script
from bt_teleop.takes.recorder import DemoInfo
from bt_teleop.testing.harness import FakeTab, wait_until
from bt_teleop.ui.tab import ClientUI

REPO = Path(__file__).resolve().parents[2]


def _closed(tab: FakeTab) -> bool:
    return not tab._thread.is_alive()  # its reader ends when the server closes the socket


def test_refused_tabs_are_told_then_closed_and_never_pile_up(make_app, tabs) -> None:
    app = make_app(max_sessions=1)
    kept = tabs(app)
    app.wait_for_sessions(1)
    refused = [tabs(app) for _ in range(6)]
    wait_until(lambda: all(_closed(tab) for tab in refused), 20.0, "refused sockets to close")
    assert "server is full" in refused[0].text()
    # The tab sees its socket close a moment before the server has forgotten it (under load).
    wait_until(lambda: app.refused_open() == 0, 20.0, "the server to release refused sockets")
    assert not _closed(kept) and len(app.sessions()) == 1


@pytest.mark.parametrize(
    ("theta", "rho", "match"),
    [
        (0.0, 1e-300, "rho must lie in \\[0.5, 1.5\\]"),
        (0.0, 1e308, "rho must lie in"),
        (45.0, 1.0, "theta_deg must lie in \\[-30, 30\\]"),
    ],
)
def test_preferences_outside_the_sliders_are_refused_on_the_server(theta, rho, match) -> None:
    with pytest.raises(ConfigError, match=match):
        DemoInfo("a", theta, rho, created=_now())
    assert math.isnan(DemoInfo("a", math.nan, math.nan, created=_now()).rho)  # unknown is fine


def test_a_browser_sending_rho_1e_300_records_with_a_valid_rho(make_app, tabs) -> None:
    app = make_app()
    tabs(app)
    (ui,) = app.wait_for_sessions(1).values()
    assert isinstance(ui, ClientUI)
    ui.controls.rho_input.value = 1e-300  # what a websocket client can send
    assert ui.controls.rho == 1.0  # the server keeps the last value inside the slider's range
    ui.controls.record_button.value = True
    assert ui.wait_idle()
    assert ui.session.status().recording
    time.sleep(1.0)  # the session runs in real time: let it record a few samples
    saved = read_recording(ui.session.stop_and_save())
    assert [d.rho for d in saved.demos.values()] == [1.0]  # never 1e-300


def test_absurd_gizmo_targets_are_refused(make_app, tabs) -> None:
    app = make_app()
    tabs(app)
    (ui,) = app.wait_for_sessions(1).values()
    before = ui.session.status().command_pos.copy()
    for target in ([1e30, 0.0, 0.0], [np.nan, 0.0, 0.0], [0.0, 0.0]):
        with pytest.raises(ConfigError):
            ui.session.set_target(target)
    assert np.allclose(ui.session.status().command_pos, before, atol=0.05)


@pytest.fixture
def recordings(tmp_path: Path) -> Path:
    root = tmp_path / "recordings"
    times = np.linspace(0.0, 2.0, 21)
    phase = np.pi * times
    rows = np.stack([times, 0.08 * np.cos(phase), 0.04 * np.sin(phase)], axis=1).tolist()
    for task in ("wiping", "weaving"):
        script = {"task": task, "demonstrator": "ci", "theta_deg": 0, "rho": 1, "waypoints": rows}
        run_script(script, root)
    return root


def test_a_clean_job_past_its_time_limit_is_stopped_and_blocks_no_other_task(recordings) -> None:
    runner = CleanRunner(
        recordings, CleanOptions(epochs=2, write_rrd=False), processes=True, timeout_s=0.3
    )
    stuck = runner.start("wiping")
    other = runner.start("weaving")  # another task starts at once: nothing blocks it
    with pytest.raises(ConfigError, match="wiping is running"):
        runner.start("wiping")
    progress = stuck.wait(60.0)
    assert progress.state == "failed" and "time limit" in progress.message
    other.wait(60.0)
    runner.close()
    assert not (recordings / ".cleaned" / "wiping.cleaned.hdf5").exists()
    assert not any(p.name.startswith(".bt-staging") for p in (recordings / ".cleaned").glob("*"))


def test_a_clean_job_can_be_cancelled_and_the_task_cleaned_again(recordings) -> None:
    runner = CleanRunner(recordings, CleanOptions(epochs=2, write_rrd=False), processes=True)
    job = runner.start("wiping")
    assert runner.cancel("wiping")
    assert job.wait(30.0).state == "cancelled"
    assert not runner.cancel("wiping")  # nothing left to cancel
    again = runner.start("wiping")
    assert again is not job and runner.job_for("wiping") is again
    runner.close()


def test_a_clean_job_runs_at_a_lower_cpu_priority_than_the_app(recordings) -> None:
    from bt_teleop.proc.priority import CLEAN_NICE

    runner = CleanRunner(recordings, CleanOptions(epochs=100_000, write_rrd=False), processes=True)
    try:
        runner.start("wiping")
        process = psutil.Process(runner._processes["wiping"].pid)
        wait_until(lambda: process.nice() != os.nice(0), 60.0, "the job to lower its priority")
        assert process.nice() == min(os.nice(0) + CLEAN_NICE, 19)
    finally:
        runner.close()


def test_a_non_loopback_host_prints_a_warning(monkeypatch, capsys) -> None:
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.5")
    monkeypatch.setattr(app_module, "TeleopApp", lambda options: options)  # do not bind
    start_app(AppOptions(host="0.0.0.0"))
    assert "WARNING: --host 0.0.0.0 exposes the app" in capsys.readouterr().err
    start_app(AppOptions(host="127.0.0.1"))
    assert "WARNING" not in capsys.readouterr().err


def _start_bt_teleop(tmp_path: Path, *flags: str, **popen: Any) -> tuple[subprocess.Popen, int]:
    """`bt teleop --port 0 <flags>` started and serving; (process, port)."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    command = ["teleop", "--port", "0", "--recordings", str(tmp_path / "rec"), *flags]
    process = subprocess.Popen(
        [sys.executable, "-m", "bt_pipeline", *command],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
        **popen,
    )
    assert process.stdout is not None
    lines = []
    for line in process.stdout:
        lines.append(line)
        if "press Ctrl-C" in line:
            break
    urls = [line.split("open http://")[1] for line in lines if "open http://" in line]
    assert urls, "".join(lines)
    return process, int(urls[0].split()[0].rstrip("/").rsplit(":", 1)[1])


def test_every_socket_of_bt_teleop_listens_on_loopback_only(tmp_path) -> None:
    """All listening sockets of `bt teleop` (defaults, Rerun serving) and its children; and
    when the app is killed with SIGKILL (it cannot stop them), its children die too: Rerun's
    and a tab's session process (bt_teleop/session/process.py)."""
    process, port = _start_bt_teleop(tmp_path)
    tab: FakeTab | None = None
    try:
        tab = FakeTab(port)
        app = psutil.Process(process.pid)
        wait_until(lambda: _session_processes(app), 60.0, "the tab's session process")
        # The reader names itself just after its fork; on a busy machine that can take a while,
        # and until then it looks like a second session.
        wait_until(
            lambda: any(_name(c) == READER_NAME for c in _forked(app)), 60.0, "the named reader"
        )
        time.sleep(1.0)  # let Rerun's servers come up
        sockets = listening(process.pid)
        assert sockets, "bt teleop listens on nothing"
        exposed = [s for s in sockets if not is_loopback_address(s[1])]
        assert not exposed, f"sockets on non-loopback interfaces: {exposed}"
        children = app.children(recursive=True)
        assert any("rerun" in " ".join(_cmdline(c)) for c in children), children
        sessions = _session_processes(app)
        assert len(sessions) == 1, sessions
        process.kill()
        process.wait(30)
        _, alive = psutil.wait_procs(children, timeout=10.0)
        assert not alive, f"children outlived a SIGKILL of bt teleop: {alive}"
    finally:
        if tab is not None:
            tab.close()
        process.terminate()
        process.wait(30)


def test_ctrl_c_of_bt_teleop_ends_every_session_process(tmp_path) -> None:
    """Ctrl-C in a terminal signals the whole process group: the session processes ignore it
    and the app closes them (a take in progress is settled, tests above); none is left."""
    # its own process group, as a terminal's foreground job
    process, port = _start_bt_teleop(tmp_path, "--rerun", "off", start_new_session=True)
    tabs: list[FakeTab] = []
    try:
        app = psutil.Process(process.pid)
        tabs = [FakeTab(port) for _ in range(2)]
        wait_until(lambda: len(_session_processes(app)) == 2, 60.0, "2 session processes")
        wait_until(lambda: len(_forked(app)) == 3, 60.0, "the library's reader process")
        children = app.children(recursive=True)
        os.killpg(process.pid, signal.SIGINT)
        assert process.wait(60) == 0
        _, alive = psutil.wait_procs(children, timeout=10.0)
        assert not alive, f"children outlived Ctrl-C of bt teleop: {alive}"
    finally:
        for tab in tabs:
            tab.close()
        process.kill()
        process.wait(30)


def _session_processes(app: psutil.Process) -> list[psutil.Process]:
    """The app's session processes: the forkserver's children but the library's reader."""
    return [child for child in _forked(app) if _name(child) not in (READER_NAME, None)]


def _forked(app: psutil.Process) -> list[psutil.Process]:
    """Every child of the app's forkserver (sessions and the reader)."""
    return [
        child
        for server in app.children()
        if "multiprocessing.forkserver" in " ".join(_cmdline(server))
        for child in _children(server)
    ]


# A process listed a moment ago may have exited since (a child the forkserver forks briefly):
# psutil then raises NoSuchProcess, which these read as "not there" rather than a failure.
def _name(process: psutil.Process) -> str | None:
    try:
        return process.name()
    except psutil.NoSuchProcess:
        return None


def _cmdline(process: psutil.Process) -> list[str]:
    try:
        return process.cmdline()
    except psutil.NoSuchProcess:
        return []


def _children(process: psutil.Process) -> list[psutil.Process]:
    try:
        return process.children()
    except psutil.NoSuchProcess:
        return []


def _now() -> datetime:
    return datetime.now(UTC)


def test_a_tab_thread_never_sets_viser_message_events_off_their_loop(make_app, tabs) -> None:
    """viser's message buffers set an asyncio.Event from the thread that queues a message,
    which raced the loop (connections.LoopSafeEvent): off the loop the set waits for the
    loop-side set that viser schedules next."""
    import asyncio

    from bt_teleop.ui.connections import LoopSafeEvent

    app = make_app()
    tabs(app)
    wait_until(lambda: len(app.sessions()) == 1, what="the tab's session")
    (ui,) = app.sessions().values()
    for buffer in (
        app.server._websock_server.get_message_buffer(),
        ui.client._websock_connection.get_message_buffer(),
    ):
        assert type(buffer.message_event) is LoopSafeEvent
    loop = asyncio.new_event_loop()
    event = LoopSafeEvent()
    event._bt_loop = loop
    waiter = loop.create_task(event.wait())
    loop.run_until_complete(asyncio.sleep(0))  # the waiter is queued
    event.set()  # off the loop: nothing happens
    assert not event.is_set() and not waiter.done()
    loop.call_soon_threadsafe(event.set)  # what viser schedules next
    loop.run_until_complete(asyncio.wait_for(waiter, 5.0))
    assert event.is_set()
    loop.close()
