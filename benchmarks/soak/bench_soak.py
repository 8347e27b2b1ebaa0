"""Soak: 8 scripted browser-like sessions on one teleop app for a long time (10 min by default).

Each of the 8 tabs is a real viser websocket client (:class:`bt_teleop.testing.harness.FakeTab`)
that reads everything the server sends; a driver thread per tab does what a person does, through the
app's own handles: drags the target along the task's guide, a loop every 4 s
(``session.set_target``, what the gizmo callback calls) at 30 Hz, presses Record, records a
take of 4-8 s (1-2 loops: it passes the take checks, so the library scores it and Clean cleans
it), presses Stop & save, and again; every ``--clean-every`` seconds one tab presses Clean (the
cleaner then competes for the CPU, as in real use).

Reported:

* the largest control-loop stall over all sessions: the longest wall time between two control
  ticks minus the tick period, and the distribution of those gaps (p50, p99, p99.9, max), as
  each session keeps them (:mod:`bt_teleop.session.tick_stats`; read from the session processes, or
  from the sessions in the app's process with ``--in-process``, the baseline);
* the late ticks attributed (:mod:`benchmarks.common.soak_late`): for each tick later than
  ``--late-ms``, what its session process did meanwhile (run-queue wait, collections, requests,
  the tick's phases: :mod:`bt_teleop.session.late_ticks`), the app's heap trims, Clean presses
  and library loads, and the machine's steal time beside it (``--late-log FILE``: every late tick as
  a JSON line);
* where the time went (to attribute stalls): the compute time of the ticks themselves, the
  app process's garbage-collector pauses (``gc.callbacks``), the task-library loads every save
  triggers (:func:`bt_teleop.library.listing.load_library` as the tabs' shared loader calls it,
  timed), the CPU used in cores by the app and its session processes;
* memory every ``--sample-every`` seconds over the app's whole process tree (the session
  processes, the forkserver, clean jobs): the sum of RSS (which counts the pages forked
  children share once per process), of PSS (shared pages split among their users) and of USS,
  the app process's own RSS, and the PSS of the anonymous memory of the processes that stay
  ("kept anon PSS": the measure that must stay flat; clean jobs move the file-backed part);
  their slopes over the second half of the run [MiB/min] (flat: about 0), with the machine's
  1-minute load average at the same moments (other jobs share the CPU); and the same per kind
  of process, with its C heap (in use, free) and slopes per quarter of the run
  (:mod:`benchmarks.common.soak_memory`; ``--memory-log FILE`` appends every sample as a JSON
  line);
* takes saved vs intended (Stop & save presses; files counted on disk at the end);
* with ``--discard`` the tabs press Discard instead of Stop & save: the same recording work
  without files, library loads or table updates, a control for the memory measured;
* with ``--library-loads none`` the takes are saved as usual but the tabs' library loads list
  nothing (no file is read or scored, tables and pickers stay empty), and with ``read-new``
  they read and score each new file as the app does and list nothing: controls that tell the
  memory of saving a take, of reading it, and of listing the task's takes apart;
* with ``--keep-takes N`` the benchmark moves all but the N newest takes out of the
  recordings folder every second, as a lab archives old takes: the takes on disk, the
  library's listing and each Clean job's input stay bounded, so memory that still grows grows
  with time, not with the data (a control for "memory flat");
* the late ticks the machine explains: ``--control-loops`` processes (``soak_control.py``)
  that only wake up every period at the sessions' priority; a late tick they shared, or that
  the VM's steal time beside it covers by half, is the machine's, the rest are bt's own;
* with ``--tracemalloc N``: what was allocated after a third of the run and is still held at
  its end, by the Python lines that allocated it (N frames of traceback; tracing starts at the
  third). Tracing slows the app down several times, so the starved loops simulate too little
  time for a 2-4 s take: give longer takes (``--take-s 15``) and use such a run to find what
  grows, not for the stall or RSS numbers.

The fake tabs (their websocket clients) run in a process of their own (``soak_tabs.py``), as
real browsers do; ``--tabs-in-app`` runs them as threads of the app's process, as the soak did
before 2026-12-03 (their receive buffers then counted as the app's memory). Their drivers run in
the benchmark's (the app's) process, as threads: they act through the app's handles, as the
gizmo's callbacks do, and add load to the app's process that real use does not (it is the
process the session processes left; their control loops no longer share its GIL).

Aims (issue 10): no stall > 50 ms, memory flat, 0 lost takes. The app trims its C heap every
``--trim-heap-every-s`` (the app's default, 60 s; ``inf``: never, the code before that change).

    nice -n 10 .venv/bin/python benchmarks/soak/bench_soak.py --minutes 10
    nice -n 10 .venv/bin/python benchmarks/soak/bench_soak.py --minutes 4 --sessions 4 \
        --take-s 15 --tracemalloc 6
"""

