"""A tab's session in a child process (bt_teleop/session/process.py): it moves the arm, records
and saves takes that read back, re-raises the child's errors, survives nothing it should not
(a killed child is one clear message, never a hang) and leaves no child behind; and
the tick timing every session keeps (bt_teleop/session/tick_stats.py)."""

from __future__ import annotations

import logging
import os
import pickle
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import psutil
import pytest

from bt_pipeline.data.recording import read_recording
from bt_pipeline.exceptions import BtError, ConfigError, SessionLostError
from bt_teleop.proc.child import portable_error
from bt_teleop.proc.native_memory import HeapInfo, heap_info
from bt_teleop.proc.priority import command_priority
from bt_teleop.session.config import SessionConfig
from bt_teleop.session.process import SessionProcess, open_session
from bt_teleop.session.tick_stats import BIN_S, Histogram, TickReport, TimedSession
from bt_teleop.sim.scene import SceneModel
from bt_teleop.testing.harness import circle_uv, wait_until


@pytest.fixture
def session(scene: SceneModel, tmp_path: Path):
    with SessionProcess(scene, tmp_path, session_id="proc1") as proxy:
        yield proxy


def _near(proxy: SessionProcess, goal: np.ndarray, tol_m: float = 5e-3) -> bool:
    return bool(np.linalg.norm(proxy.status().ee_pos - goal) < tol_m)


def test_the_child_is_another_process_and_its_arm_follows_the_target(
    session: SessionProcess, scene: SceneModel
) -> None:
    assert session.pid is not None and session.pid != os.getpid()
    assert psutil.Process(session.pid).is_running()
    assert session.dt_s == pytest.approx(1.0 / session.config.control_hz)
    start = session.status()
    assert not start.running and start.sim_time_s == 0.0  # not started yet
    session.start()
    goal = scene.plane.to_world(np.array([0.06, 0.04]))
    assert np.linalg.norm(start.ee_pos - goal) > 0.05
    session.set_target(goal)
    wait_until(lambda: _near(session, goal), 30.0, "the arm to reach the target")
    status = session.status()
    assert status.running and status.sim_time_s > 0.0 and status.ik_ok


def test_a_take_recorded_in_the_child_is_saved_and_reads_back(
    session: SessionProcess, scene: SceneModel, tmp_path: Path
) -> None:
    session.start()
    session.start_recording("Zoë <b>", 10.0, 1.2)
    assert session.recording
    t0 = time.perf_counter()
    while session.status().duration_s < 2.0:
        session.set_target(scene.plane.to_world(circle_uv(time.perf_counter() - t0)))
        time.sleep(0.02)
    trail = session.trail()
    assert trail.ndim == 2 and trail.shape[1] == 3 and len(trail) >= 50
    take = session.stop_and_check()
    assert not session.recording
    assert take.path.parent == tmp_path / "wiping" and take.path.exists()
    recording = read_recording(take.path)
    (demo,) = recording.demos.values()
    assert demo.demonstrator == "Zoë <b>" and demo.rho == pytest.approx(1.2)
    assert demo.num_samples >= len(trail)  # the trail was read before the last samples
    np.testing.assert_allclose(demo.ee_pos[: len(trail)], trail)


def test_the_child_reports_its_own_c_heap(session: SessionProcess) -> None:
    """heap_info is the child's (MuJoCo's model and data live there), not this process's."""
    here, child = heap_info(), session.process_info("heap_info")
    if here is None:
        pytest.skip("needs glibc's mallinfo2")
    assert isinstance(child, HeapInfo) and child.in_use > 0
    assert child != heap_info()


@pytest.mark.parametrize("release", [True, False])
def test_a_child_gives_back_what_hdf5_kept_of_each_take(
    scene: SceneModel, tmp_path: Path, release: bool
) -> None:
    """HDF5 keeps the blocks a save freed on free lists of its own, one per size (to malloc
    they stay in use), so every take of a new length left more in the child. After takes of
    three lengths a child holds none once its last take is saved (it releases them after each
    take), and, told not to (``release_memory_after_take=False``: the code before), some."""
    config = SessionConfig(release_memory_after_take=release)
    with SessionProcess(scene, tmp_path, config=config) as child:
        if child.process_info("hdf5_free_lists") is None:
            pytest.skip("needs HDF5 >= 1.10.7 (H5get_free_list_sizes)")
        child.start()
        for n_samples in (20, 40, 60):
            child.start_recording("a")
            wait_until(lambda n=n_samples: child.status().n_samples >= n, 30.0, "the samples")
            child.stop_and_check()
        lists = child.process_info("hdf5_free_lists")
    assert lists is not None
    if release:
        assert lists.block == 0 and lists.array == 0
    else:
        assert lists.block > 0


