"""How fast ``bt clean`` is, and how it grows with the number of demos M.

Writes synthetic wiping sets of M = 4, 20 and 100 demos (300 samples each after resampling) to a
temporary directory and cleans each with the library call behind ``bt clean`` (reading, scoring,
Stage 1, Stage 2, metrics, writing HDF5 and .rrd), several times; prints the median wall time,
its split, the growth relative to M = 4, and the paper variant at M = 4 as a baseline measured in
the same process.

With ``--style human`` it instead cleans human-style sets (rest, approach, loops, pauses,
retreat; bt_pipeline.data.synth_human) re-timed to a fixed length at 50 Hz: M = 8 demos of 20 s
(the speed aim, ≤ 5 s after warm-up), and for growth M = 4, 16 at 20 s and 10 s, 40 s at M = 8.

    python benchmarks/speed/bench_clean_speed.py --repeats 3
    python benchmarks/speed/bench_clean_speed.py --style human --repeats 3
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from bt_pipeline.clean.driver import clean_paths
from bt_pipeline.clean.pipeline import CleanOptions
from bt_pipeline.data.recording import write_recording
from bt_pipeline.data.records import DemoRecord, Recording, forward_difference_actions
from bt_pipeline.data.synth import make_demo_set
from bt_pipeline.data.synth_human import make_human_set

HUMAN_CASES = ((8, 20.0), (4, 20.0), (16, 20.0), (8, 10.0), (8, 40.0))
"""(M, seconds per demo) of the human-style runs; the first is the speed aim's set."""


def run(path: Path, out: Path, options: CleanOptions) -> tuple[float, dict[str, float]]:
    """Clean one file; return the wall time and the stage split [s]."""
    start = time.perf_counter()
    (summary,) = clean_paths([path], out, options)
    return time.perf_counter() - start, summary.stage_seconds


def human_recording(m: int, seconds: float, rate_hz: float = 50.0) -> Recording:
    """A human-style set of m demos, each re-timed to `seconds` and read at `rate_hz`."""
    source = make_human_set("wiping", n_demos=m, seed=0).recording
    demos = {}
    for name, record in source.demos.items():
        t = record.timestamps
        new_t = t[0] + np.arange(round(seconds * rate_hz) + 1) / rate_hz
        old_t = t[0] + (new_t - new_t[0]) * (t[-1] - t[0]) / seconds  # Time stretched.
        ee_pos = np.stack([np.interp(old_t, t, record.ee_pos[:, d]) for d in range(3)], axis=1)
        demos[name] = DemoRecord(
            ee_pos=ee_pos,
            timestamps=new_t,
            actions=forward_difference_actions(ee_pos, new_t),
            demonstrator=record.demonstrator,
            theta_deg=record.theta_deg,
            rho=record.rho,
            source=record.source,
            created=record.created,
        )
    return Recording(task=source.task, plane=source.plane, demos=demos, env_args=source.env_args)


def main_human(repeats: int) -> None:
    """Median wall time of `bt clean` on human-style sets (HUMAN_CASES)."""
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        files = {
            case: write_recording(root / f"h{case[0]}_{case[1]:g}.hdf5", human_recording(*case))
            for case in HUMAN_CASES
        }
        run(files[HUMAN_CASES[0]], root / "warm", CleanOptions(progress=False))  # Warm-up.
        rows = []
        for case in HUMAN_CASES:
            times, splits = [], []
            for k in range(repeats):
                out = root / f"out_{case[0]}_{case[1]:g}_{k}"
                seconds, split = run(files[case], out, CleanOptions(progress=False))
                times.append(seconds)
                splits.append(split)
            split = {key: statistics.median(s[key] for s in splits) for key in splits[0]}
            rows.append((case, statistics.median(times), split))
    base = rows[0][1]
    print(f"\n`bt clean`, human style (wiping), 50 Hz, median of {repeats} runs after warm-up\n")
    print(
        "| M | s per demo | total [s] | read | loop | segment | score | stage 1 | stage 2 | "
        "metrics | write | total / total(M=8, 20 s) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for (m, seconds), median, split in rows:
        parts = " | ".join(
            f"{split.get(key, 0.0):.2f}"
            for key in ("read", "loop", "segment", "score", "stage1", "stage2", "metrics", "write")
        )
        print(f"| {m} | {seconds:g} | {median:.2f} | {parts} | {median / base:.2f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sizes", default="4,20,100")
    parser.add_argument("--task", default="wiping")
    parser.add_argument("--style", choices=("single", "human"), default="single")
    args = parser.parse_args()
    if args.style == "human":
        main_human(args.repeats)
        return
    sizes = [int(m) for m in args.sizes.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        files = {}
        for m in sizes:
            files[m] = write_recording(
                root / f"m{m}.hdf5", make_demo_set(args.task, n_demos=m, seed=0).recording
            )
        # Warm-up: imports, torch kernels, Rerun.
        run(files[sizes[0]], root / "warm", CleanOptions(progress=False))
        rows = []
        cases = [(m, "default") for m in sizes] + [(sizes[0], "paper")]
        for m, variant in cases:
            times, splits = [], []
            for k in range(args.repeats):
                options = CleanOptions(variant=variant, progress=False)  # type: ignore[arg-type]
                seconds, split = run(files[m], root / f"out_{m}_{variant}_{k}", options)
                times.append(seconds)
                splits.append(split)
            median = statistics.median(times)
            split = {key: statistics.median(s[key] for s in splits) for key in splits[0]}
            rows.append((m, variant, median, split))
    base = next(r[2] for r in rows if r[0] == sizes[0] and r[1] == "default")
    print(f"\n`bt clean`, task {args.task}, N = 300, median of {args.repeats} runs\n")
    print(
        "| M | variant | total [s] | read | loop | segment | score | stage 1 | stage 2 | metrics | "
        "write | s per demo | total / total(M=4, default) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for m, variant, median, split in rows:
        parts = " | ".join(
            f"{split.get(key, 0.0):.2f}"
            for key in ("read", "loop", "segment", "score", "stage1", "stage2", "metrics", "write")
        )
        print(
            f"| {m} | {variant} | {median:.2f} | {parts} | {median / m:.3f} | {median / base:.2f} |"
        )


if __name__ == "__main__":
    main()
