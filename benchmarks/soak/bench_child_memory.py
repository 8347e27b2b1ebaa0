"""What a session keeps per saved take: a session child's memory over N takes back to back.

Issue 10's soak (8 tabs, 10 minutes) saw the session children grow +1.04 MiB/min together
while saving ~125 takes a minute (docs/security.md). This measures one session directly,
without the app, the tabs or clean jobs: it records and saves ``--takes`` takes of
U(``--take-s``, 2 ``--take-s``) seconds back to back (as bench_soak.py's tabs do) while this
process plays a tab (``status()`` and a target on a circle 30 times a second, ``trail()`` 10
times a second), and samples at each of ``--at`` takes:

* the session process's ``/proc/<pid>/smaps_rollup``: RSS, PSS, the PSS of anonymous
  memory, its private pages (USS) and its dirty pages shared with other processes: a page of
  the forkserver's that a child writes to (a reference count, an allocator's free list) moves
  from shared to private (copy on write);
* its C heap (``mallinfo2``: bytes in use, free but kept, the arenas' size, large blocks
  mmapped one by one), what HDF5's free lists hold, and the number of memory blocks Python's
  allocator has handed out (``sys.getallocatedblocks``), asked over the pipe;

in three arms: ``child``, a session in a child process as the app makes it
(:class:`bt_teleop.session.process.SessionProcess`, which releases free memory after each
take); ``child-keep``, the same without that release (``release_memory_after_take=False``,
the code before); ``in-process``, the baseline: the same session in this process
(:class:`bt_teleop.session.tick_stats.TimedSession`; this process's memory). Growth is per take,
from the sample after ``--warmup`` takes; medians over ``--runs`` runs (run r draws its take
lengths from seed + r, the same in every arm). Also the wall time of a save and of the
``status()`` right after it.

    nice -n 10 .venv/bin/python benchmarks/soak/bench_child_memory.py --takes 500 --runs 3
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import dataclass, fields
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repo root: benchmarks.common

import numpy as np

from benchmarks.common.procfs import KIB, smaps_rollup
from bt_teleop.proc.native_memory import hdf5_free_lists, heap_info
from bt_teleop.session.config import SessionConfig
from bt_teleop.session.process import SessionProcess, TabSession
from bt_teleop.session.tick_stats import TimedSession
from bt_teleop.sim.scene import SceneModel, load_scene
from bt_teleop.testing.harness import circle_uv

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


def sample(session: TabSession) -> Sample:
    """`session`'s memory now: its child's, or this process's for an in-process session."""
    if isinstance(session, SessionProcess):
        assert session.pid is not None
        pid, heap, blocks = (
            session.pid,
            session.process_info("heap_info"),
            session.process_info("allocated_blocks"),
        )
        lists = session.process_info("hdf5_free_lists")
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
    session: TabSession,
    scene: SceneModel,
    take_s: float,
    t0: float,
    discard: bool = False,
) -> tuple[float, float]:
    """Record a take of `take_s` seconds as a tab drives it, and save it (or discard it); the
    wall time of the save and of the first ``status()`` after it [s] (a child releases memory
    after replying to the save, so that call waits for it)."""
    session.start_recording("bench")
    end, frame = time.perf_counter() + take_s, 0
    while time.perf_counter() < end:
        session.set_target(scene.plane.to_world(circle_uv(time.perf_counter() - t0)))
        session.status()
        if frame % 3 == 0:
            session.trail()
        frame += 1
        time.sleep(1.0 / 30.0)
    start = time.perf_counter()
    if discard:
        session.discard()
    else:
        session.stop_and_check()
    saved = time.perf_counter()
    session.status()
    return saved - start, time.perf_counter() - saved


@dataclass
class Run:
    """One arm's run: growth per take at each checkpoint, and the call times [s]."""

    growth: dict[int, Sample]
    saves_s: list[float]
    next_status_s: list[float]


def run(
    where: str,
    scene: SceneModel,
    takes: int,
    at: list[int],
    warmup: int,
    take_s: float,
    seed: int,
    discard: bool = False,
) -> Run:
    """`takes` takes of U(`take_s`, 2 `take_s`) seconds (as bench_soak.py's tabs; the lengths
    drawn from `seed`), after `warmup` more; growth per take from the sample after those."""
    rng = np.random.default_rng(seed)
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
            one_take(session, scene, float(rng.uniform(take_s, 2 * take_s)), t0, discard)
        base = sample(session)
        out = Run({}, [], [])
        for k in range(1, takes + 1):
            save_s, status_s = one_take(
                session, scene, float(rng.uniform(take_s, 2 * take_s)), t0, discard
            )
            out.saves_s.append(save_s)
            out.next_status_s.append(status_s)
            if k in at:
                now = sample(session)
                out.growth[k] = Sample(
                    *((getattr(now, f.name) - getattr(base, f.name)) / k for f in fields(Sample))
                )
                print(f"  {where} {k} takes: {describe(out.growth[k])}", flush=True)
        session.close()
    return out


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
    parser.add_argument(
        "--take-s", type=float, default=0.5, help="takes last U(take_s, 2 take_s) s of wall time"
    )
    parser.add_argument("--seed", type=int, default=0, help="of the take lengths (run r: +r)")
    parser.add_argument("--discard", action="store_true", help="discard the takes, save none")
    parser.add_argument("--where", nargs="*", choices=WHERE, default=list(WHERE))
    args = parser.parse_args()
    at = sorted({k for k in args.at if k <= args.takes} | {args.takes})
    scene = load_scene("wiping")
    print(f"load average at start: {os.getloadavg()[0]:.2f}; {time.strftime('%H:%M')}")
    results: dict[str, list[Run]] = {}
    for r in range(args.runs):
        for where in args.where:
            results.setdefault(where, []).append(
                run(
                    where,
                    scene,
                    args.takes,
                    at,
                    args.warmup,
                    args.take_s,
                    args.seed + r,
                    args.discard,
                )
            )
        print(f"run {r + 1} done, load average {os.getloadavg()[0]:.2f}", flush=True)
    print(f"growth per take after {args.warmup} warm-up takes [KiB a take], medians of the runs:")
    for where, runs in results.items():
        for k in at:
            median = Sample(
                *(
                    float(np.median([getattr(one.growth[k], f.name) for one in runs]))
                    for f in fields(Sample)
                )
            )
            print(f"{where}, {k} takes: {describe(median)}")
        saves = 1e3 * np.concatenate([one.saves_s for one in runs])
        after = 1e3 * np.concatenate([one.next_status_s for one in runs])
        print(
            f"{where}: a save {np.median(saves):.1f} ms (p99 {np.percentile(saves, 99):.1f}); the "
            f"status() after it {np.median(after):.2f} ms (p99 {np.percentile(after, 99):.2f})"
        )
    print(f"load average at end: {os.getloadavg()[0]:.2f}; {time.strftime('%H:%M')}")


if __name__ == "__main__":
    main()