def test_errors_of_the_child_are_raised_here_with_their_class_and_message(
    session: SessionProcess,
) -> None:
    with pytest.raises(ConfigError, match="nothing to save"):
        session.stop_and_check()
    session.start_recording("a")
    with pytest.raises(ConfigError, match="already in progress"):
        session.start_recording("b")
    with pytest.raises(ConfigError, match="theta_deg must be finite"):
        session.start_recording("c", theta_deg=float("inf"))
    for target in ([1e30, 0.0, 0.0], [np.nan, 0.0, 0.0], [0.0, 0.0]):
        with pytest.raises(ConfigError):
            session.set_target(target)  # refused here, before it is sent
    assert session.discard() and not session.discard()
    assert session.lost is None  # errors are answers, not a lost child


def test_an_error_that_cannot_be_pickled_comes_back_as_a_bt_error_with_its_text() -> None:
    class Local(Exception):  # a local class cannot be pickled
        pass

    portable = portable_error(Local("boom"))
    assert isinstance(portable, BtError) and "Local: boom" in str(portable)
    bug = portable_error(KeyError("x"))
    assert isinstance(pickle.loads(pickle.dumps(bug)), KeyError)
    assert "in the session process" in "".join(bug.__notes__)


def test_a_killed_child_is_one_clear_message_not_a_hang(session: SessionProcess) -> None:
    session.start()
    session.status()
    assert session.pid is not None
    os.kill(session.pid, signal.SIGKILL)
    status = session.status()  # the last status, with the reason
    assert not status.running
    assert status.warning is not None and "stopped" in status.warning
    assert "exit code -9" in status.warning and session.lost == status.warning
    with pytest.raises(SessionLostError, match="session proc1 stopped"):
        session.start_recording("a")
    session.set_target([0.4, 0.0, 0.3])  # dropped, not raised: the status says why
    assert session.trail().shape == (0, 3) and not session.recording
    assert session.close() is None


def _recording_child(session: SessionProcess, name: str) -> psutil.Process:
    """Start `session` recording a take by `name` (40 samples in); its child process."""
    session.start()
    session.start_recording(name)
    wait_until(lambda: session.status().n_samples >= 40, 30.0, "samples")
    assert session.pid is not None
    return psutil.Process(session.pid)


def test_closing_mid_take_saves_it_flagged_incomplete_and_ends_the_child(
    session: SessionProcess,
) -> None:
    child = _recording_child(session, "closer")
    path = session.close()
    assert path is not None
    (demo,) = read_recording(path).demos.values()
    assert "closed_mid_take" in demo.flags
    assert not child.is_running() or child.status() == psutil.STATUS_ZOMBIE
    with pytest.raises(ConfigError, match="closed"):
        session.start_recording("again")
    assert not session.recording and session.trail().shape == (0, 3)  # as a closed Session


def test_a_child_whose_app_vanished_saves_its_take_and_exits(
    session: SessionProcess, tmp_path: Path
) -> None:
    """EOF on the pipe (the app was killed): the child settles the take as a closed tab's."""
    child = _recording_child(session, "orphan")
    session._pipe.conn.close()  # what the app's death does to the child's pipe
    child.wait(30.0)
    (path,) = (tmp_path / "wiping").glob("*.hdf5")
    (demo,) = read_recording(path).demos.values()
    assert demo.demonstrator == "orphan" and "closed_mid_take" in demo.flags


def test_the_child_ignores_ctrl_c_the_app_closes_it(session: SessionProcess) -> None:
    assert session.pid is not None
    os.kill(session.pid, signal.SIGINT)  # Ctrl-C reaches the terminal's whole process group
    session.start()
    assert session.status().running and session.lost is None


def test_the_child_counts_its_ticks_and_their_gaps(session: SessionProcess) -> None:
    session.start()
    wait_until(lambda: session.tick_stats().n_ticks >= 100, 30.0, "100 ticks")
    report = session.tick_stats()
    period = session.dt_s
    assert report.period_s == pytest.approx(period)
    # paced to real time: the median gap is the period (to a bin and the scheduler)
    assert report.gap_percentile(50) == pytest.approx(period, abs=2e-3)
    assert report.max_gap_s >= report.gap_percentile(99) >= report.gap_percentile(50)
    assert report.largest_stall_s == pytest.approx(max(0.0, report.max_gap_s - period))
    assert 0.0 < report.compute_percentile(50) < period  # a tick costs less than its period


def test_in_process_sessions_are_timed_the_same_way(scene: SceneModel, tmp_path: Path) -> None:
    config = SessionConfig()
    local = open_session(scene, tmp_path, config=config, session_id="x", in_process=True)
    assert isinstance(local, TimedSession)
    local.step(50)
    report = local.tick_stats()
    assert report.n_ticks == 49  # gaps between 50 ticks
    local.close()


