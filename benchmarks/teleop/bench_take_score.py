"""What scoring one saved take costs the app's library: its periodic part against the whole take.

Since 2026-12-03 the library scores each take as ``bt clean`` does
(:func:`bt_pipeline.clean.selection.take_score`: segmentation, θ/ρ, the ranking metrics on
the kept span and the guide misfit) instead of Eqs. (1), (4)-(6) on the whole take
(:func:`bt_pipeline.score.utility.raw_metrics`). The loader computes it once per take (a new or
changed file); unchanged takes reuse it. This benchmark times both on the same demos, in the
same process: human-style takes of 20 s at 30-60 Hz (``make_human_set``) and, when present, the
browser takes in ``../shared/data/browser-takes`` (those with a loop). Median over ``--runs``
runs per demo, then the median over the demos, and the ratio new / old::

    .venv/bin/python benchmarks/teleop/bench_take_score.py --runs 5
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repo root: benchmarks.common

import numpy as np

from benchmarks.common.timing import median_s
from bt_pipeline.clean.selection import take_score
from bt_pipeline.data.demo import Demo, demos_from_recording, load_demos
from bt_pipeline.data.synth_human import make_human_set
from bt_pipeline.exceptions import DemoError
from bt_pipeline.score.utility import raw_metrics
from bt_teleop.testing.harness import shared_dir


def _demos() -> dict[str, list[Demo]]:
    sets = {
        task: demos_from_recording(make_human_set(task, 4, seed=0).recording)
        for task in ("wiping", "weaving", "pick_and_place")
    }
    takes = shared_dir() / "data/browser-takes"
    if takes.is_dir():
        found = []
        for path in sorted(takes.glob("*/*.hdf5")):
            for demo in load_demos([path]):
                try:
                    take_score(demo)
                except DemoError:
                    continue  # no loop: the library lists it unscored
                found.append(demo)
        sets["browser takes"] = found
    return sets


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    print("| demos | n | whole take: raw_metrics [ms] | periodic part: take_score [ms] | ratio |")
    print("|---|---|---|---|---|")
    for label, demos in _demos().items():
        old = [median_s(lambda d=d: raw_metrics(d.positions, d.actions, d.theta_deg), args.runs)
               for d in demos]  # fmt: skip
        new = [median_s(lambda d=d: take_score(d), args.runs) for d in demos]
        old_ms, new_ms = 1e3 * float(np.median(old)), 1e3 * float(np.median(new))
        print(f"| {label} | {len(demos)} | {old_ms:.1f} | {new_ms:.1f} | {new_ms / old_ms:.1f} |")


if __name__ == "__main__":
    main()
