"""Memory of a teleop app's process tree over a soak run, by process kind (bench_soak.py).

Every ``every_s`` seconds, for each kind of process (the app, the forkserver, the tabs'
session children, clean jobs, others such as multiprocessing's resource tracker):

* RSS, PSS (pages shared by forked children split among them) and USS (pages only that
  process maps), summed over the processes of the kind;
* PSS by kind of mapping, from ``/proc/<pid>/smaps``: ``[heap]`` (glibc's main arena, grown by
  brk), anonymous mappings (the threads' malloc arenas, large mmapped blocks, Python's obmalloc
  arenas, thread stacks) and file-backed mappings (code, data of shared libraries);
* the C heap as glibc's ``mallinfo2`` sees it (:mod:`bt_teleop.proc.native_memory`): bytes in use
  and bytes free but kept (fragmentation), for the app (in process) and the session children
  (asked over their pipe);
* for the app, Python's small-object allocator (``sys._debugmallocstats``): the memory of its
  arenas against the bytes of the blocks allocated in them (the rest is its fragmentation).

A kind whose PSS grows while its C heap's ``in_use`` stays flat and ``free`` grows is
fragmenting; ``in_use`` growing is memory some native library holds.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import math
import os
import re
import sys
import tempfile
import threading
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import psutil

from bt_teleop.proc.native_memory import HeapInfo, heap_info

KINDS = ("app", "forkserver", "session", "reader", "clean", "other")
"""Kinds of the app's process tree (the benchmark's tab process, ``soak_tabs.py``, and its
control loops, ``soak_control.py``, are not)."""
FIELDS = (
    *("rss", "pss", "uss", "pss_heap", "pss_anon", "pss_file", "heap_in_use", "heap_free"),
    "heap_mmapped",
    *("py_arenas", "py_blocks"),
)
MIB = 2**20


def kind_of(
    process: psutil.Process, app_pid: int, session_pids: set[int], reader_pid: int | None = None
) -> str:
    """Which kind of the app's tree `process` is."""
    if process.pid == app_pid:
        return "app"
    if process.pid in session_pids:
        return "session"
    if (
        process.pid == reader_pid
    ):  # the library's reader child (bt_teleop/library/reader_process.py)
        return "reader"
    command = " ".join(process.cmdline())
    if "soak_tabs.py" in command:  # the benchmark's browsers, not the app
        return "tabs"
    if "soak_control.py" in command:  # the benchmark's control loops, not the app
        return "control"
    if "multiprocessing.forkserver" in command:
        return "forkserver"
    if "multiprocessing.spawn" in command:
        return "clean"
    return "other"


def pymalloc_mib() -> tuple[float, float]:
    """(arenas, allocated blocks) [MiB] of Python's small-object allocator in this process,
    parsed from ``sys._debugmallocstats`` (which writes to the C stderr: redirected meanwhile,
    so another thread's stderr line may be lost)."""
    with tempfile.TemporaryFile("w+") as out:
        saved = os.dup(2)
        try:
            os.dup2(out.fileno(), 2)
            sys._debugmallocstats()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        out.seek(0)
        text = out.read()
    arenas = re.search(r"(\d+) arenas \* (\d+) bytes/arena", text)
    blocks = re.search(r"# bytes in allocated blocks\s+=\s+([\d,]+)", text)
    if arenas is None or blocks is None:
        return (math.nan, math.nan)
    total = int(arenas.group(1)) * int(arenas.group(2))
    return (total / MIB, int(blocks.group(1).replace(",", "")) / MIB)


def smaps_pss(pid: int) -> dict[str, float]:
    """PSS [MiB] of a process by kind of mapping: heap, anon, file (others: stack, vdso ...)."""
    totals = {"pss_heap": 0.0, "pss_anon": 0.0, "pss_file": 0.0}
    key = "pss_anon"
    with open(f"/proc/{pid}/smaps") as lines:
        for line in lines:
            field, _, rest = line.partition(" ")
            if not field.endswith(":"):  # a mapping's header: address perms offset dev inode path
                parts = line.split(None, 5)
                path = parts[5].strip() if len(parts) > 5 else ""
                key = (
                    "pss_heap"
                    if path == "[heap]"
                    else "pss_anon"
                    if not path
                    else ""
                    if path.startswith("[")
                    else "pss_file"
                )
            elif field == "Pss:" and key:
                totals[key] += int(rest.split()[0]) / 1024.0
    return totals


