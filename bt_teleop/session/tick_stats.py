"""How punctually a session's control loop ticks: the gaps between ticks and each tick's cost.

::

    TimedSession(Session)     a Session whose every tick is timed (wall clock, perf_counter)
        .tick_stats() -> TickReport   gaps between ticks and compute per tick, as histograms,
                                      and each late tick's attribution (session/late_ticks.py)

A *stall* is a gap between two ticks beyond the control period: the loop asked to tick every
``1 / control_hz`` seconds and did not. The histograms have fixed 0.1 ms bins up to 2 s (the
largest value is kept exactly), so a session that runs for hours holds the same few hundred KiB
(a list of every gap grew ~1 MiB a minute at 8 × 100 Hz in benchmarks/soak/bench_soak.py).
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bt_teleop.proc.priority import raise_priority, use_realtime
from bt_teleop.session.control_loop import Session
from bt_teleop.session.late_ticks import LateProbe, LateTick

__all__ = [
    "BIN_S",
    "N_BINS",
    "Histogram",
    "TickReport",
    "TimedSession",
]

LOGGER = logging.getLogger("bt.teleop")
BIN_S = 1e-4
"""Width of a histogram bin [s]."""
N_BINS = 20_000
"""Bins of a histogram (the last one holds everything from ``(N_BINS - 1) · BIN_S`` up)."""


class Histogram:
    """Durations [s] in fixed 0.1 ms bins; the largest one exactly (not thread-safe)."""

    def __init__(self) -> None:
        self.counts: NDArray[np.int64] = np.zeros(N_BINS, dtype=np.int64)
        self.max_s = 0.0

    def add(self, seconds: float) -> None:
        """Count one duration [s]."""
        self.counts[min(max(int(seconds / BIN_S), 0), N_BINS - 1)] += 1
        self.max_s = max(self.max_s, seconds)


@dataclass(frozen=True, eq=False)  # holds arrays
class TickReport:
    """A session's tick timing so far (or several sessions' merged: :meth:`merged`)."""

    period_s: float
    """The control period the loop aims for [s]."""
    gap_counts: NDArray[np.int64]
    """Wall time between consecutive ticks: counts of 0.1 ms bins, shape (N_BINS,)."""
    max_gap_s: float
    """The longest gap between two ticks [s] (0 before the second tick)."""
    compute_counts: NDArray[np.int64]
    """Wall time of the ticks themselves (IK + physics + sampling), 0.1 ms bins, (N_BINS,)."""
    max_compute_s: float
    """The longest tick [s]."""
    nice: int | None = None
    """The control thread's nice value while it ran (None: not started, or merged reports
    that differ); lower is a higher priority (``SessionConfig.priority_boost``)."""
    realtime: bool | None = None
    """Whether the control thread ran under a real-time policy (``SCHED_RR``:
    ``SessionConfig.realtime_priority``; None: not started, or merged reports that differ)."""
    late: tuple[LateTick, ...] = ()
    """The ticks later than ``SessionConfig.late_tick_s`` and what overlapped each gap
    (:mod:`bt_teleop.session.late_ticks`; the most recent
    :data:`~bt_teleop.session.late_ticks.MAX_KEPT`)."""

    @property
    def n_ticks(self) -> int:
        """Ticks timed (gaps counted: one fewer than the ticks run)."""
        return int(self.gap_counts.sum())

    @property
    def largest_stall_s(self) -> float:
        """The longest gap beyond the control period [s] (0 when every tick was on time)."""
        return max(0.0, self.max_gap_s - self.period_s)

    def gap_percentile(self, q: float) -> float:
        """The `q`-th percentile of the gaps [s] (to its bin's centre; 0 without ticks)."""
        return _percentile(self.gap_counts, self.max_gap_s, q)

    def compute_percentile(self, q: float) -> float:
        """The `q`-th percentile of the ticks' own time [s]."""
        return _percentile(self.compute_counts, self.max_compute_s, q)

    def gaps_above(self, seconds: float) -> int:
        """Gaps longer than `seconds` [s] (to the bin)."""
        return int(self.gap_counts[min(int(seconds / BIN_S) + 1, N_BINS) :].sum())

    @staticmethod
    def merged(reports: list[TickReport]) -> TickReport:
        """Every report's ticks in one (the period of the first)."""
        if not reports:
            raise ValueError("no tick reports to merge")
        return TickReport(
            reports[0].period_s,
            np.sum([r.gap_counts for r in reports], axis=0),
            max(r.max_gap_s for r in reports),
            np.sum([r.compute_counts for r in reports], axis=0),
            max(r.max_compute_s for r in reports),
            reports[0].nice if len({r.nice for r in reports}) == 1 else None,
            reports[0].realtime if len({r.realtime for r in reports}) == 1 else None,
            tuple(t for r in reports for t in r.late),
        )


def _percentile(counts: NDArray[np.int64], max_s: float, q: float) -> float:
    cumulative = np.cumsum(counts)
    if cumulative[-1] == 0:
        return 0.0
    index = int(np.searchsorted(cumulative, q / 100.0 * cumulative[-1]))
    return min((index + 0.5) * BIN_S, max_s)


class TimedSession(Session):
    """A :class:`~bt_teleop.session.control_loop.Session` that times every control tick (the app's
    sessions, in a process of their own or not); :meth:`tick_stats` reads the timing.

    Its :attr:`late_probe` attributes the late ticks: the tick's IK and recording-sample
    phases are timed by wrapping the session's IK controller and recording slot (the rest of a
    tick, mostly ``mj_step``, is its ``physics`` phase)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        """The arguments of :class:`~bt_teleop.session.control_loop.Session`."""
        self._gaps, self._compute = Histogram(), Histogram()
        self._stats_lock = threading.Lock()
        self._last_tick: float | None = None
        self._last_compute = 0.0
        self._nice: int | None = None
        self._realtime: bool | None = None
        super().__init__(*args, **kwargs)
        self.late_probe = LateProbe(self.dt_s, self.config.late_tick_s)
        """What overlapped each late tick's gap (:mod:`bt_teleop.session.late_ticks`)."""
        if self.late_probe.enabled:
            self._ik.solve = self._timed("ik", self._ik.solve)  # type: ignore[method-assign]
            self._demo.sample_due = self._timed(  # type: ignore[method-assign]
                "sample", self._demo.sample_due
            )

    def _timed(self, name: str, function: Any) -> Any:
        probe = self.late_probe

        def timed(*args: Any, **kwargs: Any) -> Any:
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                probe.phase(name, time.perf_counter() - start)

        return timed

    def _run(self) -> None:
        """The real-time loop, its thread's priority raised by ``config.priority_boost``, and
        under ``SCHED_RR`` with ``config.realtime_priority``."""
        self._nice = raise_priority(self.config.priority_boost)
        self._realtime = use_realtime(self.config.realtime_priority)
        self.late_probe.loop_started()
        super()._run()

    def _tick(self) -> None:
        start = time.perf_counter()
        self.late_probe.tick_started(start, self._last_compute)
        super()._tick()
        end = time.perf_counter()
        self._last_compute = end - start
        self.late_probe.tick_ended(self._last_compute)
        with self._stats_lock:
            if self._last_tick is not None:
                self._gaps.add(start - self._last_tick)
            self._last_tick = start
            self._compute.add(end - start)

    def tick_stats(self) -> TickReport:
        """The timing of every tick so far (copies)."""
        with self._stats_lock:
            gaps, compute = self._gaps, self._compute
            return TickReport(
                self.dt_s,
                gaps.counts.copy(),
                gaps.max_s,
                compute.counts.copy(),
                compute.max_s,
                self._nice,
                self._realtime,
                self.late_probe.kept(),
            )

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the loop; the next start's first tick does not count the pause as a gap."""
        super().stop(timeout_s)
        with self._stats_lock:
            self._last_tick = None
