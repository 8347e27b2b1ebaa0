"""The soak's control loops (benchmarks/common/soak_control.py): loops that only wake up every
period, beside the sessions, so that a late tick they shared is told apart as the machine's. A pause
of a loop's process must show as its stall, at the right moment, and be matched to the late ticks it
overlapped and to no others."""

from __future__ import annotations

import math
import os
import signal
import time

from benchmarks.common import soak_control, soak_late
from bt_teleop.session.late_ticks import LateTick


def test_a_paused_control_loop_reports_its_stall_and_the_late_ticks_beside_it() -> None:
    loops = soak_control.ControlLoops(2, 0.01, 0.05)
    try:
        time.sleep(0.3)
        paused = loops.pids[0]
        os.kill(paused, signal.SIGSTOP)
        stopped_at = time.time()
        time.sleep(0.3)
        os.kill(paused, signal.SIGCONT)
        time.sleep(0.3)
    except BaseException:
        loops.kill()
        raise
    report = loops.close()
    assert report.ticks > 50
    stall = max(report.stalls, key=lambda s: s.late_s)
    assert stall.loop == 0
    assert 0.25 <= stall.late_s < 1.0
    assert abs((stall.at_s - stall.gap_s) - stopped_at) < 0.1
    # A session tick late over the same 0.3 s is the machine's; one a second later is not.
    assert stall in report.beside(stopped_at + 0.32, 0.3)
    assert report.beside(stopped_at + 1.5, 0.3) == []


def test_late_ticks_are_the_machines_when_the_control_loops_or_steal_time_explain_them() -> None:
    control, late = soak_control, soak_late
    stall = control.ControlStall(loop=0, at_s=100.0, gap_s=0.12, late_s=0.11, runqueue_s=0.0)
    report = control.ControlReport(ticks=1000, largest_late_s=0.11, stalls=(stall,))
    steal = late.StealSampler()
    steal.stop()
    # Steal so far [s], sampled every 50 ms: 60 ms of it between 199.95 and 200.0, none else.
    steal.samples = [(100.0 + 0.05 * k, 0.06 if k >= 2000 else 0.0) for k in range(4000)]

    def tick(at_s: float, late_s: float) -> LateTick:
        return LateTick(at_s, late_s + 0.01, late_s, 0.0, 0.0, 0.0, 0.0, 0.001)

    assert abs(steal.during_gap(200.02, 0.11) - 0.06) < 1e-12
    assert steal.during_gap(150.0, 0.01) == 0.0 and math.isnan(steal.during_gap(100.02, 0.11))
    # The sampler keeps only the samples whose value changed, and the same answers come back.
    kept = late.StealSampler()
    kept.stop()
    kept.samples = []
    for at_s, steal_s in steal.samples:
        kept.record(at_s, steal_s)
    assert kept.samples == [(100.0, 0.0), (200.0, 0.06)] and kept.total() == 0.06
    for at_s in (150.0, 200.02, 250.0):
        assert kept.during_gap(at_s, 0.11) == steal.during_gap(at_s, 0.11)
    kept.samples = kept.samples[:1]  # no steal at all: one sample kept, and none stolen
    assert kept.total() == 0.0
    kept.samples = kept.samples[:0]
    assert math.isnan(kept.total())
    ticks = (tick(100.02, 0.1), tick(200.02, 0.09), tick(300.0, 0.07))
    lines = late.machine_lines(ticks, report, 0.05, steal)
    assert (
        "late ticks the machine explains: 2 of 3 (the control loops were late too: 1;" in (lines[1])
    )
    assert "steal time beside the gap >= half the lateness: 1)" in lines[1]
    assert "late ticks of bt's own (neither): 1, the latest 70.0 ms late" in lines[2]
