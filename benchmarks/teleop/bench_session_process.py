"""What a session in a child process costs the app: start time and call latency.

A tab asks its session for ``status()`` 30 times a second and sends a target with every gizmo
drag; in a child process (:class:`bt_teleop.session.process.SessionProcess`) each is a message
over a pipe. Measured on sessions running in real time, in this process:

* start: the first child (the forkserver starts and imports MuJoCo and mink), then the median
  of the next ones (forked from the preloaded server);
* memory of each child while ``--starts`` + 1 of them run (PSS and USS, psutil; the median
  child) and of the forkserver;
* ``status()``, ``trail()`` while recording, and a one-way ``set_target``: median and p99 of
  ``--calls`` calls per run, for a child and for the same session in this process (the
  baseline, :class:`bt_teleop.session.tick_stats.TimedSession`), over ``--runs`` runs (medians of
  the runs' medians), and their ratio;
* one child alone recording ``--takes`` takes of 2 s back to back, each saved (the save runs
  in the child, beside its control loop): its largest stall and gap percentiles
  (:mod:`bt_teleop.session.tick_stats`).

    nice -n 10 .venv/bin/python benchmarks/teleop/bench_session_process.py
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import psutil

from bt_teleop.session.process import SessionProcess
from bt_teleop.session.tick_stats import TimedSession
from bt_teleop.sim.scene import SceneModel, load_scene
from bt_teleop.testing.harness import circle_uv


def timed(call: Callable[[], Any], n: int) -> tuple[float, float]:
    """(median, p99) of `n` calls [ms]."""
    times = np.empty(n)
    for k in range(n):
        t0 = time.perf_counter()
        call()
        times[k] = time.perf_counter() - t0
        time.sleep(0.001)  # a tab does not call back to back
    return 1e3 * float(np.median(times)), 1e3 * float(np.percentile(times, 99))


def child_memory(sessions: list[SessionProcess]) -> str:
    """PSS and USS [MiB] of the median child and of the forkserver."""
    pss, uss = [], []
    for session in sessions:
        assert session.pid is not None
        full = psutil.Process(session.pid).memory_full_info()
        pss.append(full.pss / 2**20)
        uss.append(full.uss / 2**20)
    assert sessions[0].pid is not None
    server = psutil.Process(sessions[0].pid).parent()
    assert server is not None
    full = server.memory_full_info()
    return (
        f"{len(sessions)} children running: median PSS {np.median(pss):.0f} MiB, USS "
        f"{np.median(uss):.0f} MiB a child (RSS {full.rss / 2**20:.0f} MiB of the forkserver, "
        f"PSS {full.pss / 2**20:.0f}, USS {full.uss / 2**20:.0f})"
    )


def saving(scene: SceneModel, takes: int) -> str:
    """One child recording and saving 2 s takes back to back: its tick gaps."""
    with tempfile.TemporaryDirectory(prefix="bt-proc-") as tmp:
        session = SessionProcess(scene, tmp)
        session.start()
        t0, saves = time.perf_counter(), []
        for _ in range(takes):
            session.start_recording("bench")
            end = time.perf_counter() + 2.0
            while time.perf_counter() < end:
                session.set_target(scene.plane.to_world(circle_uv(time.perf_counter() - t0)))
                session.status()
                time.sleep(1.0 / 30.0)
            t_save = time.perf_counter()
            session.stop_and_check()
            saves.append(time.perf_counter() - t_save)
        report = session.tick_stats()
        session.close()
    p50, p99, p999 = (1e3 * report.gap_percentile(q) for q in (50, 99, 99.9))
    return (
        f"one child saving {takes} takes of 2 s: largest stall {1e3 * report.largest_stall_s:.1f}"
        f" ms; gaps p50 {p50:.1f}, p99 {p99:.1f}, p99.9 {p999:.1f} ms; a save "
        f"{1e3 * float(np.median(saves)):.0f} ms (median)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--calls", type=int, default=500)
    parser.add_argument("--starts", type=int, default=5, help="children started after the first")
    parser.add_argument("--takes", type=int, default=10, help="takes saved by one child")
    args = parser.parse_args()
    scene = load_scene("wiping")
    with tempfile.TemporaryDirectory(prefix="bt-proc-") as tmp:
        t0 = time.perf_counter()
        first = SessionProcess(scene, tmp)
        first_s = time.perf_counter() - t0
        starts, others = [], []
        for _ in range(args.starts):
            t0 = time.perf_counter()
            others.append(SessionProcess(scene, tmp))
            starts.append(time.perf_counter() - t0)
        for session in others:
            session.start()
        time.sleep(5.0)
        memory = child_memory([first, *others])
        for session in others:
            session.close()
        local = TimedSession(scene, tmp)
        target = scene.plane.to_world(np.array([0.03, 0.02]))
        rows: dict[str, list[tuple[float, float]]] = {}
        for session, where in ((first, "child"), (local, "in-process")):
            session.start()
            session.start_recording("bench")
            time.sleep(1.0)
            for _ in range(args.runs):
                for name, call in (
                    ("status()", session.status),
                    ("trail() (recording)", session.trail),
                    ("set_target", lambda s=session: s.set_target(target)),
                ):
                    rows.setdefault(f"{name} {where}", []).append(timed(call, args.calls))
            session.discard()
            session.close()
    print(f"first child: {first_s:.2f} s; later children: median {np.median(starts):.3f} s")
    print(memory)
    print(saving(scene, args.takes))
    for name in ("status()", "trail() (recording)", "set_target"):
        child = np.median(np.asarray(rows[f"{name} child"]), axis=0)
        local_ms = np.median(np.asarray(rows[f"{name} in-process"]), axis=0)
        print(
            f"{name}: child median {child[0]:.3f} ms (p99 {child[1]:.3f}), in-process "
            f"{local_ms[0]:.3f} ms (p99 {local_ms[1]:.3f}); ratio {child[0] / local_ms[0]:.1f}×"
        )


if __name__ == "__main__":
    main()
