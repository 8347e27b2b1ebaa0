"""What the late-tick probe costs a control tick (bt_teleop/session/late_ticks.py).

Every session attributes its late ticks by default (``SessionConfig.late_tick_s`` = 50 ms): per
tick it reads the control thread's and the command thread's schedstat files and times the
tick's IK and recording-sample phases. Measured in this process:

* the probe's bookkeeping alone (``tick_started``, two phases, ``tick_ended``; no late ticks):
  mean over ``--ticks`` calls;
* a whole tick, stepped as fast as possible (``TimedSession.step``), with the probe on
  (both schedstat files open, as in a session child) against off (``late_tick_s = inf``):
  ``--runs`` alternating runs of ``--ticks`` ticks each, the medians and their ratio, with the
  1-minute load average (other jobs share the CPU: compare the ratio, not the times).

    .venv/bin/python benchmarks/teleop/bench_late_probe.py
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import tempfile
import time

from bt_teleop.session.config import SessionConfig
from bt_teleop.session.late_ticks import LateProbe
from bt_teleop.session.tick_stats import TimedSession
from bt_teleop.sim.scene import load_scene


def bookkeeping_s(n: int) -> float:
    """Mean time [s] of the probe's per-tick calls (no tick late)."""
    probe = LateProbe(0.01, 0.05)
    probe.loop_started()
    probe.watch_peer()
    start = time.perf_counter()
    for i in range(n):
        probe.tick_started(i * 0.01, 0.001)
        probe.phase("ik", 0.0005)
        probe.phase("sample", 0.0)
        probe.tick_ended(0.001)
    return (time.perf_counter() - start) / n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--ticks", type=int, default=1000)
    parser.add_argument("--runs", type=int, default=10)
    args = parser.parse_args()
    print(f"probe bookkeeping: {1e6 * bookkeeping_s(100 * args.ticks):.1f} µs per tick")
    scene = load_scene("wiping")
    with tempfile.TemporaryDirectory() as tmp:
        on = TimedSession(scene, tmp, config=SessionConfig(late_tick_s=0.05))
        off = TimedSession(scene, tmp, config=SessionConfig(late_tick_s=math.inf))
        on.late_probe.loop_started()  # as the control thread of a child does
        on.late_probe.watch_peer()  # and its command thread
        times: dict[str, list[float]] = {"on": [], "off": []}
        for run in range(args.runs):
            order = (("on", on), ("off", off)) if run % 2 else (("off", off), ("on", on))
            for name, session in order:
                start = time.perf_counter()
                session.step(args.ticks)
                times[name].append((time.perf_counter() - start) / args.ticks)
        on.close()
        off.close()
    median = {name: statistics.median(values) for name, values in times.items()}
    print(
        f"a whole tick, median of {args.runs} runs of {args.ticks}: probe on "
        f"{1e6 * median['on']:.1f} µs, off {1e6 * median['off']:.1f} µs, ratio "
        f"{median['on'] / median['off']:.3f}; load average (1 min) {os.getloadavg()[0]:.1f}"
    )


if __name__ == "__main__":
    main()
