"""Soak: 8 scripted browser-like sessions on one teleop app for a long time (10 min by default).

Each of the 8 tabs is a real viser websocket client (:class:`bt_teleop.testing.FakeTab`) that
reads everything the server sends; a driver thread per tab does what a person does, through the
app's own handles: drags the target along a circle (``Session.set_target``, what the gizmo
callback calls) at 30 Hz, presses Record, records a take of a few seconds, presses Stop & save,
and again; every ``--clean-every`` seconds one tab presses Clean (the cleaner then competes for
the CPU, as in real use).

Reported:

* the largest control-loop stall over all sessions: the longest wall time between two control
  ticks minus the tick period (each session's ``_tick`` is wrapped with a timestamp), and the
  distribution of those gaps (p50, p99, p99.9, max);
* where the time went (to attribute stalls): the compute time of the ticks themselves, the
  garbage collector's pauses (``gc.callbacks``), the task-library loads every save triggers
  (:func:`bt_teleop.library.load_library` as the tabs' shared loader calls it, timed), the
  process's CPU use in cores;
* resident memory (psutil) every ``--sample-every`` seconds, and its slope over the second
  half of the run [MiB/min] (flat: about 0), with the machine's 1-minute load average at the
  same moments (other jobs share the CPU);
* takes saved vs intended (Stop & save presses; files counted on disk at the end);
* with ``--discard`` the tabs press Discard instead of Stop & save: the same recording work
  without files, library loads or table updates, a control for the memory measured;
* with ``--tracemalloc N``: what was allocated after a third of the run and is still held at
  its end, by the Python lines that allocated it (N frames of traceback; tracing starts at the
  third). Tracing slows the app down several times, so the starved loops simulate too little
  time for a 2-4 s take: give longer takes (``--take-s 15``) and use such a run to find what
  grows, not for the stall or RSS numbers.

Aims (issue 10): no stall > 50 ms, memory flat, 0 lost takes.

    nice -n 10 .venv/bin/python benchmarks/bench_soak.py --minutes 10
    nice -n 10 .venv/bin/python benchmarks/bench_soak.py --minutes 4 --sessions 4 \
        --take-s 15 --tracemalloc 6
"""

from __future__ import annotations

import argparse
import gc
import os
import shutil
import sys
import tempfile
import threading
import time
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import psutil

import bt_teleop.library
import bt_teleop.library_loader
from bt_teleop.app import TeleopApp
from bt_teleop.testing import app_factory, circle_uv, reachable, tab_factory, wait_until
from bt_teleop.ui import ClientUI

REFUSALS = ("Not done", "Error")
"""Titles of the notices a tab shows when an action fails."""


class Durations:
    """A histogram of durations in fixed memory (0.1 ms bins up to 5 s; the max exactly).

    Keeping every tick's time in a list grew the benchmark's own memory by ~1 MiB a minute at
    8 × 100 Hz, inside the RSS the soak measures; this allocates (and touches) its bins once.
    """

    BIN_S = 1e-4
    BINS = 50_000

    def __init__(self) -> None:
        self.counts = np.ones(self.BINS, dtype=np.int64)  # ones, then zeros: every page touched
        self.counts[:] = 0
        self.max_s = 0.0

    def add(self, seconds: float) -> None:
        self.counts[min(int(seconds / self.BIN_S), self.BINS - 1)] += 1
        self.max_s = max(self.max_s, seconds)

    @property
    def n(self) -> int:
        return int(self.counts.sum())

    def percentile(self, q: float) -> float:
        """The `q`-th percentile [s] (to the bin's centre)."""
        cumulative = np.cumsum(self.counts)
        index = int(np.searchsorted(cumulative, q / 100.0 * cumulative[-1]))
        return min((index + 0.5) * self.BIN_S, self.max_s)

    def count_above(self, seconds: float) -> int:
        return int(self.counts[int(seconds / self.BIN_S) + 1 :].sum())

    @staticmethod
    def merged(parts: list[Durations]) -> Durations:
        total = Durations()
        for part in parts:
            total.counts += part.counts
            total.max_s = max(total.max_s, part.max_s)
        return total


class TickClock:
    """Wraps a session's ``_tick`` to keep the gaps between ticks and each tick's own time."""

    def __init__(self, ui: ClientUI) -> None:
        self.gaps = Durations()
        self.compute = Durations()
        self._last: float | None = None
        session = ui.session
        tick = session._tick

        def timed() -> None:
            now = time.perf_counter()
            if self._last is not None:
                self.gaps.add(now - self._last)
            self._last = now
            tick()
            self.compute.add(time.perf_counter() - now)

        session._tick = timed  # type: ignore[method-assign]


