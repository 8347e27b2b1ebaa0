"""What the app keeps of each take its library reads: files read in the app vs in a reader child.

The app's library loader reads every take saved and scores it on its periodic part
(:func:`bt_teleop.library.reading.read_file_tracks`). This benchmark plays the app's side of that
alone: a process (a stand-in for the app) with a :class:`~bt_teleop.library.loader.LibraryLoader`
into which takes are saved one by one (copies of human-style demos with θ/ρ given, one demo a
file, as the app saves them); after each, one load of the task, as every tab asks for it; every
20 takes the C heap is trimmed (as the app's ``HeapTrimmer`` does every minute) and the
process's memory sampled (``/proc/<pid>/smaps_rollup``). Two arms, each run in a fresh process:

* ``in-process``: files read and scored in the app's process (the code before);
* ``reader``: read and scored in a :class:`~bt_teleop.library.reader_process.ReaderProcess` child
  (the app now); the child's own memory is reported beside it (it is replaced after ``max_reads``).

It reports the growth per take of the app stand-in's RSS, anonymous PSS and USS [KiB a take]
(least squares from the warm-up on), medians over the runs, and the median time of a load::

    .venv/bin/python benchmarks/soak/bench_reader_memory.py --takes 600 --runs 3
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repo root: benchmarks.common

import numpy as np

from benchmarks.common.procfs import KIB, smaps_rollup

ARMS = ("in-process", "reader")


def memory(pid: int) -> list[float]:
    """[RSS, anon PSS, USS] of `pid` [bytes]."""
    s = smaps_rollup(pid)
    return [s["Rss"], s.get("Pss_Anon", float("nan")), s["Private_Clean"] + s["Private_Dirty"]]


def make_pool(folder: Path, seeds: int) -> list[Path]:
    """Take files to copy: each demo of human-style wiping sets, θ/ρ given, one a file."""
    from bt_pipeline.data.recording import write_recording
    from bt_pipeline.data.synth_human import make_human_set

    pool: list[Path] = []
    for seed in range(seeds):
        recording = make_human_set("wiping", 4, seed, hidden=False).recording
        for name, demo in recording.demos.items():
            one = replace(recording, demos={"demo_0": demo})
            pool.append(write_recording(folder / f"pool_{seed}_{name}.hdf5", one))
    return pool


def one_arm(arm: str, pool: list[Path], takes: int, every: int) -> dict[str, object]:
    """Save `takes` takes and load the library after each; memory every `every` takes."""
    from bt_teleop.library.loader import LibraryLoader
    from bt_teleop.library.reader_process import ReaderProcess
    from bt_teleop.library.reading import read_file_tracks
    from bt_teleop.proc.native_memory import trim_heap

    reader = ReaderProcess() if arm == "reader" else None
    read_file = reader.read if reader is not None else read_file_tracks
    samples: list[list[float]] = []
    load_s: list[float] = []
    with tempfile.TemporaryDirectory() as tmp, concurrent.futures.ThreadPoolExecutor(1) as pool_x:
        folder = Path(tmp) / "wiping"
        folder.mkdir()
        loader = LibraryLoader(Path(tmp), pool_x, read_file=read_file, min_interval_s=0, duty=0)
        for k in range(1, takes + 1):
            shutil.copyfile(pool[k % len(pool)], folder / f"take_{k:05d}.hdf5")
            start = time.perf_counter()
            library = loader.request("wiping").result()
            load_s.append(time.perf_counter() - start)
            assert len(library.raw) == k
            if k % every == 0:
                trim_heap()
                child = memory(reader.pid) if reader is not None and reader.pid else [0.0] * 3
                samples.append([float(k), *memory(os.getpid()), *child])
    if reader is not None:
        reader.close()
    return {"samples": samples, "load_s": load_s}


def growth(samples: np.ndarray, column: int, warmup: int) -> float:
    """Least-squares slope of a column from the warm-up on [KiB a take]."""
    keep = samples[:, 0] >= warmup
    return float(np.polyfit(samples[keep, 0], samples[keep, column], 1)[0] / KIB)


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--takes", type=int, default=600)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--warmup", type=int, default=100)
    parser.add_argument("--every", type=int, default=20)
    parser.add_argument("--pool-seeds", type=int, default=6)
    parser.add_argument("--arms", nargs="*", choices=ARMS, default=list(ARMS))
    parser.add_argument("--one", choices=ARMS, help=argparse.SUPPRESS)
    parser.add_argument("--pool", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        pool = sorted(Path(args.pool).glob("*.hdf5"))
        print(json.dumps(one_arm(args.one, pool, args.takes, args.every)))
        return
    print(f"load average at start: {os.getloadavg()[0]:.2f}; {time.strftime('%H:%M')}")
    results: dict[str, list[dict]] = {arm: [] for arm in args.arms}
    with tempfile.TemporaryDirectory() as pool_dir:
        make_pool(Path(pool_dir), args.pool_seeds)
        for r in range(args.runs):
            for arm in args.arms:  # each arm in a fresh process, alternating
                command = [sys.executable, __file__, "--one", arm, "--pool", pool_dir]
                command += ["--takes", str(args.takes), "--every", str(args.every)]
                out = subprocess.run(command, check=True, capture_output=True, text=True)
                results[arm].append(json.loads(out.stdout.splitlines()[-1]))
            print(f"run {r + 1} done, load average {os.getloadavg()[0]:.2f}", flush=True)
    names = ["RSS", "anon PSS", "USS"]
    print(f"growth per take from take {args.warmup} to {args.takes} [KiB a take], median of runs:")
    for arm, runs in results.items():
        arrays = [np.asarray(run["samples"]) for run in runs]
        app = ", ".join(
            f"{name} {np.median([growth(a, 1 + c, args.warmup) for a in arrays]):+.2f}"
            for c, name in enumerate(names)
        )
        ends = ", ".join(
            f"{name} {np.median([a[-1, 1 + c] - a[0, 1 + c] for a in arrays]) / KIB**2:+.1f}"
            for c, name in enumerate(names)
        )
        loads = 1e3 * np.median([np.median(run["load_s"]) for run in runs])
        span = f"take {args.every} to {args.takes}"
        print(f"{arm}: app {app}; {span}: {ends} MiB; load {loads:.1f} ms")
        if arm == "reader":
            child = ", ".join(
                f"{name} {np.median([growth(a, 4 + c, args.warmup) for a in arrays]):+.2f}"
                for c, name in enumerate(names)
            )
            print(f"reader: the child {child} (replaced after max_reads reads)")
    print(f"load average at end: {os.getloadavg()[0]:.2f}; {time.strftime('%H:%M')}")


if __name__ == "__main__":
    main()