from __future__ import annotations

import argparse
import gc
import shutil
import sys
import tempfile
import threading
import time
import tracemalloc
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repo root: benchmarks.common

import numpy as np
import psutil

import bt_teleop.library.listing
import bt_teleop.library.loader
from benchmarks.common.soak_control import ControlLoops
from benchmarks.common.soak_drive import drive
from benchmarks.common.soak_late import AppEvents, StealSampler, write_log
from benchmarks.common.soak_late import report as late_report
from benchmarks.common.soak_memory import Sampler
from benchmarks.common.soak_tabs import TabsProcess
from bt_pipeline.data.tasks import parse_guided_task
from bt_pipeline.exceptions import BtError
from bt_teleop.app import AppOptions, TeleopApp, freeze_startup_objects
from bt_teleop.clean.runner import task_dir
from bt_teleop.session.config import SessionConfig
from bt_teleop.session.late_ticks import GcLog
from bt_teleop.session.process import SessionProcess
from bt_teleop.session.tick_stats import TickReport
from bt_teleop.testing.harness import (
    app_factory,
    reachable,
    tab_factory,
    wait_until,
)
from bt_teleop.ui.tab import ClientUI

REFUSALS = ("Not done", "Error")
"""Titles of the notices a tab shows when an action fails."""


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


def gc_summary(log: GcLog) -> str:
    """The garbage collector's pauses in this process, by generation."""
    parts = []
    for generation in (0, 1, 2):
        d = np.array([b - a for g, a, b in log.entries if g == generation]) * 1e3
        top = f", max {d.max():.1f} ms" if d.size else ""
        parts.append(f"gen{generation} {d.size}× (total {d.sum() / 1e3:.2f} s{top})")
    return "; ".join(parts)


def tree_cpu_s(uis: list[ClientUI]) -> float:
    """CPU time [s] of the app process and its tabs' session processes so far."""
    total = psutil.Process().cpu_times()
    seconds = total.user + total.system
    for ui in uis:
        pid = getattr(ui.session, "pid", None)
        if pid is not None:
            try:
                times = psutil.Process(pid).cpu_times()
            except psutil.Error:
                continue
            seconds += times.user + times.system
    return seconds


def session_heaps(uis: list[ClientUI]) -> list[tuple[int, Any]]:
    """(pid, C heap) of each tab's session child (none with the sessions in process)."""
    return [
        (session.pid, session.process_info("heap_info"))
        for session in (ui.session for ui in uis)
        if isinstance(session, SessionProcess) and session.pid is not None
    ]


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


def empty_library(
    recordings_dir: Any, task: str, **_: Any
) -> bt_teleop.library.listing.TaskLibrary:
    """``--library-loads none``: the task's library as if it had no demos (nothing is read)."""
    return bt_teleop.library.listing.TaskLibrary(parse_guided_task(task), (), ())


def read_new_files(
    recordings_dir: Any, task: str, read: Any = None, **_: Any
) -> bt_teleop.library.listing.TaskLibrary:
    """``--library-loads read-new``: every file of the task through the loader's `read` (so
    each new file is read and scored once, as the app does), then an empty library (nothing
    listed, scored over the task, or shown)."""
    folder = task_dir(recordings_dir, parse_guided_task(task))
    for path in bt_teleop.library.listing.task_files(folder) if folder.is_dir() else []:
        try:
            read(path, "raw")
        except BtError:
            continue
    return empty_library(recordings_dir, task)