class Timed:
    """Durations [s] of the calls of a wrapped function."""

    def __init__(self) -> None:
        self.durations: list[float] = []

    def wrap(self, function: Any) -> Any:
        def timed(*args: Any, **kwargs: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                self.durations.append(time.perf_counter() - t0)

        return timed

    def summary(self) -> str:
        d = np.asarray(self.durations) * 1e3
        if not d.size:
            return "none"
        total = d.sum() / 1e3
        return (
            f"{d.size} calls, total {total:.1f} s, p50 {np.median(d):.1f} ms, max {d.max():.0f} ms"
        )


class GcPauses:
    """The garbage collector's pauses, by generation (``gc.callbacks``)."""

    def __init__(self) -> None:
        self.pauses: dict[int, list[float]] = {0: [], 1: [], 2: []}
        self._t0 = 0.0
        gc.callbacks.append(self._callback)

    def _callback(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self._t0 = time.perf_counter()
        else:
            self.pauses[info["generation"]].append(time.perf_counter() - self._t0)

    def summary(self) -> str:
        parts = []
        for generation, pauses in self.pauses.items():
            d = np.asarray(pauses) * 1e3
            top = f", max {d.max():.1f} ms" if d.size else ""
            parts.append(f"gen{generation} {d.size}× (total {d.sum() / 1e3:.2f} s{top})")
        return "; ".join(parts)


class Sampler:
    """RSS [MiB], the 1-minute load average and, while tracemalloc traces, the Python memory
    it sees [MiB] (NaN otherwise) every `every_s` seconds, in a thread."""

    def __init__(self, every_s: float) -> None:
        self.rows: list[tuple[float, float, float, float]] = []  # t [s], RSS, load, traced
        self._process = psutil.Process()
        self._t0 = time.monotonic()
        self._stop = threading.Event()
        self.sample()
        self._thread = threading.Thread(target=self._run, args=(every_s,), daemon=True)
        self._thread.start()

    def sample(self) -> None:
        rss = self._process.memory_info().rss / 2**20
        traced = tracemalloc.get_traced_memory()[0] / 2**20 if tracemalloc.is_tracing() else np.nan
        self.rows.append((time.monotonic() - self._t0, rss, os.getloadavg()[0], traced))

    def _run(self, every_s: float) -> None:
        while not self._stop.wait(every_s):
            self.sample()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        self.sample()

    def slope_second_half(self, column: int = 1) -> float:
        """Least-squares slope of RSS (or another column) over the second half of the run
        [MiB/min]."""
        rows = np.asarray(self.rows)
        half = rows[(rows[:, 0] >= rows[-1, 0] / 2.0) & np.isfinite(rows[:, column])]
        if len(half) < 2:
            return float("nan")
        return float(np.polyfit(half[:, 0] / 60.0, half[:, column], 1)[0])


def deep_size(root: Any) -> tuple[int, int]:
    """(bytes, numpy array bytes) of everything reachable from `root` (``sys.getsizeof``)."""
    objects = list(reachable(root))
    arrays = sum(item.nbytes for item in objects if isinstance(item, np.ndarray))
    return sum(sys.getsizeof(item) for item in objects), arrays


def held_by_loader(app: TeleopApp, uis: list[ClientUI]) -> str:
    """What the tabs' shared library loader, the tabs' libraries and Play's reader hold."""
    files = dict(app.context.libraries._files)
    cache, cache_arrays = deep_size(files)
    libraries, library_arrays = deep_size([ui.library for ui in uis])
    tracks = sum(len(file.tracks) for file in files.values())
    return (
        f"the tabs' shared loader lists {tracks} demos of {len(files)} files in "
        f"{cache / 2**10:.0f} KiB ({cache / max(tracks, 1):.0f} bytes a demo, "
        f"{cache_arrays} bytes of sample arrays); the tabs' libraries with it: "
        f"{libraries / 2**10:.0f} KiB ({library_arrays} bytes of arrays); Play's reader holds "
        f"{app.context.samples.cached} tracks"
    )


class Refusals:
    """Counts the notices of failed actions of a tab (its own list keeps only the last 100)."""

    def __init__(self, ui: ClientUI) -> None:
        self.bodies: list[str] = []
        notify = ui._notify

        def counted(title: str, body: str, color: Any = None) -> None:
            if title in REFUSALS:
                self.bodies.append(body)
            notify(title, body, color)

        ui._notify = counted  # type: ignore[method-assign]


def top_growth(snapshot: tracemalloc.Snapshot, n: int = 25) -> str:
    """The `n` allocation sites holding most of what was allocated since tracing started."""
    noise = [
        tracemalloc.Filter(False, tracemalloc.__file__),
        tracemalloc.Filter(False, "<frozen importlib._bootstrap*>"),
        tracemalloc.Filter(False, "<unknown>"),
    ]
    stats = snapshot.filter_traces(noise).statistics("traceback")
    lines = []
    for stat in stats[:n]:
        lines.append(f"{stat.size / 1024:.1f} KiB in {stat.count} blocks:")
        lines += [f"      {frame.filename}:{frame.lineno}" for frame in stat.traceback[-6:]]
    total = sum(stat.size for stat in stats)
    return (
        f"allocated since tracing started and still held: {total / 2**20:.2f} MiB; top sites:"
        "\n  " + "\n  ".join(lines)
    )


def drive(
    ui: ClientUI,
    stop: threading.Event,
    seed: int,
    counts: dict[str, int],
    take_s: float,
    discard: bool = False,
) -> None:
    """Record takes of `take_s`-2 `take_s` seconds (wall time), the target on a circle, until
    `stop`; save each (or, with `discard`, press Discard instead)."""
    rng = np.random.default_rng(seed)
    plane = ui.session.scene.plane
    t0 = time.perf_counter()
    while not stop.is_set():
        ui.controls.record_button.value = True
        ui.wait_idle()
        end = time.perf_counter() + float(rng.uniform(take_s, 2.0 * take_s))
        while time.perf_counter() < end and not stop.is_set():
            ui.session.set_target(plane.to_world(circle_uv(time.perf_counter() - t0)))
            time.sleep(1.0 / 30.0)
        if stop.is_set():
            break
        counts["intended"] += 0 if discard else 1
        (ui.controls.discard_button if discard else ui.controls.save_button).value = True
        ui.wait_idle(30.0)
        time.sleep(float(rng.uniform(0.2, 1.0)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--sessions", type=int, default=8)
    parser.add_argument("--clean-every", type=float, default=120.0, help="[s]; 0: never")
    parser.add_argument("--sample-every", type=float, default=30.0, help="RSS and load [s]")
    parser.add_argument(
        "--tracemalloc", type=int, default=0, help="frames to trace (0: off); see the docstring"
    )
    parser.add_argument(
        "--take-s", type=float, default=2.0, help="takes last U(take_s, 2 take_s) s of wall time"
    )
    parser.add_argument(
        "--discard",
        action="store_true",
        help="press Discard instead of Stop & save (the same work without the files: a control)",
    )
    args = parser.parse_args()
    process = psutil.Process()
    loads = Timed()
    bt_teleop.library_loader.load_library = loads.wrap(bt_teleop.library.load_library)
    tmp = tempfile.mkdtemp(prefix="bt-soak-")
    with app_factory(Path(tmp) / "rec") as make, tab_factory() as open_tab:
        # The drivers act through the app's handles, not the websocket, so every tab looks
        # silent: idle closing (tests/test_connections.py) would end them at the 10-min mark.
        app: TeleopApp = make(
            max_sessions=args.sessions, clean_epochs=5, idle_timeout_s=float("inf")
        )
        tabs = [open_tab(app, decode=False) for _ in range(args.sessions)]
        uis = list(app.wait_for_sessions(args.sessions, 120.0).values())
        clocks = [TickClock(ui) for ui in uis]
        refusals = [Refusals(ui) for ui in uis]
        time.sleep(2.0)
        sampler = Sampler(args.sample_every)
        pauses = GcPauses()
        cpu_start, wall_start = process.cpu_times(), time.monotonic()
        stop = threading.Event()
        counts = [{"intended": 0} for _ in uis]
        drivers = [
            threading.Thread(
                target=drive, args=(ui, stop, k, counts[k], args.take_s, args.discard), daemon=True
            )
            for k, ui in enumerate(uis)
        ]
        for thread in drivers:
            thread.start()
        end = time.monotonic() + 60.0 * args.minutes
        next_clean = time.monotonic() + args.clean_every if args.clean_every else None
        cleans = 0
        trace_at = time.monotonic() + 20.0 * args.minutes  # a third of the run
        while time.monotonic() < end:
            time.sleep(1.0)
            if args.tracemalloc and not tracemalloc.is_tracing() and time.monotonic() >= trace_at:
                gc.collect()
                tracemalloc.start(args.tracemalloc)
            if next_clean is not None and time.monotonic() >= next_clean:
                uis[cleans % len(uis)].controls.clean_button.value = True
                cleans += 1
                next_clean += args.clean_every
        stop.set()
        for thread in drivers:
            thread.join(60.0)
        wait_until(app.settled, 60.0, "tabs to settle")
        for ui in uis:
            ui.wait_idle(120.0)  # the last Stop & save may still be queued
        refused = [body for counted in refusals for body in counted.bodies]
        sampler.stop()
        growth_text = ""
        if tracemalloc.is_tracing():
            gc.collect()
            growth_text = top_growth(tracemalloc.take_snapshot())
            tracemalloc.stop()
        cpu_end, wall = process.cpu_times(), time.monotonic() - wall_start
        received = sum(tab.bytes for tab in tabs)
        saved_ui = sum(ui.takes.saved_count for ui in uis)
        files = len(list((Path(tmp) / "rec" / "wiping").glob("*.hdf5")))
        held = held_by_loader(app, uis)
    gaps = Durations.merged([c.gaps for c in clocks])
    compute = Durations.merged([c.compute for c in clocks])
    period = 1.0 / uis[0].session.config.control_hz
    intended = sum(c["intended"] for c in counts)
    print(f"{args.sessions} sessions for {args.minutes:g} min, {cleans} Clean presses")
    print(
        f"control ticks: {gaps.n} ({gaps.n / wall:.0f}/s of {args.sessions / period:.0f}/s"
        f" intended), period {1e3 * period:.1f} ms"
    )
    print(f"largest stall: {1e3 * (gaps.max_s - period):.1f} ms beyond the period")
    p50, p99, p999 = (1e3 * gaps.percentile(q) for q in (50, 99, 99.9))
    print(
        f"gap p50: {p50:.1f} ms, p99: {p99:.1f} ms, p99.9: {p999:.1f} ms, "
        f"max {1e3 * gaps.max_s:.0f} ms (0.1 ms bins)"
    )
    print(f"stalls > 50 ms: {gaps.count_above(period + 0.05)}")
    c50, c99 = (1e3 * compute.percentile(q) for q in (50, 99))
    print(f"tick compute: p50 {c50:.2f} ms, p99 {c99:.2f} ms, max {1e3 * compute.max_s:.0f} ms")
    print(f"gc pauses: {pauses.summary()}")
    print(f"task-library loads (after saves): {loads.summary()}")
    used = (cpu_end.user + cpu_end.system - cpu_start.user - cpu_start.system) / wall
    print(f"CPU of the app: {used:.2f} cores of {psutil.cpu_count()}")
    rows = np.asarray(sampler.rows)
    print(
        f"load average (1 min): min {rows[:, 2].min():.1f}, mean {rows[:, 2].mean():.1f}, "
        f"max {rows[:, 2].max():.1f}"
    )
    print(
        f"memory (RSS): {rows[0, 1]:.0f} MiB at start, {rows[-1, 1]:.0f} MiB at end, "
        f"slope over the second half {sampler.slope_second_half():+.2f} MiB/min"
    )
    print(
        "  t [s]  RSS [MiB]  load: "
        + "; ".join(f"{t:.0f} {m:.0f} {la:.1f}" for t, m, la, _ in rows)
    )
    if np.isfinite(rows[:, 3]).any():
        print(
            f"Python memory tracemalloc sees: slope over the second half "
            f"{sampler.slope_second_half(3):+.2f} MiB/min; t [s] MiB: "
            + "; ".join(f"{t:.0f} {m:.1f}" for t, _, _, m in rows if np.isfinite(m))
        )
    growth = rows[-1, 1] - rows[0, 1]
    print(f"RSS growth per saved take: {1024 * growth / max(saved_ui, 1):.0f} KiB; {held}")
    print(f"takes: {intended} intended, {saved_ui} saved by the tabs, {files} files on disk")
    print(f"refused actions: {len(refused)}" + "".join(f"\n  {body}" for body in refused[:10]))
    print(f"bytes sent to the tabs: {received / 2**20:.0f} MiB")
    if growth_text:
        print(growth_text)
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
