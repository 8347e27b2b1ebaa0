"""The late control ticks of a soak run, attributed (bench_soak.py;
bt_teleop/session/late_ticks.py).

Each session keeps, for every tick later than ``SessionConfig.late_tick_s`` (``--late-ms``),
what overlapped its gap in its own process: the control thread's run-queue wait and CPU time,
the command thread's, the garbage collections, the requests served and the phases of the tick
before. This module adds what happened meanwhile in the app's process (its heap trims, Clean
presses) by wall clock, counts the causes and prints the latest ticks in full.
"""

from __future__ import annotations

import bisect
import collections
import dataclasses
import json
import math
import os
import threading
import time
from pathlib import Path
from typing import Any

from benchmarks.common.soak_control import ControlReport
from bt_teleop.session.late_ticks import LateTick, cause_counts

AIM_S = 0.05
"""Issue 10's aim: no tick later than this beyond the period [s]."""


class AppEvents:
    """Wall-clock intervals of the app process's events a late tick may line up with."""

    def __init__(self) -> None:
        self.events: list[tuple[str, float, float]] = []

    def wrap(self, name: str, function: Any) -> Any:
        """`function`, its calls recorded as events `name`."""

        def recorded(*args: Any, **kwargs: Any) -> Any:
            start = time.time()
            try:
                return function(*args, **kwargs)
            finally:
                self.events.append((name, start, time.time()))

        return recorded

    def mark(self, name: str) -> None:
        """An instant event now."""
        now = time.time()
        self.events.append((name, now, now))

    def during(self, tick: LateTick, slack_s: float = 0.0) -> list[str]:
        """The events overlapping `tick`'s gap (widened by `slack_s` each side)."""
        t0, t1 = tick.at_s - tick.gap_s - slack_s, tick.at_s + slack_s
        return sorted({name for name, a, b in self.events if a <= t1 and b >= t0})


class StealSampler:
    """The machine's steal time (``/proc/stat``: time the hypervisor ran something else while
    this VM's vCPUs were runnable), summed over the CPUs, every `every_s` seconds in a thread:
    a pause of the whole VM shows up as steal beside a late tick.

    Only the samples whose value changed are kept (and the first): the sampler runs in the
    app's process, whose memory the soak measures, and 20 tuples a second were ~0.08 MiB/min
    of it (docs/security.md, "What the app still holds: traced")."""

    def __init__(self, every_s: float = 0.05) -> None:
        self.samples: list[tuple[float, float]] = []  # (wall time, steal so far [s]): changes
        self._stop = threading.Event()
        self._hz = os.sysconf("SC_CLK_TCK")
        self._thread = threading.Thread(target=self._run, args=(every_s,), daemon=True)
        self._thread.start()

    def _read(self) -> float:
        with open("/proc/stat", encoding="ascii") as stat:
            fields = stat.readline().split()
        return int(fields[8]) / self._hz if len(fields) > 8 else math.nan

    def _run(self, every_s: float) -> None:
        while not self._stop.wait(every_s):
            self.record(time.time(), self._read())

    def record(self, at_s: float, steal_s: float) -> None:
        """Keep the sample (`at_s` wall time, `steal_s` steal so far) if the value changed."""
        if not self.samples or self.samples[-1][1] != steal_s:
            self.samples.append((at_s, steal_s))

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()

    def during(self, tick: LateTick, slack_s: float = 0.1) -> float:
        """Steal [s of CPU] between the samples around `tick`'s gap (widened by `slack_s`)."""
        return self.during_gap(tick.at_s, tick.gap_s, slack_s)

    def during_gap(self, at_s: float, gap_s: float, slack_s: float = 0.1) -> float:
        """Steal [s of CPU] between the samples around the gap of `gap_s` ending at `at_s`."""
        t0, t1 = at_s - gap_s - slack_s, at_s + slack_s
        return self._at(t1) - self._at(t0)

    def _at(self, t: float) -> float:
        """Steal so far at wall time `t`: the last kept sample at or before it (NaN before
        the first)."""
        k = bisect.bisect_right(self.samples, t, key=lambda sample: sample[0])
        return self.samples[k - 1][1] if k > 0 else math.nan

    def total(self) -> float:
        """Steal over the sampling [s of CPU]."""
        return self.samples[-1][1] - self.samples[0][1] if self.samples else math.nan


