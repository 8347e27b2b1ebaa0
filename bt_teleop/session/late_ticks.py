"""Why a control tick was late: what the loop's thread and its process did during each long gap.

Issue 10 aims at no control-loop stall over 50 ms. A stall's cause is invisible in the gap
alone, so for every gap longer than the period plus ``SessionConfig.late_tick_s`` the loop
keeps a :class:`LateTick` with what could have taken the time::

    LateProbe (one per TimedSession)
      .tick_started(now)        every tick (control thread): schedstat read, gap checked
      .phase(name, seconds)     the tick's own phases (IK, recording sample)
      .tick_ended(seconds)      the rest of the tick is its physics phase
      .serving(name)            the command thread's requests (status, trail, stop_and_check ...)
      .watch_peer()             the command thread reads its own schedstat too
    GcLog (one per process)     every collection (gc.callbacks): generation, start, end

The run-queue wait is the Linux scheduler's own count of the time a runnable thread waited for
a CPU (``/proc/thread-self/schedstat``, second field, ns; the first is time on a CPU). When it
covers the lateness, the loop was starved of CPU by other work (other processes, or other
threads of the machine), and nothing in the process could have helped. When it does not, the
thread was blocked (the GIL, a lock) or computing: the collections, requests and phases
overlapping the gap say by what. Reading schedstat costs ~1 µs (``pread`` on a kept fd), so the
probe is on by default; ``late_tick_s = inf`` turns it off.
"""

from __future__ import annotations

import collections
import contextlib
import gc
import math
import os
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

__all__ = ["GcLog", "LateProbe", "LateTick", "cause_counts", "gc_log"]

MAX_KEPT = 2000
"""Late ticks a session keeps (the most recent)."""
_LOG_LEN = 512
"""Collections and requests remembered (enough to cover any gap at the rates seen)."""
_NAN2 = (math.nan, math.nan)


@dataclass(frozen=True)
class LateTick:
    """One gap between control ticks longer than the period plus the threshold, and what
    overlapped it (times in seconds)."""

    at_s: float
    """Wall clock (``time.time()``) when the late tick started: to line it up with events of
    other processes (the app's heap trims, clean jobs)."""
    gap_s: float
    """Start of the tick before to start of this one."""
    late_s: float
    """``gap_s`` minus the period."""
    runqueue_s: float
    """The control thread waited for a CPU this long during the gap (nan: unknown)."""
    on_cpu_s: float
    """The control thread ran on a CPU this long during the gap (nan: unknown)."""
    peer_runqueue_s: float
    """The command thread (which shares the GIL) waited for a CPU this long (nan: unknown)."""
    peer_on_cpu_s: float
    """The command thread ran on a CPU this long during the gap (nan: unknown)."""
    tick_s: float
    """Wall time of the tick before the gap (the loop's own work)."""
    phases: tuple[tuple[str, float], ...] = ()
    """That tick's phases: (name, wall time)."""
    collections: tuple[tuple[int, float], ...] = ()
    """Garbage collections in this process overlapping the gap: (generation, overlap)."""
    requests: tuple[tuple[str, float], ...] = ()
    """The command thread's requests overlapping the gap: (name, overlap)."""

    @property
    def cause(self) -> str:
        """What explains at least half the lateness, checked in this order: ``cpu`` (the
        control thread's run-queue wait), ``peer-cpu`` (the control thread was blocked, off
        the CPU and not runnable, while the command thread waited for a CPU: it held the GIL
        or the state lock, preempted), ``gc<generation>`` (a collection),
        ``request:<name>`` (the command thread served it: it held the GIL or the state lock),
        ``tick:<phase>`` (a phase of the tick before took the time itself), else
        ``unattributed``. Starvation comes first: a request or phase that was only slowed by
        it names where the time went, not why."""
        half = 0.5 * self.late_s
        if self.runqueue_s >= half:
            return "cpu"
        blocked = self.gap_s - self.on_cpu_s - self.runqueue_s
        candidates = (
            [("peer-cpu", min(self.peer_runqueue_s, blocked))]
            + [(f"gc{g}", s) for g, s in self.collections]
            + [(f"request:{n}", s) for n, s in self.requests]
            + [(f"tick:{n}", s) for n, s in self.phases]
        )
        for name, seconds in candidates:
            if seconds >= half:
                return name
        return "unattributed"

    def describe(self) -> str:
        """One line with every number (ms)."""

        def ms(pairs: tuple[tuple[object, float], ...]) -> str:
            return ", ".join(f"{n} {1e3 * s:.1f}" for n, s in pairs) or "-"

        return (
            f"{self.cause}: gap {1e3 * self.gap_s:.1f} ms (late {1e3 * self.late_s:.1f}); "
            f"control thread: run queue {1e3 * self.runqueue_s:.1f}, on CPU "
            f"{1e3 * self.on_cpu_s:.1f}; command thread: run queue "
            f"{1e3 * self.peer_runqueue_s:.1f}, on CPU {1e3 * self.peer_on_cpu_s:.1f}; "
            f"tick before {1e3 * self.tick_s:.1f} ({ms(self.phases)}); gc: "
            f"{ms(self.collections)}; requests: {ms(self.requests)}"
        )


def cause_counts(late: list[LateTick] | tuple[LateTick, ...]) -> dict[str, int]:
    """How many late ticks each cause explains, most first."""
    return dict(collections.Counter(t.cause for t in late).most_common())


