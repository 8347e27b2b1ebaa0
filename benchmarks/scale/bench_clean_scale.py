"""``bt clean`` at scale: M = 100, 1,000 and 5,000 demos over 3 tasks, processes vs a local Ray.

Writes single-loop synthetic sets (300 samples per demo, M/3 demos per task, one file per task)
to a temporary directory, then cleans them through the library call behind ``bt clean`` with each
executor. Reports per (M, executor): wall time, CPU time of the whole process tree, peak resident
memory of the whole tree (sampled every 0.1 s with psutil: this process, worker processes and,
with Ray, raylet, GCS and Ray workers; RSS summed over processes counts shared pages once per
process, PSS shares them out, so their sum is the tree's real footprint), and the growth against
the smallest M. Ray's overhead is
the ratio of its wall time to the process executor's at the smallest M, measured in this run.

    python benchmarks/scale/bench_clean_scale.py --sizes 100,1000,5000 --workers 2 --chunk-size 256

Stage 2 runs in chunks of at most ``--chunk-size`` demos (``bt clean``'s default, 256), so a task of
M/3 > K demos sends its chunks to the executor as jobs. Each row also prints the 1-minute load
average before and after the run (the machine may be shared).

The numbers in docs/scale.md come from this script; it is a benchmark, not a test.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import tempfile
import threading
import time
from pathlib import Path

import psutil

from bt_pipeline.clean.driver import clean_paths
from bt_pipeline.clean.pipeline import CleanOptions
from bt_pipeline.data.recording import write_recording
from bt_pipeline.data.synth import make_demo_set
from bt_pipeline.execute import ExecutorConfig

TASKS = ("wiping", "weaving", "pick_and_place")


def process_kind(proc: psutil.Process, me: int) -> str:
    """What a process of the tree is: the driver, a pool or Ray worker, or one of Ray's services.

    Ray names its workers ``ray::<task>`` (``ray::IDLE`` between tasks) and starts its services
    as ``gcs_server``, ``raylet`` and Python scripts (dashboard API server and its modules,
    dashboard agent, runtime-env agent, log monitor, autoscaler monitor, process reaper).
    """
    if proc.pid == me:
        return "driver"
    try:
        name, cmdline = proc.name(), " ".join(proc.cmdline())
    except psutil.Error:
        return "gone"
    if name in ("gcs_server", "raylet"):  # Ray's two binaries (other cmdlines name the raylet)
        return name
    for needle, kind in (
        ("ray::DashboardAgent", "dashboard agent"),
        ("ray::RuntimeEnvAgent", "runtime-env agent"),
        ("ray::", "ray worker"),
        ("default_worker.py", "ray worker"),
        ("dashboard/agent.py", "dashboard agent"),
        ("runtime_env/agent", "runtime-env agent"),
        ("dashboard/dashboard.py", "dashboard (API server)"),
        ("ray-dashboard", "dashboard modules"),
        ("log_monitor.py", "log monitor"),
        ("monitor.py", "autoscaler monitor"),
        ("ray_process_reaper", "reaper"),
        ("multiprocessing", "pool worker"),
    ):
        if needle in cmdline:
            return kind
    return name


class TreeSampler:
    """Peak RSS and PSS [bytes] and CPU seconds of this process and all its descendants.

    Also the PSS of each kind of process (:func:`process_kind`) at the moment the tree's PSS
    peaked, and the most processes of each kind seen at once.
    """

    def __init__(self, period_s: float = 0.1) -> None:
        self.period_s = period_s
        self.peak = 0
        self.peak_pss = 0
        self.peak_driver = 0
        self.driver_start = psutil.Process().memory_info().rss
        self.cpu_at_start = 0.0
        self.kinds_at_peak: dict[str, int] = {}
        """PSS [bytes] per kind of process, at the sample where the tree's PSS peaked."""
        self.most_processes: dict[str, int] = {}
        """Most processes of each kind alive at one sample."""
        self.shm_start = _shm_used()
        self.peak_shm = self.shm_start
        """Peak of /dev/shm in use [bytes] (Ray's object store lives there; machine-wide)."""
        self._cpu: dict[int, float] = {}
        self._kinds: dict[int, str] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> TreeSampler:
        self._sample()
        self.cpu_at_start = self.cpu_s
        self._thread.start()
        return self

    def __exit__(self, *_: object) -> None:
        self._stop.set()
        self._thread.join()
        self._sample()

    @property
    def cpu_s(self) -> float:
        return sum(self._cpu.values())

    def breakdown(self) -> str:
        """``kind PSS [MiB] (×n)`` per kind at the peak, largest first."""
        parts = sorted(self.kinds_at_peak.items(), key=lambda kv: -kv[1])
        return ", ".join(
            f"{kind} {pss / 2**20:.0f}"
            + (f" (x{self.most_processes[kind]})" if self.most_processes.get(kind, 1) > 1 else "")
            for kind, pss in parts
        )

    def _sample(self) -> None:
        me = psutil.Process()
        rss = pss = 0
        kinds: dict[str, int] = {}
        counts: dict[str, int] = {}
        for proc in [me, *me.children(recursive=True)]:
            try:
                with proc.oneshot():
                    memory = proc.memory_full_info()
                    times = proc.cpu_times()
            except psutil.Error:
                continue
            rss += memory.rss
            pss += memory.pss  # shared pages (libraries, Ray's object store) counted once
            self._cpu[proc.pid] = times.user + times.system
            if proc.pid not in self._kinds:  # a pid's kind is looked up once (Ray renames
                self._kinds[proc.pid] = process_kind(proc, me.pid)  # workers per task)
            kind = self._kinds[proc.pid]
            kinds[kind] = kinds.get(kind, 0) + memory.pss
            counts[kind] = counts.get(kind, 0) + 1
        self.peak = max(self.peak, rss)
        if pss > self.peak_pss:
            self.peak_pss, self.kinds_at_peak = pss, kinds
        for kind, n in counts.items():
            self.most_processes[kind] = max(self.most_processes.get(kind, 0), n)
        self.peak_driver = max(self.peak_driver, me.memory_info().rss)
        self.peak_shm = max(self.peak_shm, _shm_used())

    def _run(self) -> None:
        while not self._stop.is_set():
            self._sample()
            self._stop.wait(self.period_s)


