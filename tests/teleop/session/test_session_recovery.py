"""A session child that is slow is not lost, and a lost one is replaced
(bt_teleop/session/process.py, pipe.py, recovery.py; bt_teleop/ui/takes.py).

A child stopped (SIGSTOP) longer than the quick-call timeout stays, its late replies are never
taken for another call's, and commands sent meanwhile never block; a child that died or
answered nothing for ``unresponsive_s`` is replaced by a new one with the same settings, in a
tab at once, and its take in progress is saved flagged incomplete or reported lost.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

from bt_pipeline.data.recording import read_recording
from bt_pipeline.exceptions import ConfigError, SessionLostError
from bt_teleop.session.config import SessionStatus
from bt_teleop.session.pipe import BUSY_WARNING
from bt_teleop.session.process import SessionProcess
from bt_teleop.session.tick_stats import TickReport
from bt_teleop.sim.scene import SceneModel
from bt_teleop.testing.harness import circle_uv, wait_until
from bt_teleop.ui.tab import ClientUI


def _near(proxy: SessionProcess, goal: np.ndarray, tol_m: float = 5e-3) -> bool:
    return bool(np.linalg.norm(proxy.status().ee_pos - goal) < tol_m)


def _record(proxy: SessionProcess, scene: SceneModel, name: str, samples: int = 40) -> None:
    proxy.start_recording(name)
    t0 = time.perf_counter()
    while proxy.status().n_samples < samples:
        proxy.set_target(scene.plane.to_world(circle_uv(time.perf_counter() - t0)))
        time.sleep(0.02)


def test_a_child_stopped_longer_than_the_timeout_is_slow_not_lost(
    scene: SceneModel, tmp_path: Path
) -> None:
    with SessionProcess(scene, tmp_path, session_id="slow", timeout_s=0.3) as proxy:
        proxy.start()
        assert proxy.status().running and proxy.pid is not None
        goals = [scene.plane.to_world(np.array([0.06, 0.04 - 1e-5 * k])) for k in range(3000)]
        os.kill(proxy.pid, signal.SIGSTOP)
        try:
            busy = [proxy.status() for _ in range(3)]  # each gives up after 0.3 s
            assert not proxy.recording  # the last answer known
            assert proxy.trail().shape == (0, 3)
            # 3000 targets overflow the pipe of a child that does not read: never block
            sender = threading.Thread(target=lambda: [proxy.set_target(g) for g in goals])
            sender.start()
            sender.join(120.0)
            assert not sender.is_alive()
            assert all(s.warning == BUSY_WARNING and s.running for s in busy)
            assert proxy.lost is None
            assert psutil.Process(proxy.pid).status() == psutil.STATUS_STOPPED
        finally:
            os.kill(proxy.pid, signal.SIGCONT)
        # 5 late replies (3 status, recording, trail) are in the pipe: each is dropped, none is
        # taken as the answer to these calls
        assert isinstance(proxy.tick_stats(), TickReport)
        assert proxy.discard() is False
        status = proxy.status()
        assert isinstance(status, SessionStatus) and status.running and status.warning is None
        wait_until(lambda: _near(proxy, goals[-1]), 30.0, "the last target sent while stopped")
        assert proxy.lost is None and proxy.recoveries == []


def test_a_child_that_answers_nothing_for_unresponsive_s_is_lost_and_its_take_saved(
    scene: SceneModel, tmp_path: Path
) -> None:
    proxy = SessionProcess(scene, tmp_path, session_id="stuck", timeout_s=0.3, unresponsive_s=2)
    try:
        proxy.start()
        _record(proxy, scene, "Stuck Sam")
        old_pid = proxy.pid
        assert old_pid is not None
        os.kill(old_pid, signal.SIGSTOP)
        wait_until(lambda: proxy.status().warning != BUSY_WARNING, 60.0, "the child to be lost")
        assert proxy.lost is not None and "answered nothing for 2 s" in proxy.lost
        recovery = proxy.recover()  # it was told to end: it saves the take, then exits
        assert not psutil.pid_exists(old_pid) or psutil.Process(old_pid).status() == "zombie"
        assert recovery.take_by == "Stuck Sam" and not recovery.take_lost
        (path,) = recovery.saved
        (demo,) = read_recording(path).demos.values()
        assert demo.demonstrator == "Stuck Sam" and "closed_mid_take" in demo.flags
        assert demo.ep_meta["session"] == "stuck"
        title, body = recovery.notice()
        assert title == "Simulation restarted" and path.name in body
        assert proxy.lost is None and proxy.pid != old_pid and proxy.status().running
    finally:
        proxy.close()


def test_a_killed_child_is_replaced_and_the_session_keeps_working(
    scene: SceneModel, tmp_path: Path
) -> None:
    with SessionProcess(scene, tmp_path, session_id="phoenix") as proxy:
        proxy.start()
        old_pid = proxy.pid
        assert old_pid is not None
        os.kill(old_pid, signal.SIGKILL)
        assert not proxy.status().running
        assert proxy.lost is not None and "exit code -9" in proxy.lost
        goal = scene.plane.to_world(np.array([-0.05, 0.03]))
        proxy.set_target(goal)  # kept for the new child
        recovery = proxy.recover()
        assert "exit code -9" in recovery.reason and recovery.take_by is None
        assert not recovery.take_lost and recovery.saved == ()
        assert proxy.lost is None and proxy.pid not in (None, old_pid)
        assert proxy.recoveries == [recovery]
        wait_until(lambda: _near(proxy, goal), 30.0, "the new child's arm at the target")
        assert proxy.status().running  # running again, as it was
        _record(proxy, scene, "After")
        take = proxy.stop_and_check()
        (demo,) = read_recording(take.path).demos.values()
        assert demo.demonstrator == "After" and demo.ep_meta["session"] == "phoenix"


def test_a_take_in_progress_when_the_child_is_killed_is_reported_lost(
    scene: SceneModel, tmp_path: Path
) -> None:
    with SessionProcess(scene, tmp_path, session_id="ouch") as proxy:
        proxy.start()
        _record(proxy, scene, "Ada")
        assert proxy.pid is not None
        os.kill(proxy.pid, signal.SIGKILL)
        proxy.status()
        recovery = proxy.recover()
        assert recovery.take_lost and recovery.take_by == "Ada" and recovery.saved == ()
        assert recovery.take_duration_s > 0.0
        title, body = recovery.notice()
        assert "lost" in title.lower() and "Ada" in body and "was lost" in body
        assert not list(tmp_path.rglob("*.hdf5")) and not proxy.recording


def test_a_tab_whose_simulation_is_killed_gets_a_new_one_and_a_notice(make_app, tabs) -> None:
    app = make_app()
    tabs(app)
    (ui,) = app.wait_for_sessions(1).values()
    assert isinstance(ui, ClientUI) and isinstance(ui.session, SessionProcess)
    ui.controls.name_input.value = "Grace"
    ui.controls.record_button.value = True  # what a click does
    assert ui.wait_idle()
    wait_until(lambda: ui.session.status().n_samples >= 40, what="samples")
    old_pid = ui.session.pid
    assert old_pid is not None
    os.kill(old_pid, signal.SIGKILL)
    wait_until(lambda: any("lost" in t.lower() for t, _ in ui.messages), 60.0, "the notice")
    (body,) = [b for t, b in ui.messages if "lost" in t.lower()]
    assert "Grace" in body and "record it again" in body
    session = ui.session
    assert isinstance(session, SessionProcess) and session.pid != old_pid
    assert session.lost is None and not session.recording
    goal = session.scene.plane.to_world(np.array([0.05, -0.03]))
    session.set_target(goal)
    wait_until(lambda: _near(session, goal), 30.0, "the new arm to move")
    ui.controls.record_button.value = True
    assert ui.wait_idle()
    wait_until(lambda: session.status().duration_s >= 1.0, what="recording")
    ui.controls.save_button.value = True
    assert ui.wait_idle()
    (demo,) = read_recording(ui.saved[-1]).demos.values()
    assert demo.demonstrator == "Grace"


def test_when_no_new_child_starts_the_session_stays_lost_and_says_reload(
    scene: SceneModel, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    with SessionProcess(scene, tmp_path, session_id="dead") as proxy:
        proxy.start()
        _record(proxy, scene, "Bo")
        assert proxy.pid is not None
        os.kill(proxy.pid, signal.SIGKILL)
        proxy.status()

        def no_child(self: SessionProcess) -> None:
            raise ConfigError("no forkserver")

        monkeypatch.setattr(SessionProcess, "_spawn", no_child)
        with pytest.raises(SessionLostError, match="reload the page") as caught:
            proxy.recover()
        assert "no forkserver" in str(caught.value) and "(by Bo," in str(caught.value)
        assert not proxy.can_recover and proxy.lost == str(caught.value)
        assert proxy.status().warning == proxy.lost and not proxy.recording