class GcLog:
    """This process's garbage collections (``gc.callbacks``): (generation, start, end) in
    ``perf_counter`` seconds, the last few hundred."""

    def __init__(self, maxlen: int | None = _LOG_LEN) -> None:
        """Keep the last `maxlen` collections (None: every one, for a benchmark's summary)."""
        self.entries: collections.deque[tuple[int, float, float]] = collections.deque(maxlen=maxlen)
        self._start = 0.0
        gc.callbacks.append(self._callback)

    def _callback(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self._start = time.perf_counter()
        else:
            self.entries.append((info["generation"], self._start, time.perf_counter()))

    def overlapping(self, t0: float, t1: float) -> tuple[tuple[int, float], ...]:
        """Collections overlapping [t0, t1]: (generation, seconds of overlap)."""
        return tuple((g, o) for g, a, b in _snapshot(self.entries) if (o := _overlap(a, b, t0, t1)))


_gc_log: GcLog | None = None
_gc_log_lock = threading.Lock()


def gc_log() -> GcLog:
    """This process's :class:`GcLog` (installed on first use)."""
    global _gc_log
    with _gc_log_lock:
        if _gc_log is None:
            _gc_log = GcLog()
        return _gc_log


class _ThreadClock:
    """A thread's scheduler counters (on a CPU, waiting for one) [s], from its own schedstat
    file opened by that thread."""

    def __init__(self) -> None:
        try:
            self._fd: int | None = os.open("/proc/thread-self/schedstat", os.O_RDONLY)
        except OSError:  # not Linux, or no schedstat
            self._fd = None

    def read(self) -> tuple[float, float]:
        if self._fd is None:
            return _NAN2
        try:
            fields = os.pread(self._fd, 128, 0).split()
            return int(fields[0]) * 1e-9, int(fields[1]) * 1e-9
        except (OSError, ValueError, IndexError):
            return _NAN2


@dataclass
class _TickMark:
    t: float
    clock: tuple[float, float]
    peer: tuple[float, float]
    phases: dict[str, float] = field(default_factory=dict)


class LateProbe:
    """Attributes a session's late ticks (see the module docstring)."""

    def __init__(self, period_s: float, late_after_s: float) -> None:
        """Keep the gaps longer than `period_s` + `late_after_s` [s] (inf: none, no reads)."""
        self.period_s = period_s
        self.late_after_s = late_after_s
        self.enabled = math.isfinite(late_after_s)
        self.late: collections.deque[LateTick] = collections.deque(maxlen=MAX_KEPT)
        self._gc = gc_log() if self.enabled else None
        self._requests: collections.deque[tuple[str, float, float]] = collections.deque(
            maxlen=_LOG_LEN
        )
        self._serving: tuple[str, float] | None = None
        self._clock: _ThreadClock | None = None
        self._peer: _ThreadClock | None = None
        self._last: _TickMark | None = None
        self._phases: dict[str, float] = {}

    def watch_peer(self) -> None:
        """Call from the thread serving requests: its scheduler counters are read too."""
        if self.enabled:
            self._peer = _ThreadClock()

    def loop_started(self) -> None:
        """Call from the control thread when its loop starts (its schedstat file is opened)."""
        if self.enabled and self._clock is None:
            self._clock = _ThreadClock()
        self._last = None

    @contextlib.contextmanager
    def serving(self, name: str) -> Iterator[None]:
        """Around a request of the command thread."""
        if not self.enabled:
            yield
            return
        start = time.perf_counter()
        self._serving = (name, start)
        try:
            yield
        finally:
            self._serving = None
            self._requests.append((name, start, time.perf_counter()))

    def phase(self, name: str, seconds: float) -> None:
        """The tick in progress spent `seconds` in phase `name` (control thread)."""
        self._phases[name] = self._phases.get(name, 0.0) + seconds

    def tick_ended(self, seconds: float) -> None:
        """The tick in progress took `seconds` [s]: what its timed phases left is ``physics``
        (slewing, ``mj_step``, the state lock)."""
        if self.enabled:
            self.phase("physics", seconds - sum(self._phases.values()))

    def kept(self) -> tuple[LateTick, ...]:
        """The late ticks kept so far (any thread)."""
        return tuple(_snapshot(self.late))

    def tick_started(self, now: float, previous_tick_s: float) -> None:
        """A tick starts at `now` (perf_counter); the one before took `previous_tick_s`."""
        if not self.enabled:
            return
        clock = self._clock.read() if self._clock is not None else _NAN2
        peer = self._peer.read() if self._peer is not None else _NAN2
        mark = _TickMark(now, clock, peer)
        last, self._last = self._last, mark
        phases, self._phases = self._phases, {}
        if last is None or now - last.t <= self.period_s + self.late_after_s:
            return
        t0, gap = last.t, now - last.t
        serving = self._serving
        requests = list(_snapshot(self._requests))
        if serving is not None:
            requests.append((serving[0], serving[1], now))
        assert self._gc is not None
        self.late.append(
            LateTick(
                at_s=time.time(),
                gap_s=gap,
                late_s=gap - self.period_s,
                runqueue_s=clock[1] - last.clock[1],
                on_cpu_s=clock[0] - last.clock[0],
                peer_runqueue_s=peer[1] - last.peer[1],
                peer_on_cpu_s=peer[0] - last.peer[0],
                tick_s=previous_tick_s,
                phases=tuple(phases.items()),
                collections=self._gc.overlapping(t0, now),
                requests=tuple(
                    (n, o) for n, a, b in requests if (o := _overlap(a, b, t0, now)) > 0.0
                ),
            )
        )


def _overlap(a: float, b: float, t0: float, t1: float) -> float:
    return max(0.0, min(b, t1) - max(a, t0))


def _snapshot(entries: collections.deque[Any]) -> list[Any]:
    """A copy of a deque another thread (or a gc callback in this one) may append to."""
    for _ in range(10):
        try:
            return list(entries)
        except RuntimeError:  # mutated during the copy
            continue
    return []
