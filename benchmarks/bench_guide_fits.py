"""Per-demo θ/ρ fits (no pooling) on two generators, with the guide fit's consensus rule varied.

For each task and seed it segments every demo of a human-style set of 4 and of an operator set
of 5, both with θ/ρ hidden (:func:`bt_pipeline.clean.segment.segment_demo`, which fits the guide
to the demo's kept span), and counts the fits within 5° and 0.05 of the demonstrator's true θ/ρ,
apart for the human-style lopsided demos and the others, and for the steady and the wobbly
operators. Truth comes from the generators, not from the cleaner. The flags set the consensus
constants of :mod:`bt_pipeline.clean.guide_fit`, so the rules compared in docs/quality.md
("Centred fits alone") can be run again:

    python benchmarks/bench_guide_fits.py --seeds 12
    python benchmarks/bench_guide_fits.py --seeds 12 --centred-reach 0      # the rule before
    python benchmarks/bench_guide_fits.py --seeds 12 --centred-slack 2.5
    python benchmarks/bench_guide_fits.py --seeds 12 --centred-bulge 0.06
"""

from __future__ import annotations

import argparse
import time
from typing import cast

import numpy as np

from bt_pipeline.clean import guide_fit
from bt_pipeline.clean.segment import segment_demo
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.synth_human import make_human_set
from bt_pipeline.data.tasks import TASKS, Task
from bt_pipeline.testing.operator_sets import operator_set


def _hit(demo_samples: tuple[np.ndarray, np.ndarray], task: Task, theta: float, rho: float) -> bool:
    positions, times = demo_samples
    fit = segment_demo(positions, times, task).guide
    return abs(fit.theta_deg - theta) < 5.0 and abs(fit.rho - rho) < 0.05


def measure(task: Task, seeds: int) -> dict[str, list[bool]]:
    """Hits per kind of demo over `seeds` sets of each generator."""
    kinds: dict[str, list[bool]] = {"lopsided": [], "other": [], "steady": [], "wobbly": []}
    for seed in range(seeds):
        synth = make_human_set(task, 4, seed, hidden=True)
        demos = demos_from_recording(synth.recording)
        for i, record in enumerate(synth.recording.demos.values()):
            theta, rho = record.attrs["truth_theta_deg"], record.attrs["truth_rho"]
            kind = "lopsided" if "lopsided" in synth.demos[i].defects else "other"
            kinds[kind].append(_hit(demos[i].raw_samples(), task, theta, rho))
        ops = operator_set(task, seed, hidden=True)
        for i, op in enumerate(ops.demos):
            kind = "steady" if i == ops.steady_index else "wobbly"
            kinds[kind].append(_hit(op.demo.raw_samples(), task, op.theta_deg, op.rho))
    return kinds


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument("--centred-reach", type=float, default=guide_fit._CENTRED_REACH)
    parser.add_argument("--centred-slack", type=float, default=guide_fit._CENTRED_SLACK)
    parser.add_argument("--centred-bulge", type=float, default=guide_fit._CENTRED_BULGE)
    args = parser.parse_args()
    guide_fit._CENTRED_REACH = args.centred_reach
    guide_fit._CENTRED_SLACK = args.centred_slack
    guide_fit._CENTRED_BULGE = args.centred_bulge
    print(
        f"centred reach {args.centred_reach}, slack {args.centred_slack}, "
        f"bulge {args.centred_bulge}; θ within 5° and ρ within 0.05, per-demo fits"
    )
    print(
        "| task | human: lopsided | human: others | operators: steady | operators: wobbly | time |"
    )
    print("|---|---|---|---|---|---|")
    for task in args.tasks.split(","):
        start = time.perf_counter()
        kinds = measure(cast(Task, task), args.seeds)
        cells = " | ".join(f"{100 * np.mean(v):.0f}% ({len(v)})" for v in kinds.values())
        print(f"| {task} | {cells} | {time.perf_counter() - start:.0f} s |", flush=True)


if __name__ == "__main__":
    main()
