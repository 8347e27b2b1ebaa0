"""Two overheads of ``bt clean`` cut in issue 14, each against its old form in the same process.

1. Worker pools: three rounds of jobs (what a large task makes: segmentation, Stage 2 chunks,
   metrics) with a fresh spawn pool per round, as before, vs one pool for all three
   (:func:`bt_pipeline.execute.reuse_workers`). The jobs are trivial, so this is the pools' own
   cost: spawning workers that import bt's cleaner (numpy, scipy, torch).
2. Reading: the extra attrs of every demo of a 333-demo file, reading every attr's value and
   then skipping the reserved ones (as before) vs skipping them by name first.

    python benchmarks/scale/bench_clean_overheads.py --runs 3

Prints the median of `--runs` runs of each and their ratio; docs/scale.md quotes them.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repo root: benchmarks.common

import h5py

from benchmarks.common.timing import median_s
from bt_pipeline.clean.fan_out import segment_step  # noqa: F401  (workers import the cleaner)
from bt_pipeline.data.h5_read import read_extra_attrs
from bt_pipeline.data.recording import write_recording
from bt_pipeline.data.synth import make_demo_set
from bt_pipeline.data.validate import DEMO_ATTRS
from bt_pipeline.execute import ExecutorConfig, reuse_workers, run_jobs

POOL = ExecutorConfig("processes", workers=2)


def job(item: int) -> int:
    """A trivial job in a module that imports the cleaner, as ``bt clean``'s jobs do."""
    return item * item


def three_rounds() -> None:
    for _ in range(3):
        run_jobs(job, list(range(4)), POOL)


def three_rounds_one_pool() -> None:
    with reuse_workers(POOL):
        three_rounds()


def read_all_values_first(attrs: h5py.AttributeManager, reserved: frozenset[str]) -> None:
    """The old read: every value read, reserved ones dropped afterwards."""
    {key: value for key, value in attrs.items() if key not in reserved}


def read_file(path: Path, reader: Callable[[Any, frozenset[str]], object]) -> None:
    with h5py.File(path, "r") as file:
        data = file["data"]
        assert isinstance(data, h5py.Group)
        for group in data.values():
            reader(group.attrs, DEMO_ATTRS)


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    fresh = median_s(three_rounds, args.runs)
    shared = median_s(three_rounds_one_pool, args.runs)
    print(
        f"3 rounds of jobs, 2 workers: a pool per round {fresh:.2f} s, one pool {shared:.2f} s "
        f"(ratio {shared / fresh:.2f}; median of {args.runs})"
    )
    with tempfile.TemporaryDirectory() as tmp:
        path = write_recording(Path(tmp) / "w.hdf5", make_demo_set("wiping", 333, seed=0).recording)
        old = median_s(lambda: read_file(path, read_all_values_first), args.runs)
        new = median_s(lambda: read_file(path, read_extra_attrs), args.runs)
    print(
        f"extra attrs of 333 demos: every value read first {old:.3f} s, names first {new:.3f} s "
        f"(ratio {new / old:.2f}; median of {args.runs})"
    )


if __name__ == "__main__":
    main()