def report(
    late: tuple[LateTick, ...],
    events: AppEvents,
    threshold_s: float,
    shown: int,
    steal: StealSampler | None = None,
    control: ControlReport | None = None,
) -> str:
    """Counts of the causes of the late ticks, of the app events beside them, of those the
    control loops shared, and the `shown` latest ticks in full."""
    lines = [f"late ticks (> {1e3 * threshold_s:.0f} ms beyond the period): {len(late)}"]
    if control is not None:
        lines += machine_lines(late, control, threshold_s, steal)
    if not late:
        return "\n".join(lines)
    lines.append("  by cause: " + ", ".join(f"{c} {n}" for c, n in cause_counts(late).items()))
    over_aim = [t for t in late if t.late_s > AIM_S]
    if threshold_s < AIM_S:
        lines.append(
            f"  of them > {1e3 * AIM_S:.0f} ms late: {len(over_aim)}; by cause: "
            + ", ".join(f"{c} {n}" for c, n in cause_counts(over_aim).items())
        )
    beside: collections.Counter[str] = collections.Counter()
    for tick in late:
        beside.update(events.during(tick, slack_s=0.5) or ["none"])
    lines.append(
        "  app events within 0.5 s of the gap: "
        + ", ".join(f"{name} {n}" for name, n in beside.most_common())
    )
    runq = sorted(t.runqueue_s / t.late_s for t in late if t.late_s > 0)
    lines.append(
        f"  run-queue wait / lateness: median {runq[len(runq) // 2]:.2f}, "
        f"min {runq[0]:.2f}, max {runq[-1]:.2f}"
    )
    if steal is not None:
        stolen = [steal.during(t) for t in late]
        lines.append(
            f"  machine steal time over the run: {steal.total():.2f} s; beside late ticks "
            f"(gap ± 0.1 s): {sum(s > 0 for s in stolen)} of {len(late)} had some, max "
            f"{1e3 * max((s for s in stolen if s == s), default=0.0):.0f} ms"
        )
    worst = sorted(late, key=lambda t: t.late_s, reverse=True)[:shown]
    lines.append(f"  the {len(worst)} latest (ms):")
    for tick in worst:
        stamp = time.strftime("%H:%M:%S", time.gmtime(tick.at_s))
        extra = ", ".join(events.during(tick, slack_s=0.5)) or "-"
        if steal is not None:
            extra += f"; steal {1e3 * steal.during(tick):.0f} ms"
        if control is not None:
            shared = control.beside(tick.at_s, tick.gap_s)
            extra += "; control loops late " + (
                ", ".join(
                    f"{1e3 * c.late_s:.0f} (run queue {1e3 * c.runqueue_s:.0f})" for c in shared
                )
                or "-"
            )
        lines.append(f"    {stamp} {tick.describe()}; app: {extra}")
    return "\n".join(lines)


def machine_lines(
    late: tuple[LateTick, ...],
    control: ControlReport,
    threshold_s: float,
    steal: StealSampler | None = None,
) -> list[str]:
    """The control loops' own lateness, and which late ticks were the machine's: the control
    loops were late at the same moment, or the VM's steal time beside the gap covers at least
    half the lateness (a vCPU not run by the hypervisor: the control loops, on the other one,
    may have run meanwhile)."""

    def stolen(tick: LateTick) -> bool:
        return steal is not None and steal.during(tick) >= 0.5 * tick.late_s

    shared = [t for t in late if control.beside(t.at_s, t.gap_s)]
    own = [t for t in late if t not in shared and not stolen(t)]
    return [
        f"  control loops (wake-ups only, at the sessions' priority): largest lateness "
        f"{1e3 * control.largest_late_s:.1f} ms; {len(control.stalls)} wake-ups > "
        f"{1e3 * threshold_s:.0f} ms late, {sum(s.late_s > AIM_S for s in control.stalls)} "
        f"> {1e3 * AIM_S:.0f} ms",
        f"  late ticks the machine explains: {len(late) - len(own)} of {len(late)} (the control "
        f"loops were late too: {len(shared)}; else steal time beside the gap >= half the "
        f"lateness: {len(late) - len(own) - len(shared)})",
        f"  late ticks of bt's own (neither): {len(own)}, the latest "
        f"{1e3 * max((t.late_s for t in own), default=0.0):.1f} ms late",
    ]


def write_log(
    path: Path,
    late: tuple[LateTick, ...],
    events: AppEvents,
    steal: StealSampler | None = None,
    control: ControlReport | None = None,
) -> None:
    """Every late tick as a JSON line: its fields, its cause and the app events beside it."""
    with path.open("a", encoding="utf-8") as out:
        for tick in late:
            row = dataclasses.asdict(tick) | {
                "cause": tick.cause,
                "app": events.during(tick, slack_s=0.5),
                "steal_s": steal.during(tick) if steal is not None else None,
                "control_late_runqueue_s": [  # the control loops' lateness, run-queue wait
                    (c.late_s, c.runqueue_s)
                    for c in (control.beside(tick.at_s, tick.gap_s) if control else [])
                ],
            }
            out.write(json.dumps(row) + "\n")
