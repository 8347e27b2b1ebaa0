"""What a session in a child process costs the app: start time and call latency.

A tab asks its session for ``status()`` 30 times a second and sends a target with every gizmo
drag; in a child process (:class:`bt_teleop.session_process.SessionProcess`) each is a message
over a pipe. Measured on sessions running in real time, in this process:

* start: the first child (the forkserver starts and imports MuJoCo and mink), then the median
  of the next ones (forked from the preloaded server);
* ``status()``, ``trail()`` while recording, and a one-way ``set_target``: median and p99 of
  ``--calls`` calls per run, for a child and for the same session in this process (the
  baseline, :class:`bt_teleop.tick_stats.TimedSession`), over ``--runs`` runs (medians of the
  runs' medians), and their ratio.

    nice -n 10 .venv/bin/python benchmarks/bench_session_process.py
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from bt_teleop.scene import load_scene
from bt_teleop.session_process import SessionProcess
from bt_teleop.tick_stats import TimedSession


def timed(call: Callable[[], Any], n: int) -> tuple[float, float]:
    """(median, p99) of `n` calls [ms]."""
    times = np.empty(n)
    for k in range(n):
        t0 = time.perf_counter()
        call()
        times[k] = time.perf_counter() - t0
        time.sleep(0.001)  # a tab does not call back to back
    return 1e3 * float(np.median(times)), 1e3 * float(np.percentile(times, 99))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--calls", type=int, default=500)
    parser.add_argument("--starts", type=int, default=5, help="children started after the first")
    args = parser.parse_args()
    scene = load_scene("wiping")
    with tempfile.TemporaryDirectory(prefix="bt-proc-") as tmp:
        t0 = time.perf_counter()
        first = SessionProcess(scene, tmp)
        first_s = time.perf_counter() - t0
        starts = []
        for _ in range(args.starts):
            t0 = time.perf_counter()
            SessionProcess(scene, tmp).close()
            starts.append(time.perf_counter() - t0)  # includes close: an upper bound
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
    for name in ("status()", "trail() (recording)", "set_target"):
        child = np.median(np.asarray(rows[f"{name} child"]), axis=0)
        local_ms = np.median(np.asarray(rows[f"{name} in-process"]), axis=0)
        print(
            f"{name}: child median {child[0]:.3f} ms (p99 {child[1]:.3f}), in-process "
            f"{local_ms[0]:.3f} ms (p99 {local_ms[1]:.3f}); ratio {child[0] / local_ms[0]:.1f}×"
        )


if __name__ == "__main__":
    main()
