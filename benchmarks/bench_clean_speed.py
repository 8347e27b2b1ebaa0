"""How fast ``bt clean`` is, and how it grows with the number of demos M.

Writes synthetic wiping sets of M = 4, 20 and 100 demos (300 samples each after resampling) to a
temporary directory and cleans each with the library call behind ``bt clean`` (reading, scoring,
Stage 1, Stage 2, metrics, writing HDF5 and .rrd), several times; prints the median wall time,
its split, the growth relative to M = 4, and the paper variant at M = 4 as a baseline measured in
the same process.

    python benchmarks/bench_clean_speed.py --repeats 3
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from bt_pipeline.clean.driver import clean_paths
from bt_pipeline.clean.pipeline import CleanOptions
from bt_pipeline.data.recording import write_recording
from bt_pipeline.data.synth import make_demo_set


def run(path: Path, out: Path, options: CleanOptions) -> tuple[float, dict[str, float]]:
    """Clean one file; return the wall time and the stage split [s]."""
    start = time.perf_counter()
    (summary,) = clean_paths([path], out, options)
    return time.perf_counter() - start, summary.stage_seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sizes", default="4,20,100")
    parser.add_argument("--task", default="wiping")
    args = parser.parse_args()
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
        "| M | variant | total [s] | read | score | stage 1 | stage 2 | metrics | write | "
        "s per demo | total / total(M=4, default) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for m, variant, median, split in rows:
        parts = " | ".join(
            f"{split.get(key, 0.0):.2f}"
            for key in ("read", "score", "stage1", "stage2", "metrics", "write")
        )
        print(
            f"| {m} | {variant} | {median:.2f} | {parts} | {median / m:.3f} | {median / base:.2f} |"
        )


if __name__ == "__main__":
    main()
