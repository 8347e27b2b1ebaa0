"""What a session keeps per saved take: a session child's memory over N takes back to back.

Issue 10's soak (8 tabs, 10 minutes) saw the session children grow +1.04 MiB/min together
while saving ~125 takes a minute (docs/security.md). This measures one session directly,
without the app, the tabs or clean jobs: it records and saves ``--takes`` takes of
``--take-s`` seconds back to back while this process plays a tab (``status()`` and a target
on a circle 30 times a second, ``trail()`` 10 times a second), and samples at each of
``--at`` takes:

* the child's ``/proc/<pid>/smaps_rollup``: RSS, PSS, the PSS of anonymous memory, and its
  private (USS) and shared dirty pages: a page of the forkserver's that the child writes to
  (a reference count, an allocator's free list) moves from shared to private (copy on write);
* its C heap (``mallinfo2``: bytes in use, free but kept, the arenas' size, large blocks
  mmapped one by one) and the number of
  memory blocks Python's allocator has handed out (``sys.getallocatedblocks``), both asked
  over the pipe;

for the session in a child (:class:`bt_teleop.session_process.SessionProcess`) and, as the
baseline, the same session in this process (:class:`bt_teleop.tick_stats.TimedSession`,
this process's memory). Growth is per take, from the sample after ``--warmup`` takes;
medians over ``--runs`` runs.

    nice -n 10 .venv/bin/python benchmarks/bench_child_memory.py --takes 500 --runs 3
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import dataclass, fields

import numpy as np

from bt_teleop.native_memory import hdf5_free_lists, heap_info
from bt_teleop.scene import SceneModel, load_scene
from bt_teleop.session_config import SessionConfig
from bt_teleop.session_process import SessionProcess, TabSession
from bt_teleop.testing import circle_uv
from bt_teleop.tick_stats import TimedSession

KIB = 1024.0
WHERE = ("child", "child-keep", "in-process")
"""The arms: a child as the app makes it; a child that keeps what each take freed
(``SessionConfig(release_memory_after_take=False)``, the code before); the baseline."""


@dataclass(frozen=True)
class Sample:
    """A session's memory after some takes [bytes; blocks: a count]."""

    rss: float
    pss: float
    pss_anon: float
    uss: float
    """Private pages (``Private_Clean`` + ``Private_Dirty``)."""
    shared_dirty: float
    """Dirty pages shared with another process (the forkserver's, for a child)."""
    c_in_use: float
    c_free: float
    c_arena: float
    c_mmapped: float
    hdf5_lists: float
    """What HDF5's free lists hold (all four kinds)."""
    blocks: float


def smaps_rollup(pid: int) -> dict[str, float]:
    """``/proc/<pid>/smaps_rollup`` [bytes] by field (Rss, Pss, Pss_Anon, ...)."""
    out: dict[str, float] = {}
    with open(f"/proc/{pid}/smaps_rollup") as lines:
        for line in lines:
            parts = line.split()
            if len(parts) == 3 and parts[0].endswith(":") and parts[2] == "kB":
                out[parts[0][:-1]] = KIB * int(parts[1])
    return out


def sample(session: TabSession) -> Sample:
    """`session`'s memory now: its child's, or this process's for an in-process session."""
    if isinstance(session, SessionProcess):
        assert session.pid is not None
        pid, heap, blocks = session.pid, session.heap_info(), session.allocated_blocks()
        lists = session.hdf5_free_lists()
    else:
        pid, heap, blocks = os.getpid(), heap_info(), sys.getallocatedblocks()
        lists = hdf5_free_lists()
    smaps = smaps_rollup(pid)
    return Sample(
        smaps["Rss"],
        smaps["Pss"],
        smaps.get("Pss_Anon", float("nan")),
        smaps["Private_Clean"] + smaps["Private_Dirty"],
        smaps["Shared_Dirty"],
        float("nan") if heap is None else heap.in_use,
        float("nan") if heap is None else heap.free,
        float("nan") if heap is None else heap.arena,
        float("nan") if heap is None else heap.mmapped,
        float("nan") if lists is None else lists.total,
        blocks,
    )


