"""Control loops for the soak's stalls: processes that only sleep one control period at a time.

A session's control loop can be late for reasons of its own process (its GIL, its requests,
its collections) or of the whole machine (a pause of the virtual machine itself, or load that
delays any loop at that priority). A loop that does nothing but wake up every period, at the
control loops' priority, separates the two: a late tick that such a loop shared at the same
moment was the machine's. The machine's load includes bt's other processes (the app, Clean
jobs), so a shared tick is not by itself proof that bt had no part in it: the steal time and
run-queue wait beside it say which. On this benchmark's VM (2 vCPUs), 8 such loops on an
otherwise idle machine stalled together by up to 67.7 ms in one 10-minute run, and by at most
17.5 ms in the next (``bench_machine_stalls.py``; docs/security.md).

::

    python benchmarks/common/soak_control.py PERIOD_S LATE_S BOOST REALTIME
        # prints "ready"; at end of stdin prints one JSON line: ticks, largest gap, late ticks
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class ControlStall:
    """A control loop's wake-up later than its period plus the threshold (times in s)."""

    loop: int
    """Which control loop."""
    at_s: float
    """Wall clock (``time.time()``) of the late wake-up."""
    gap_s: float
    """Since the wake-up before."""
    late_s: float
    """``gap_s`` minus the period."""
    runqueue_s: float
    """The loop's thread waited this long for a CPU during the gap (schedstat)."""

    def overlaps(self, at_s: float, gap_s: float) -> bool:
        """Whether this gap and the gap ending at `at_s` that lasted `gap_s` overlap."""
        return self.at_s - self.gap_s < at_s and at_s - gap_s < self.at_s


@dataclass(frozen=True)
class ControlReport:
    """What the control loops saw."""

    ticks: int
    largest_late_s: float
    stalls: tuple[ControlStall, ...]

    def beside(self, at_s: float, gap_s: float) -> list[ControlStall]:
        """The control stalls overlapping a gap ending at `at_s` that lasted `gap_s`."""
        return [s for s in self.stalls if s.overlaps(at_s, gap_s)]


class ControlLoops:
    """`n` control loops, each in a process of its own, until :meth:`close`."""

    def __init__(
        self, n: int, period_s: float, late_s: float, boost: int = 0, realtime: int = 0
    ) -> None:
        args = [str(period_s), str(late_s), str(boost), str(realtime)]
        self._children = [
            subprocess.Popen(
                [sys.executable, __file__, *args],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                text=True,
            )
            for _ in range(n)
        ]
        for child in self._children:
            assert child.stdout is not None
            line = child.stdout.readline().strip()
            if line != "ready":
                self.kill()
                raise RuntimeError(f"a control loop did not start: {line!r}")

    @property
    def pids(self) -> list[int]:
        """The loops' process ids."""
        return [child.pid for child in self._children]

    def kill(self) -> None:
        for child in self._children:
            child.kill()

    def close(self) -> ControlReport:
        """Stop the loops; what they saw."""
        ticks, largest, stalls = 0, 0.0, []
        for k, child in enumerate(self._children):
            out, _ = child.communicate(timeout=60.0)
            try:
                row: dict[str, Any] = json.loads(out.strip().splitlines()[-1])
            except (IndexError, json.JSONDecodeError):  # it died: the soak's report still counts
                print(f"control loop {k} ended with no report (exit {child.returncode})")
                continue
            ticks += row["ticks"]
            largest = max(largest, row["largest_late_s"])
            stalls += [ControlStall(k, *s) for s in row["stalls"]]
        return ControlReport(ticks, largest, tuple(sorted(stalls, key=lambda s: s.at_s)))


def _runqueue_s(fd: int) -> float:
    """The thread's run-queue wait so far [s] (schedstat's second field)."""
    return int(os.pread(fd, 128, 0).split()[1]) / 1e9


def run_loop(period_s: float, late_s: float, stop: threading.Event) -> dict[str, Any]:
    """Wake up every `period_s` until `stop`, as ``Session._run`` does with no work per tick;
    the late wake-ups."""
    fd = os.open("/proc/thread-self/schedstat", os.O_RDONLY)
    stalls: list[tuple[float, float, float, float]] = []
    ticks, largest = 0, 0.0
    try:
        last = next_t = time.perf_counter()
        queued = _runqueue_s(fd)
        while not stop.is_set():
            next_t += period_s
            delay = next_t - time.perf_counter()
            if delay > 0.0:
                stop.wait(delay)
            now = time.perf_counter()
            queued_now = _runqueue_s(fd)
            late = now - last - period_s
            largest = max(largest, late)
            if late > late_s:
                stalls.append((time.time(), now - last, late, queued_now - queued))
            if -delay > 0.5:  # as Session's max_lag_s: no burst of catch-up ticks
                next_t = now
            last, queued, ticks = now, queued_now, ticks + 1
    finally:
        os.close(fd)
    return {"ticks": ticks, "largest_late_s": largest, "stalls": stalls}


def main() -> None:
    from bt_teleop.proc.priority import raise_priority, use_realtime

    period_s, late_s = float(sys.argv[1]), float(sys.argv[2])
    boost, realtime = int(sys.argv[3]), int(sys.argv[4])
    stop, result = threading.Event(), dict[str, Any]()

    def loop() -> None:
        raise_priority(boost)
        use_realtime(realtime)
        result.update(run_loop(period_s, late_s, stop))

    thread = threading.Thread(target=loop)
    thread.start()
    print("ready", flush=True)
    sys.stdin.read()  # until the benchmark closes it
    stop.set()
    thread.join()
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