def test_tick_reports_merge_and_give_percentiles_of_their_bins() -> None:
    a, b = Histogram(), Histogram()
    for seconds in (0.010, 0.010, 0.011):
        a.add(seconds)
    b.add(0.250)
    b.add(-1.0)  # clock oddities land in the first bin, never crash
    ra = TickReport(0.01, a.counts, a.max_s, a.counts.copy(), 0.0)
    rb = TickReport(0.01, b.counts, b.max_s, b.counts.copy(), 0.0)
    merged = TickReport.merged([ra, rb])
    assert merged.n_ticks == 5 and merged.max_gap_s == 0.250
    assert merged.largest_stall_s == pytest.approx(0.240)
    assert merged.gap_percentile(50) == pytest.approx(0.010 + BIN_S / 2)
    assert merged.gap_percentile(100) == pytest.approx(0.250)
    assert merged.gaps_above(0.05) == 1
    assert ra.largest_stall_s == pytest.approx(0.001)


def _permitted_in_a_thread(action: Callable[[], object]) -> bool:
    """Whether `action` (a scheduling change of the calling thread) is permitted here: tried in
    a thread of its own, which then ends, so this process's threads keep their policy."""
    result: list[bool] = []

    def probe() -> None:
        try:
            action()
        except OSError:  # PermissionError included
            result.append(False)
        else:
            result.append(True)

    thread = threading.Thread(target=probe)
    thread.start()
    thread.join()
    return result[0]


def _may_raise_priority() -> bool:
    """Whether this process may lower a thread's nice value (root, CAP_SYS_NICE, ulimit -e)."""

    def lower_nice() -> None:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) - 1)

    return _permitted_in_a_thread(lower_nice)


def test_the_control_loop_raises_its_priority_when_permitted(
    scene: SceneModel, tmp_path: Path
) -> None:
    base = os.getpriority(os.PRIO_PROCESS, 0)
    for boost in (0, 3):
        config = SessionConfig(priority_boost=boost)
        with SessionProcess(scene, tmp_path, config=config) as proxy:
            assert proxy.tick_stats().nice is None  # not started
            proxy.start()
            wait_until(lambda p=proxy: p.tick_stats().n_ticks > 10, 30.0, "ticks")
            nice = proxy.tick_stats().nice
        raised = boost > 0 and _may_raise_priority()
        assert nice == (max(-20, base - boost) if raised else base)


@pytest.mark.parametrize("boost", [-1, 21, 2.5, True])
def test_a_priority_boost_out_of_range_is_refused(boost) -> None:
    with pytest.raises(ConfigError, match="priority_boost"):
        SessionConfig(priority_boost=boost)


def _may_use_realtime() -> bool:
    """Whether this process may put a thread under SCHED_RR (root, CAP_SYS_NICE, ulimit -r)."""
    return _permitted_in_a_thread(lambda: os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(1)))


def test_the_child_s_threads_run_real_time_when_asked_and_permitted(
    scene: SceneModel, tmp_path: Path
) -> None:
    for priority in (0, 7):
        config = SessionConfig(realtime_priority=priority)
        with SessionProcess(scene, tmp_path, config=config) as proxy:
            proxy.start()
            wait_until(lambda p=proxy: p.tick_stats().n_ticks > 10, 30.0, "ticks")
            realtime = proxy.tick_stats().realtime
            assert proxy.pid is not None
            tids = [t.id for t in psutil.Process(proxy.pid).threads()]
            policies = {os.sched_getscheduler(tid) for tid in tids}
            levels = sorted(os.sched_getparam(tid).sched_priority for tid in tids)
        expected = priority > 0 and _may_use_realtime()
        assert realtime is expected
        # the loop and the command thread that shares its GIL: both, or neither
        assert policies == ({os.SCHED_RR} if expected else {os.SCHED_OTHER})
        # the loop alone at the priority asked; the thread serving it one step below, so a
        # take's save never queues another session's loop (proc/priority.py command_priority)
        n = len(tids)
        assert levels == ([priority - 1] * (n - 1) + [priority] if expected else [0] * n)
    assert os.sched_getscheduler(0) == os.SCHED_OTHER  # the app's own threads are untouched


@pytest.mark.parametrize("priority", [-1, 100, 1.5, True])
def test_a_realtime_priority_out_of_range_is_refused(priority) -> None:
    with pytest.raises(ConfigError, match="realtime_priority"):
        SessionConfig(realtime_priority=priority)


def test_the_thread_serving_a_loop_runs_one_real_time_step_below_it() -> None:
    assert [command_priority(p) for p in (0, 1, 2, 10, 99)] == [0, 1, 1, 9, 98]


def test_a_loop_not_permitted_real_time_keeps_the_normal_policy_and_says_how(
    monkeypatch, caplog
) -> None:
    import bt_teleop.proc.priority as priority

    def refuse(*args: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    result: list[bool] = []
    monkeypatch.setattr(priority.os, "sched_setscheduler", refuse)
    with caplog.at_level(logging.INFO, logger=priority.LOGGER.name):
        thread = threading.Thread(target=lambda: result.append(priority.use_realtime(10)))
        thread.start()
        thread.join()
    assert result == [False]  # the default priority, refused: the loop runs on, not real-time
    assert "ulimit -r" in caplog.text and "--realtime-priority 0" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.INFO, logger=priority.LOGGER.name):
        assert priority.use_realtime(9, quiet=True) is False  # the command thread's call
    assert caplog.text == ""  # one line per child: its loop's