class Sampler:
    """Memory of the app's process tree [MiB], the 1-minute load average and, while tracemalloc
    traces, the Python memory it sees [MiB] (NaN otherwise), every `every_s` seconds, in a
    thread. Columns of :attr:`rows`: t [s], the app's RSS, load, traced, and over the app and
    every process under it: the sums of RSS, PSS and USS, and the PSS of the processes that
    stay (the tree without clean jobs, which come and go), and of their anonymous mappings
    only (heap and anon): the memory that must stay flat. The kept PSS of file-backed mappings
    (the shared libraries' pages) jumps by 10-25 MiB whenever a clean job maps the same
    libraries or ends (their pages are then split among more or fewer processes), so the kept
    PSS's slope over a few minutes says more about when clean jobs ran than about growth.
    :attr:`by_kind` holds, per sample, :data:`FIELDS` summed per kind of process (module doc).

    Args:
        every_s: Sampling period [s].
        session_heaps: Returns (pid, C heap) of each session child (None: not asked).
        log: A file to append each sample to as a JSON line as it is taken (None: none).
    """

    COLUMNS = (
        *("t", "app RSS", "load", "traced", "tree RSS", "tree PSS", "tree USS", "kept PSS"),
        "kept anon PSS",
    )

    def __init__(
        self,
        every_s: float,
        session_heaps: Callable[[], list[tuple[int, HeapInfo | None]]] | None = None,
        log: Path | None = None,
        reader_pid: Callable[[], int | None] | None = None,
    ) -> None:
        self.rows: list[tuple[float, ...]] = []
        self.by_kind: list[dict[str, dict[str, float]]] = []
        self._session_heaps = session_heaps
        self._log = log
        self._reader_pid = reader_pid or (lambda: None)
        self._process = psutil.Process()
        self._t0 = time.monotonic()
        self._stop = threading.Event()
        self.sample()
        self._thread = threading.Thread(target=self._run, args=(every_s,), daemon=True)
        self._thread.start()

    def sample(self) -> None:
        heaps: dict[int, HeapInfo | None] = {os.getpid(): heap_info()}
        if self._session_heaps is not None:
            with contextlib.suppress(Exception):  # a session closing: skip its heap this time
                heaps.update(self._session_heaps())
        t = time.monotonic() - self._t0
        rss = self._process.memory_info().rss / MIB
        traced = tracemalloc.get_traced_memory()[0] / MIB if tracemalloc.is_tracing() else np.nan
        kinds: dict[str, dict[str, float]] = {
            kind: dict.fromkeys(("n", *FIELDS), 0.0) for kind in KINDS
        }
        reader = self._reader_pid()
        for process in [self._process, *self._process.children(recursive=True)]:
            try:
                kind = kind_of(process, self._process.pid, set(heaps) - {os.getpid()}, reader)
                if kind not in kinds:  # not the app's
                    continue
                full = process.memory_full_info()
                mapped = smaps_pss(process.pid)
            except (psutil.Error, OSError):  # ended meanwhile (a clean job)
                continue
            row = kinds[kind]
            row["n"] += 1
            for name, value in (("rss", full.rss), ("pss", full.pss), ("uss", full.uss)):
                row[name] += value / MIB
            for name, value in mapped.items():
                row[name] += value
            if kind == "app":
                row["py_arenas"], row["py_blocks"] = pymalloc_mib()
            heap = heaps.get(process.pid)
            if heap is not None:
                row["heap_in_use"] += heap.in_use / MIB
                row["heap_free"] += heap.free / MIB
                row["heap_mmapped"] += heap.mmapped / MIB
        tree = [sum(kinds[k][name] for k in KINDS) for name in ("rss", "pss", "uss")]
        kept = tree[1] - kinds["clean"]["pss"]
        kept_anon = sum(kinds[k]["pss_heap"] + kinds[k]["pss_anon"] for k in KINDS if k != "clean")
        self.rows.append((t, rss, os.getloadavg()[0], traced, *tree, kept, kept_anon))
        self.by_kind.append(kinds)
        if self._log is not None:
            with self._log.open("a") as out:
                out.write(json.dumps({"t": t, "load": os.getloadavg()[0], **kinds}) + "\n")

    def _run(self, every_s: float) -> None:
        while not self._stop.wait(every_s):
            self.sample()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(30.0)
        self.sample()

    def slope_second_half(self, column: int = 1) -> float:
        """Least-squares slope of a column (default the app's RSS) over the second half of the
        run [MiB/min]."""
        rows = np.asarray(self.rows)
        return slope(rows[:, 0], rows[:, column], rows[-1, 0] / 2.0, rows[-1, 0])

    def kind_report(self) -> str:
        """Per kind and field: start → end, and the slope over each quarter of the run
        [MiB/min] (a slope that falls quarter by quarter is levelling off)."""
        t = np.asarray(self.rows)[:, 0]
        edges = np.linspace(0.0, t[-1], 5)
        lines = ["memory by process kind [MiB]: start → end; slope per quarter [MiB/min]"]
        for kind in KINDS:
            count = max(row[kind]["n"] for row in self.by_kind)
            if not count:
                continue
            lines.append(f"  {kind} ({count:.0f} processes at most):")
            for name in FIELDS:
                values = np.asarray([row[kind][name] for row in self.by_kind])
                if not values.any():
                    continue
                quarters = [slope(t, values, a, b) for a, b in itertools.pairwise(edges)]
                lines.append(
                    f"    {name:12s} {values[0]:7.1f} → {values[-1]:7.1f}; "
                    + " ".join(f"{q:+6.2f}" for q in quarters)
                    + f"; second half {slope(t, values, t[-1] / 2.0, t[-1]):+.2f}"
                )
        return "\n".join(lines)


def slope(t: Any, values: Any, start: float, end: float) -> float:
    """Least-squares slope [MiB/min] of `values` over the samples with start ≤ t ≤ end."""
    t, values = np.asarray(t, dtype=float), np.asarray(values, dtype=float)
    keep = (t >= start) & (t <= end) & np.isfinite(values)
    if keep.sum() < 2:
        return float("nan")
    return float(np.polyfit(t[keep] / 60.0, values[keep], 1)[0])
