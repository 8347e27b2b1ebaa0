"""Benchmark of the exporters and ``bt view``'s .rrd against reading the same recordings.

Run: ``python benchmarks/speed/bench_interop.py [--repeats 5]``. Prints a Markdown table of median
wall times over `--repeats` runs (after one warm-up), each with its ratio to the baseline, reading
and scoring the same files in the same process (``load_export_tasks``: what every export does
first), so the ratios show what the export itself adds and stay meaningful on a busy machine.

Inputs: the real browser takes (../shared/data/browser-takes/wiping, 12 teleop takes, ~8 k
samples) when present beside the repo, else the bundled examples (recordings/examples).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repo root: benchmarks.common

from benchmarks.common.paths import REPO, SHARED
from benchmarks.common.timing import median_ms
from bt_pipeline.interop.export_lerobot import export_lerobot
from bt_pipeline.interop.export_robomimic import export_robomimic
from bt_pipeline.interop.sources import load_export_tasks
from bt_pipeline.viz.view import save_view_rrd

TAKES = SHARED / "data/browser-takes/wiping"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--inputs", nargs="*", type=Path, help="recordings of one task")
    args = parser.parse_args()
    inputs = args.inputs or (
        [TAKES] if TAKES.is_dir() else [REPO / "recordings/examples/wiping_d1.hdf5"]
    )
    tmp = Path(tempfile.mkdtemp(prefix="bt-bench-interop-"))
    try:
        baseline = median_ms(lambda: load_export_tasks(inputs), args.repeats)
        rows = {
            "read + score (baseline)": baseline,
            "export lerobot (50 fps)": median_ms(
                lambda: export_lerobot(inputs, tmp / "ds", fps=50, overwrite=True), args.repeats
            ),
            "export robomimic (+ Stage 1 rewards)": median_ms(
                lambda: export_robomimic(inputs, tmp / "r.hdf5", overwrite=True), args.repeats
            ),
            "bt view --out (.rrd)": median_ms(
                lambda: save_view_rrd(inputs, tmp / "v.rrd"), args.repeats
            ),
        }
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"inputs: {', '.join(str(p) for p in inputs)}; {args.repeats} repeats\n")
    print("| job | median [ms] | × baseline |\n|---|---:|---:|")
    for name, ms in rows.items():
        print(f"| {name} | {ms:.0f} | {ms / baseline:.2f} |")


if __name__ == "__main__":
    main()