def _shm_used() -> int:
    """Bytes in use on /dev/shm (0 where there is none)."""
    try:
        return shutil.disk_usage("/dev/shm").used
    except OSError:
        return 0


def _rusage_cpu() -> float:
    """CPU seconds of this process and its reaped children."""
    own, kids = (
        resource.getrusage(resource.RUSAGE_SELF),
        resource.getrusage(resource.RUSAGE_CHILDREN),
    )
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def write_sets(root: Path, m: int) -> list[Path]:
    """M demos in all, spread over the three tasks, one file per task."""
    files = []
    for k, task in enumerate(TASKS):
        n = m // len(TASKS) + (1 if k < m % len(TASKS) else 0)
        demo_set = make_demo_set(task, n_demos=n, seed=k)
        files.append(write_recording(root / f"m{m}" / f"{task}.hdf5", demo_set.recording))
    return files


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--sizes", default="100,1000,5000")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--executors", default="processes,ray")
    parser.add_argument("--chunk-size", type=int, default=256)
    parser.add_argument(
        "--warm-up", type=int, default=None, help="M of the unmeasured warm-up (0: none)"
    )
    args = parser.parse_args()
    sizes = [int(m) for m in args.sizes.split(",")]
    executors = args.executors.split(",")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        warm_up = sizes[0] if args.warm_up is None else args.warm_up
        inputs = {m: write_sets(root, m) for m in {*sizes, *([warm_up] if warm_up else [])}}
        for kind in executors:
            config = ExecutorConfig(kind, args.workers)  # type: ignore[arg-type]
            # Warm-up (imports; Ray's start-up) on the smallest set, not measured.
            if warm_up:
                clean_paths(
                    inputs[warm_up],
                    root / f"warm_{kind}",
                    CleanOptions(progress=False, chunk_size=args.chunk_size),
                    executor=config,
                )
            for m in sizes:
                load_before = os.getloadavg()[0]
                before = _rusage_cpu()
                with TreeSampler() as sampler:
                    start = time.perf_counter()
                    summaries = clean_paths(
                        inputs[m],
                        root / f"out_{kind}_{m}",
                        CleanOptions(progress=False, write_rrd=False, chunk_size=args.chunk_size),
                        executor=config,
                    )
                    wall = time.perf_counter() - start
                # Reaped pool workers are counted by getrusage; live trees (Ray) by the sampler.
                cpu = max(sampler.cpu_s - sampler.cpu_at_start, _rusage_cpu() - before)
                rows.append((kind, m, wall, cpu, sampler.peak / 2**30, sampler.peak_pss / 2**30))
                # Wall seconds per stage, summed over the tasks (stage2 of a chunked task: the
                # time its chunks took on the executor, seen from the process cleaning the task).
                stages: dict[str, float] = {}
                for summary in summaries:
                    for stage, seconds in summary.stage_seconds.items():
                        stages[stage] = stages.get(stage, 0.0) + seconds
                print(
                    f"{kind} M={m} stages [s]: "
                    + ", ".join(f"{k} {v:.1f}" for k, v in stages.items()),
                    flush=True,
                )
                print(
                    f"{kind} M={m}: {wall:.1f} s wall, {cpu:.1f} s CPU, "
                    f"{sampler.peak / 2**30:.2f} GiB peak RSS, "
                    f"{sampler.peak_pss / 2**30:.2f} GiB peak PSS (driver process alone "
                    f"{sampler.peak_driver / 2**30:.2f}, {sampler.driver_start / 2**30:.2f} at the "
                    f"start); load average {load_before:.2f} before, "
                    f"{os.getloadavg()[0]:.2f} after",
                    flush=True,
                )
                print(
                    f"{kind} M={m} PSS at the peak [MiB]: {sampler.breakdown()}; /dev/shm "
                    f"(object store) grew by {(sampler.peak_shm - sampler.shm_start) / 2**20:.0f}",
                    flush=True,
                )
    print()
    print(
        "| executor | M | wall [s] | CPU [s] | peak RSS [GiB] | peak PSS [GiB] | wall / wall(M0) "
        "| M / M0 |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for kind, m, wall, cpu, peak, pss in rows:
        base = next(r for r in rows if r[0] == kind and r[1] == sizes[0])
        print(
            f"| {kind} | {m} | {wall:.1f} | {cpu:.1f} | {peak:.2f} | {pss:.2f} | "
            f"{wall / base[2]:.1f} | {m / sizes[0]:.0f} |"
        )
    walls = {(r[0], r[1]): r[2] for r in rows}
    if ("ray", sizes[0]) in walls and ("processes", sizes[0]) in walls:
        ratio = walls[("ray", sizes[0])] / walls[("processes", sizes[0])]
        print(f"\nRay / processes wall time at M = {sizes[0]}: {ratio:.2f}")


if __name__ == "__main__":
    main()
