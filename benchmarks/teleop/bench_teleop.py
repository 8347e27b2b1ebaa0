"""Teleop control-loop speed: IK + physics rate and real-time factor for 1 and 4 sessions.

Measures, on the light FR3 in the wiping scene with the target moving on a circle:

* the cost of one control tick split into its sections (IK solve, physics substeps), one session;
* the free-running control rate [ticks/s] and real-time factor (simulated / wall seconds) of
  1 and 4 sessions, each stepping as fast as it can in its own thread;
* the real-time mode: 4 sessions paced to real time in background threads, and the
  simulated time each one achieved per wall second (1.0 = real time kept).

Every number is the median of several runs; the machine may be shared, so compare ratios
within one run rather than absolute numbers across machines. The aims (issue 4): at least
500 ticks/s for one session, real time kept with 4.

    .venv/bin/python benchmarks/teleop/bench_teleop.py --runs 5
"""

# mujoco ships compiled bindings without type stubs, so pyright cannot see MjModel, mj_step,
# mjtObj, ...: attribute checks on the mujoco module are off in this file.
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import math
import statistics
import threading
import time
from dataclasses import dataclass

import mujoco
import numpy as np
import tyro

from bt_teleop.session.control_loop import Session
from bt_teleop.sim.scene import SceneModel, load_scene
from bt_teleop.testing.harness import circle_uv


@dataclass(frozen=True)
class Args:
    """Benchmark settings."""

    runs: int = 5
    """Repetitions; medians are reported."""
    sim_seconds: float = 4.0
    """Simulated seconds per session per free-running run."""
    realtime_seconds: float = 3.0
    """Wall seconds of each real-time run."""
    task: str = "wiping"
    """Scene to run."""
    robot: str = "light"
    """FR3 model: light or menagerie."""


def _circle_target(session: Session, t_s: float) -> None:
    session.set_target_uv(circle_uv(t_s))


def _drive(session: Session, n_ticks: int) -> None:
    """Step `session` for `n_ticks` with a moving target, as fast as possible."""
    for k in range(n_ticks):
        _circle_target(session, k * session.dt_s)
        session.step(1)


def section_costs(scene: SceneModel, n_ticks: int) -> dict[str, float]:
    """Median cost of the sections of a tick [ms], one session, no contention."""
    session = Session(scene, "/tmp/bt-bench-unused")
    ik, ik_ms, physics_ms = session.ik, [], []
    substeps = round(session.dt_s / scene.model.opt.timestep)
    for k in range(n_ticks):
        _circle_target(session, k * session.dt_s)
        target = scene.plane.to_world(0.06 * np.array([math.sin(k / 60), 1 - math.cos(k / 60)]))
        t0 = time.perf_counter()
        ik.solve(target, scene.ee_quat)
        t1 = time.perf_counter()
        for _ in range(substeps):
            mujoco.mj_step(scene.model, session.data)
        t2 = time.perf_counter()
        ik_ms.append((t1 - t0) * 1e3)
        physics_ms.append((t2 - t1) * 1e3)
    session.reset()
    t0 = time.perf_counter()
    _drive(session, n_ticks)
    tick_ms = (time.perf_counter() - t0) * 1e3 / n_ticks
    return {
        "ik_ms": statistics.median(ik_ms),
        "physics_ms": statistics.median(physics_ms),
        "tick_ms": tick_ms,
    }


def free_running(scene: SceneModel, n_sessions: int, sim_seconds: float) -> tuple[float, float]:
    """Sessions stepping as fast as they can in threads: (ticks/s per session, RTF per session)."""
    sessions = [Session(scene, "/tmp/bt-bench-unused") for _ in range(n_sessions)]
    n_ticks = round(sim_seconds / sessions[0].dt_s)
    threads = [threading.Thread(target=_drive, args=(s, n_ticks)) for s in sessions]
    t0 = time.perf_counter()
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    wall = time.perf_counter() - t0
    return n_ticks / wall, sim_seconds / wall


def real_time(scene: SceneModel, n_sessions: int, wall_seconds: float) -> float:
    """Sessions paced to real time: the slowest session's simulated seconds per wall second."""
    sessions = [Session(scene, "/tmp/bt-bench-unused") for _ in range(n_sessions)]
    stop = threading.Event()

    def move(session: Session) -> None:  # a browser moving the gizmo at 50 Hz
        t0 = time.perf_counter()
        while not stop.wait(0.02):
            _circle_target(session, time.perf_counter() - t0)

    movers = [threading.Thread(target=move, args=(s,)) for s in sessions]
    start_sim = [s.status().sim_time_s for s in sessions]
    t0 = time.perf_counter()
    for session in sessions:
        session.start()
    for mover in movers:
        mover.start()
    time.sleep(wall_seconds)
    for session in sessions:
        session.stop()
    wall = time.perf_counter() - t0
    stop.set()
    for mover in movers:
        mover.join()
    return min((s.status().sim_time_s - t) / wall for s, t in zip(sessions, start_sim, strict=True))


def main(args: Args) -> None:
    """Run the benchmark and print a table of medians."""
    scene = load_scene(args.task, args.robot)
    probe = Session(scene, "/tmp/bt-bench-unused")
    print(
        f"scene {args.task}, robot {args.robot}: control {probe.config.control_hz:g} Hz, "
        f"{round(probe.dt_s / scene.model.opt.timestep)} physics steps of "
        f"{scene.model.opt.timestep * 1e3:g} ms per tick; medians of {args.runs} runs"
    )
    n_ticks = round(args.sim_seconds / probe.dt_s)
    costs = [section_costs(scene, n_ticks) for _ in range(args.runs)]
    for key in ("ik_ms", "physics_ms", "tick_ms"):
        print(f"  one tick, {key:<11} {statistics.median(c[key] for c in costs):7.3f} ms")
    for n in (1, 4):
        results = [free_running(scene, n, args.sim_seconds) for _ in range(args.runs)]
        rate = statistics.median(r[0] for r in results)
        rtf = statistics.median(r[1] for r in results)
        print(
            f"  {n} session(s) free-running: {rate:8.0f} ticks/s per session "
            f"({rate * n:8.0f} in total), real-time factor {rtf:5.2f} per session"
        )
    for n in (1, 4):
        achieved = statistics.median(
            real_time(scene, n, args.realtime_seconds) for _ in range(args.runs)
        )
        print(f"  {n} session(s) paced to real time: slowest at {achieved:5.3f} x real time")


if __name__ == "__main__":
    main(tyro.cli(Args))
