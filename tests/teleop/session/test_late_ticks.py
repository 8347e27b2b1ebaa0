"""Late control ticks are attributed (bt_teleop/session/late_ticks.py): a gap longer than the period
plus ``SessionConfig.late_tick_s`` keeps what overlapped it (the threads' run-queue wait, the
garbage collections, the command thread's requests, the phases of the tick before), and the
cause named is the one that covers at least half the lateness."""

from __future__ import annotations

import gc
import math
import pickle
import threading
import time
from pathlib import Path

import pytest

from bt_pipeline.exceptions import ConfigError
from bt_teleop.session.config import SessionConfig
from bt_teleop.session.late_ticks import LateProbe, LateTick, cause_counts
from bt_teleop.session.process import SessionProcess
from bt_teleop.session.tick_stats import TickReport, TimedSession
from bt_teleop.sim.scene import SceneModel
from bt_teleop.testing.harness import wait_until


def _late(**kwargs: object) -> LateTick:
    fields: dict[str, object] = dict(
        at_s=0.0,
        gap_s=0.110,
        late_s=0.100,
        runqueue_s=0.0,
        on_cpu_s=0.001,
        peer_runqueue_s=0.0,
        peer_on_cpu_s=0.0,
        tick_s=0.001,
    )
    fields.update(kwargs)
    return LateTick(**fields)  # type: ignore[arg-type]


def test_the_cause_is_what_covers_half_the_lateness_cpu_first() -> None:
    assert _late(runqueue_s=0.050).cause == "cpu"
    assert _late(runqueue_s=0.049).cause == "unattributed"
    # starved of CPU while a collection ran: the run queue explains it
    assert _late(runqueue_s=0.080, collections=((2, 0.090),)).cause == "cpu"
    assert _late(collections=((0, 0.001), (2, 0.060))).cause == "gc2"
    assert _late(phases=(("ik", 0.001), ("sample", 0.070))).cause == "tick:sample"
    assert _late(requests=(("status", 0.001), ("stop_and_check", 0.09))).cause == (
        "request:stop_and_check"
    )
    assert _late(peer_runqueue_s=0.07).cause == "peer-cpu"  # blocked while the GIL holder waited
    assert _late(peer_runqueue_s=0.07, on_cpu_s=0.08).cause == "unattributed"  # not blocked
    # the command thread, preempted, held up a save: starvation, not the save
    assert _late(peer_runqueue_s=0.09, requests=(("stop_and_check", 0.1),)).cause == "peer-cpu"
    assert _late(requests=(("stop_and_check", 0.1),), phases=(("physics", 0.1),)).cause == (
        "request:stop_and_check"
    )
    assert _late(runqueue_s=math.nan).cause == "unattributed"  # no schedstat: not "cpu"
    counts = cause_counts([_late(runqueue_s=0.06), _late(), _late(runqueue_s=0.07)])
    assert counts == {"cpu": 2, "unattributed": 1}
    assert list(counts) == ["cpu", "unattributed"]  # most first


def test_a_gap_keeps_the_requests_and_collections_that_overlapped_it() -> None:
    probe = LateProbe(period_s=0.01, late_after_s=0.05)
    probe.loop_started()  # this thread is the "control thread"
    probe.tick_started(time.perf_counter(), 0.001)
    probe.tick_started(time.perf_counter(), 0.001)  # on time: nothing kept
    assert probe.kept() == ()
    with probe.serving("stop_and_check"):
        gc.collect()
        time.sleep(0.08)
    probe.phase("ik", 0.002)
    probe.tick_ended(0.003)
    probe.tick_started(time.perf_counter(), 0.003)
    (late,) = probe.kept()
    assert late.gap_s >= 0.08 and late.late_s == pytest.approx(late.gap_s - 0.01)
    names = dict(late.requests)
    assert names["stop_and_check"] >= 0.08
    assert 2 in dict(late.collections)
    assert dict(late.phases) == pytest.approx({"ik": 0.002, "physics": 0.001})
    assert late.on_cpu_s >= 0.0 and late.runqueue_s >= 0.0  # schedstat read (Linux)
    assert math.isnan(late.peer_runqueue_s)  # no command thread watched
    assert pickle.loads(pickle.dumps(late)).requests == late.requests  # crosses the pipe