def archive_oldest(folder: Path, keep: int, archive: Path) -> int:
    """Move all but the `keep` newest takes of `folder` to `archive`, as a lab moves old takes
    out of the recordings folder (so the takes on disk stay bounded); how many were moved."""
    takes = sorted(folder.glob("*.hdf5"), key=lambda p: p.stat().st_mtime_ns)
    archive.mkdir(exist_ok=True)
    for take in takes[: max(len(takes) - keep, 0)]:
        take.rename(archive / take.name)
    return max(len(takes) - keep, 0)


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
        "--take-s",
        type=float,
        default=4.0,
        help="takes last U(take_s, 2 take_s) s of wall time (2.0 before 2026-12-03)",
    )
    parser.add_argument(
        "--path",
        choices=("guide", "circle"),
        default="guide",
        help="what the target follows: the guide, one loop in 4 s (takes pass the checks), or a "
        "circle (every take flagged incomplete: the soak before 2026-12-03)",
    )
    parser.add_argument(
        "--discard",
        action="store_true",
        help="press Discard instead of Stop & save (the same work without the files: a control)",
    )
    parser.add_argument(
        "--trim-heap-every-s",
        type=float,
        default=AppOptions().trim_heap_every_s,
        help="the app's malloc_trim period [s] (inf: never)",
    )
    parser.add_argument(
        "--memory-log", type=Path, help="append each memory sample to this file (JSON lines)"
    )
    parser.add_argument(
        "--in-process",
        action="store_true",
        help="the sessions in the app's process (the app's --no-session-processes): a baseline",
    )
    parser.add_argument(
        "--priority-boost",
        type=int,
        default=SessionConfig().priority_boost,
        help="lower the control loops' nice value by this much (0: as the app's threads)",
    )
    parser.add_argument(
        "--library-loads",
        choices=("full", "none", "read-new"),
        default="full",
        help="what the tabs' library loads do: full (the app's), none (list nothing: no file "
        "read, scored or listed; empty tables and pickers) or read-new (read and score each "
        "new file as the app does, list nothing); the takes are saved as usual: controls",
    )
    parser.add_argument(
        "--late-ms", type=float, default=50.0, help="attribute ticks this late [ms] and more"
    )
    parser.add_argument(
        "--realtime-priority",
        type=int,
        default=SessionConfig().realtime_priority,
        help="run the control loops under SCHED_RR at this priority (0: off)",
    )
    parser.add_argument("--late-log", type=Path, help="append each late tick as a JSON line")
    parser.add_argument(
        "--keep-takes",
        type=int,
        default=0,
        help="every second, move all but this many newest takes out of the recordings folder "
        "(0: keep all): the takes on disk, the library's listing and each Clean job stay "
        "bounded, a control that tells growth with the data from growth with time",
    )
    parser.add_argument(
        "--control-loops",
        type=int,
        default=2,
        help="control loops beside the sessions: processes that only wake up every period, at "
        "the control loops' priority (soak_control.py); a late tick they share is the machine's",
    )
    parser.add_argument(
        "--tabs-in-app",
        action="store_true",
        help="the tabs' websocket clients as threads of the app's process (as before "
        "2026-12-03; by default they run in a process of their own, soak_tabs.py)",
    )
    args = parser.parse_args()
    process = psutil.Process()
    loads, events = Timed(), AppEvents()
    load = {
        "full": bt_teleop.library.listing.load_library,
        "none": empty_library,
        "read-new": read_new_files,
    }[args.library_loads]
    bt_teleop.library.loader.load_library = loads.wrap(events.wrap("library load", load))
    tmp = tempfile.mkdtemp(prefix="bt-soak-")
    session_config = SessionConfig(
        priority_boost=args.priority_boost,
        late_tick_s=args.late_ms / 1e3,
        realtime_priority=args.realtime_priority,
    )
    # The machine's yardsticks start before the first session: a late tick while the tabs
    # connect is then attributed too (before 2026-12-04 it counted as bt's own).
    steal = StealSampler()
    control = ControlLoops(
        args.control_loops,
        1.0 / session_config.control_hz,
        args.late_ms / 1e3,
        args.priority_boost,
        args.realtime_priority,
    )
    with app_factory(Path(tmp) / "rec") as make, tab_factory() as open_tab:
        # The drivers act through the app's handles, not the websocket, so every tab looks
        # silent: idle closing (tests/teleop/ui/test_connections.py) would end them at the
        # 10-min mark.
        app: TeleopApp = make(
            max_sessions=args.sessions,
            clean_epochs=5,
            idle_timeout_s=float("inf"),
            session_processes=not args.in_process,
            trim_heap_every_s=args.trim_heap_every_s,
            session=session_config,
        )
        app.heap_trimmer._trim = events.wrap("heap trim", app.heap_trimmer._trim)
        app.cleaner.start = events.wrap("clean job start", app.cleaner.start)  # spawns it
        app.cleaner._finished = events.wrap("clean job end", app.cleaner._finished)
        freeze_startup_objects()  # as `bt teleop` (app.serve) does once the app is up
        tabs = [
            open_tab(app, decode=False) for _ in range(args.sessions if args.tabs_in_app else 0)
        ]
        tab_process = None if args.tabs_in_app else TabsProcess(app.port, args.sessions)
        uis = list(app.wait_for_sessions(args.sessions, 120.0).values())
        refusals = [Refusals(ui) for ui in uis]
        time.sleep(2.0)
        sampler = Sampler(
            args.sample_every,
            lambda: session_heaps(uis),
            args.memory_log,
            reader_pid=lambda: app.reader.pid if app.reader is not None else None,
        )
        pauses = GcLog(maxlen=None)
        cpu_start, app_cpu_start = tree_cpu_s(uis), process.cpu_times()
        wall_start = time.monotonic()
        stop = threading.Event()
        counts = [{"intended": 0} for _ in uis]
        drivers = [
            threading.Thread(
                target=drive,
                args=(ui, stop, k, counts[k], args.take_s, args.discard, args.path),
                daemon=True,
            )
            for k, ui in enumerate(uis)
        ]
        for thread in drivers:
            thread.start()
        end = time.monotonic() + 60.0 * args.minutes
        next_clean = time.monotonic() + args.clean_every if args.clean_every else None
        cleans = archived = 0
        task_folder = Path(tmp) / "rec" / "wiping"
        trace_at = time.monotonic() + 20.0 * args.minutes  # a third of the run
        while time.monotonic() < end:
            time.sleep(1.0)
            if args.keep_takes:
                archived += archive_oldest(task_folder, args.keep_takes, Path(tmp) / "archive")
            if args.tracemalloc and not tracemalloc.is_tracing() and time.monotonic() >= trace_at:
                gc.collect()
                tracemalloc.start(args.tracemalloc)
            if next_clean is not None and time.monotonic() >= next_clean:
                uis[cleans % len(uis)].controls.clean_button.value = True
                events.mark("clean press")
                cleans += 1
                next_clean += args.clean_every
        stop.set()
        for thread in drivers:
            thread.join(60.0)
        wait_until(app.settled, 60.0, "tabs to settle")
        for ui in uis:
            ui.wait_idle(120.0)  # the last Stop & save may still be queued
        refused = [body for counted in refusals for body in counted.bodies]
        recoveries = [r for ui in uis for r in getattr(ui.session, "recoveries", [])]
        lost = [r.reason for r in recoveries]  # a tab replaces a lost child at once
        lost += [why for ui in uis if (why := getattr(ui.session, "lost", None))]
        # The last memory sample before the tick reports are read: a report (two histograms
        # and the late ticks, pickled in the child) left ~1.2 MiB more in each child.
        sampler.stop()
        ticks = TickReport.merged(  # before they close; a lost child has none to give
            [ui.session.tick_stats() for ui in uis if not getattr(ui.session, "lost", None)]
        )
        cpu_end, app_cpu_end = tree_cpu_s(uis), process.cpu_times()
        steal.stop()
        machine = control.close()
        growth_text = ""
        if tracemalloc.is_tracing():
            gc.collect()
            growth_text = top_growth(tracemalloc.take_snapshot())
            tracemalloc.stop()
        wall = time.monotonic() - wall_start
        received = sum(tab.bytes for tab in tabs)
        saved_ui = sum(ui.takes.saved_count for ui in uis)
        files = len(list(task_folder.glob("*.hdf5"))) + archived
        held = held_by_loader(app, uis)
        # Closed after the takes are counted: a tab closed mid-take saves it (flagged)
        received += tab_process.close() if tab_process is not None else 0
    period = ticks.period_s
    intended = sum(c["intended"] for c in counts)
    where = "in the app's process" if args.in_process else "one child process per session"
    print(f"{args.sessions} sessions ({where}) for {args.minutes:g} min, {cleans} Clean presses")
    print(
        f"control ticks: {ticks.n_ticks} ({ticks.n_ticks / wall:.0f}/s of "
        f"{args.sessions / period:.0f}/s intended), period {1e3 * period:.1f} ms"
    )
    print(
        f"control threads' nice value: {ticks.nice} (priority boost {args.priority_boost}); "
        f"real-time (SCHED_RR {args.realtime_priority}): {ticks.realtime}"
    )
    print(f"largest stall: {1e3 * ticks.largest_stall_s:.1f} ms beyond the period")
    p50, p99, p999 = (1e3 * ticks.gap_percentile(q) for q in (50, 99, 99.9))
    print(
        f"gap p50: {p50:.1f} ms, p99: {p99:.1f} ms, p99.9: {p999:.1f} ms, "
        f"max {1e3 * ticks.max_gap_s:.0f} ms (0.1 ms bins)"
    )
    print(f"stalls > 50 ms: {ticks.gaps_above(period + 0.05)}")
    c50, c99 = (1e3 * ticks.compute_percentile(q) for q in (50, 99))
    print(
        f"tick compute: p50 {c50:.2f} ms, p99 {c99:.2f} ms, max {1e3 * ticks.max_compute_s:.0f} ms"
    )
    print(
        late_report(ticks.late, events, args.late_ms / 1e3, shown=15, steal=steal, control=machine)
    )
    if args.late_log:
        write_log(args.late_log, ticks.late, events, steal, machine)
    print(f"gc pauses (the app's process): {gc_summary(pauses)}")
    trimmer = app.heap_trimmer
    print(
        f"heap trims (every {trimmer.every_s:g} s): {trimmer.calls}, "
        f"{1e3 * trimmer.seconds / max(trimmer.calls, 1):.1f} ms each on average"
    )
    print(f"task-library loads (after saves): {loads.summary()}")
    app_used = app_cpu_end.user + app_cpu_end.system - app_cpu_start.user - app_cpu_start.system
    print(
        f"CPU of the app and its sessions: {(cpu_end - cpu_start) / wall:.2f} cores of "
        f"{psutil.cpu_count()} (the app's process alone: {app_used / wall:.2f})"
    )
    rows = np.asarray(sampler.rows)
    print(
        f"load average (1 min): min {rows[:, 2].min():.1f}, mean {rows[:, 2].mean():.1f}, "
        f"max {rows[:, 2].max():.1f}"
    )
    for column in (1, 4, 5, 6, 7, 8):
        print(
            f"memory ({Sampler.COLUMNS[column]}): {rows[0, column]:.0f} MiB at start, "
            f"{rows[-1, column]:.0f} MiB at end, slope over the second half "
            f"{sampler.slope_second_half(column):+.2f} MiB/min"
        )
    print(
        "  t [s]  app RSS, tree PSS, kept PSS, kept anon PSS [MiB]  load: "
        + "; ".join(
            f"{r[0]:.0f} {r[1]:.0f} {r[5]:.0f} {r[7]:.0f} {r[8]:.0f} {r[2]:.1f}" for r in rows
        )
    )
    if np.isfinite(rows[:, 3]).any():
        print(
            f"Python memory tracemalloc sees: slope over the second half "
            f"{sampler.slope_second_half(3):+.2f} MiB/min; t [s] MiB: "
            + "; ".join(f"{r[0]:.0f} {r[3]:.1f}" for r in rows if np.isfinite(r[3]))
        )
    print(sampler.kind_report())
    growth = rows[-1, 8] - rows[0, 8]
    print(
        f"kept anon PSS growth per saved take: {1024 * growth / max(saved_ui, 1):.0f} KiB; {held}"
    )
    print(
        f"takes: {intended} intended, {saved_ui} saved by the tabs, {files} files on disk"
        + (f" ({archived} of them moved out: --keep-takes {args.keep_takes})" if archived else "")
    )
    print(
        f"session children lost: {len(lost)} ({len(recoveries)} replaced; takes in progress "
        f"lost: {sum(r.take_lost for r in recoveries)}, "
        f"saved: {sum(len(r.saved) for r in recoveries)})" + "".join(f"\n  {why}" for why in lost)
    )
    print(f"refused actions: {len(refused)}" + "".join(f"\n  {body}" for body in refused[:10]))
    print(f"bytes sent to the tabs: {received / 2**20:.0f} MiB")
    if growth_text:
        print(growth_text)
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