def one_take(
    session: TabSession, scene: SceneModel, take_s: float, t0: float, discard: bool = False
) -> None:
    """Record a take of `take_s` seconds as a tab drives it, and save it (or discard it)."""
    session.start_recording("bench")
    end, frame = time.perf_counter() + take_s, 0
    while time.perf_counter() < end:
        session.set_target(scene.plane.to_world(circle_uv(time.perf_counter() - t0)))
        session.status()
        if frame % 3 == 0:
            session.trail()
        frame += 1
        time.sleep(1.0 / 30.0)
    if discard:
        session.discard()
    else:
        session.stop_and_check()


def run(
    where: str,
    scene: SceneModel,
    takes: int,
    at: list[int],
    warmup: int,
    take_s: float,
    discard: bool = False,
) -> dict[int, Sample]:
    """Growth per take [bytes per take; blocks per take] at each of `at` takes, from the sample
    after `warmup` takes."""
    with tempfile.TemporaryDirectory(prefix="bt-childmem-") as tmp:
        session: TabSession = (
            TimedSession(scene, tmp)
            if where == "in-process"
            else SessionProcess(
                scene, tmp, config=SessionConfig(release_memory_after_take=where == "child")
            )
        )
        session.start()
        t0 = time.perf_counter()
        for _ in range(warmup):
            one_take(session, scene, take_s, t0, discard)
        base = sample(session)
        growth: dict[int, Sample] = {}
        for k in range(1, takes + 1):
            one_take(session, scene, take_s, t0, discard)
            if k in at:
                now = sample(session)
                growth[k] = Sample(
                    *((getattr(now, f.name) - getattr(base, f.name)) / k for f in fields(Sample))
                )
                print(f"  {where} {k} takes: {describe(growth[k])}", flush=True)
        session.close()
    return growth


def describe(per_take: Sample) -> str:
    """One line of per-take growth [KiB a take; blocks a take]."""
    return ", ".join(
        f"{f.name} {getattr(per_take, f.name):+.0f}"
        if f.name == "blocks"
        else f"{f.name} {getattr(per_take, f.name) / KIB:+.2f}"
        for f in fields(Sample)
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--takes", type=int, default=500)
    parser.add_argument("--at", type=int, nargs="*", default=[200, 500, 1000])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--warmup", type=int, default=20)
    parser.add_argument("--take-s", type=float, default=0.4, help="wall time of a take [s]")
    parser.add_argument("--discard", action="store_true", help="discard the takes, save none")
    parser.add_argument("--where", nargs="*", choices=WHERE, default=list(WHERE))
    args = parser.parse_args()
    at = sorted({k for k in args.at if k <= args.takes} | {args.takes})
    scene = load_scene("wiping")
    print(f"load average at start: {os.getloadavg()[0]:.2f}; {time.strftime('%H:%M')}")
    results: dict[str, list[dict[int, Sample]]] = {}
    for r in range(args.runs):
        for where in args.where:
            results.setdefault(where, []).append(
                run(where, scene, args.takes, at, args.warmup, args.take_s, args.discard)
            )
        print(f"run {r + 1} done, load average {os.getloadavg()[0]:.2f}", flush=True)
    print(f"growth per take after {args.warmup} warm-up takes [KiB a take], medians of the runs:")
    for where, runs in results.items():
        for k in at:
            median = Sample(
                *(
                    float(np.median([getattr(run[k], f.name) for run in runs]))
                    for f in fields(Sample)
                )
            )
            print(f"{where}, {k} takes: {describe(median)}")
    print(f"load average at end: {os.getloadavg()[0]:.2f}; {time.strftime('%H:%M')}")


if __name__ == "__main__":
    main()