def test_a_disabled_probe_keeps_nothing() -> None:
    probe = LateProbe(period_s=0.01, late_after_s=math.inf)
    probe.loop_started()
    probe.tick_started(0.0, 0.0)
    probe.tick_started(10.0, 0.0)
    assert probe.kept() == () and not probe.enabled


def test_a_loop_blocked_inside_its_tick_is_attributed_to_that_phase(
    scene: SceneModel, tmp_path: Path
) -> None:
    session = TimedSession(scene, tmp_path, config=SessionConfig(late_tick_s=0.05))
    try:
        session.start()
        wait_until(lambda: session.tick_stats().n_ticks > 10, 30.0, "ticks")
        with session._state_lock:  # a tick waits for the state lock (its physics phase)
            time.sleep(0.3)
        # the gap is kept when the tick after the blocked one starts (other late ticks, from
        # CPU starvation on a loaded machine, may come before or after it)
        wait_until(lambda: _blocked(session.tick_stats().late), 30.0, "the blocked tick")
    finally:
        session.close()
    report = session.tick_stats()
    blocked = _blocked(report.late)
    assert blocked is not None
    assert blocked.gap_s >= 0.2  # the lock was held 0.3 s, from some time in a period
    assert dict(blocked.phases)["physics"] >= 0.2
    assert blocked.tick_s >= 0.2
    if blocked.runqueue_s < 0.5 * blocked.late_s:  # not starved of CPU meanwhile
        assert blocked.cause == "tick:physics"
    merged = TickReport.merged([report, report])
    assert len(merged.late) == 2 * len(report.late)


def _blocked(late: tuple[LateTick, ...]) -> LateTick | None:
    """The late tick whose tick before spent longest in its physics phase (≥ 0.2 s)."""
    found = [t for t in late if dict(t.phases).get("physics", 0.0) >= 0.2]
    return max(found, key=lambda t: dict(t.phases)["physics"], default=None)


def test_a_session_process_reads_both_its_threads(scene: SceneModel, tmp_path: Path) -> None:
    # Every tick later than 1 µs is kept: the sleep between ticks overshoots by more.
    config = SessionConfig(late_tick_s=1e-6)
    with SessionProcess(scene, tmp_path, config=config) as proxy:
        proxy.start()
        wait_until(lambda: len(proxy.tick_stats().late) > 20, 30.0, "late ticks")
        late = proxy.tick_stats().late
    for tick in late:
        assert tick.runqueue_s >= 0.0 and tick.on_cpu_s > 0.0  # the control thread
        assert tick.peer_runqueue_s >= 0.0 and tick.peer_on_cpu_s >= 0.0  # the command one
    assert any(name == "tick_stats" for tick in late for name, _ in tick.requests)


@pytest.mark.parametrize("value", [0.0, -1.0, math.nan, True, "0.05"])
def test_a_late_tick_threshold_must_be_positive(value: object) -> None:
    with pytest.raises(ConfigError, match="late_tick_s"):
        SessionConfig(late_tick_s=value)  # type: ignore[arg-type]


def test_the_gc_log_copies_while_another_thread_collects() -> None:
    probe = LateProbe(period_s=0.01, late_after_s=0.0001)
    stop = threading.Event()

    def collect() -> None:
        while not stop.is_set():
            gc.collect(0)

    thread = threading.Thread(target=collect)
    thread.start()
    try:
        for _ in range(200):
            assert probe._gc is not None
            probe._gc.overlapping(0.0, time.perf_counter())  # never "deque mutated"
    finally:
        stop.set()
        thread.join()
