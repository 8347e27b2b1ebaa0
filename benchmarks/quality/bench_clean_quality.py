"""Cleaning quality on synthetic sets with ground truth: what each step of the cleaner buys.

For every task and several seeds of D1 (4 demos) and D2 (20 demos) this runs the cleaner and
compares, per demo, the distance to its ground-truth shape (the expert shape under the demo's
θ, ρ at the task centre; symmetric Chamfer, phase-free) before and after. Rows:

- ``default``: ``bt clean`` (bt's refinement design);
- ``paper``: ``bt clean --variant paper`` (the paper's configuration as written);
- ``stage1``: Stage 1's aligned references x_i^aligned used as the cleaned demos;
- ``smooth``: plain periodic Gaussian smoothing of each raw demo (σ = 6 samples), no cleaner.

Columns: naive ratio = mean over naive demos of (distance after / distance before), lower is
better; expert ratio the same for the expert-like demo; "Ũ≥raw" the share of demos whose Ũ (true
KSG) did not fall; closure and smoothness = mean L2, L3 after / before.

    python benchmarks/quality/bench_clean_quality.py --seeds 3
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict

import numpy as np
from scipy.ndimage import gaussian_filter1d

from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.synth import make_d1, make_d2
from bt_pipeline.data.tasks import TASKS
from bt_pipeline.evaluate.distance import distance_to_truth
from bt_pipeline.score.losses import closure_loss, smoothness_loss

ROWS = ("default", "paper", "stage1", "smooth")


def measure(task: str, preset: str, seed: int, rows: tuple[str, ...]) -> dict[str, dict]:
    """Per-row quality numbers for one synthetic set."""
    synth = (make_d1 if preset == "D1" else make_d2)(task, seed)
    demos = demos_from_recording(synth.recording)
    raw = np.stack([d.positions for d in demos])
    truths = [d.truth for d in synth.demos]
    before = np.array([distance_to_truth(raw[i], truths[i]) for i in range(len(demos))])
    expert = synth.expert_index
    out: dict[str, dict] = {}
    results = {}
    for variant in ("default", "paper"):
        if variant in rows or (variant == "default" and "stage1" in rows):
            start = time.perf_counter()
            results[variant] = clean_demos(
                demos, CleanOptions(variant=variant, seed=seed, progress=False)
            )
            results[variant + "_s"] = time.perf_counter() - start
    for row in rows:
        if row in ("default", "paper"):
            result = results[row]
            cleaned = result.positions
            utility_ok = np.mean(  # Stage 2's own objective: what refinement maximises
                [
                    c.objective >= r.objective - 1e-9
                    for c, r in zip(result.cleaned, result.raw, strict=True)
                ]
            )
            seconds = results[row + "_s"]
            selected_expert = result.best_index == expert
        elif row == "stage1":
            cleaned = results["default"].stage1.aligned
            utility_ok, seconds, selected_expert = np.nan, np.nan, True
        else:
            cleaned = gaussian_filter1d(raw, sigma=6.0, axis=1, mode="wrap")
            utility_ok, seconds, selected_expert = np.nan, np.nan, True
        after = np.array([distance_to_truth(cleaned[i], truths[i]) for i in range(len(demos))])
        ratio = after / before
        naive = np.delete(ratio, expert)
        closure = np.mean([closure_loss(c) for c in cleaned]) / np.mean(
            [closure_loss(r) for r in raw]
        )
        smooth = np.mean([smoothness_loss(c) for c in cleaned]) / np.mean(
            [smoothness_loss(r) for r in raw]
        )
        out[row] = {
            "naive": float(np.mean(naive)),
            "naive_worst": float(np.max(naive)),
            "expert": float(ratio[expert]),
            "utility_ok": float(utility_ok),
            "closure": float(closure),
            "smooth": float(smooth),
            "seconds": float(seconds),
            "selected": bool(selected_expert),
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3, help="seeds per task and preset")
    parser.add_argument("--presets", default="D1,D2")
    parser.add_argument("--rows", default=",".join(ROWS))
    parser.add_argument("--tasks", default=",".join(TASKS))
    args = parser.parse_args()
    rows = tuple(args.rows.split(","))
    table: dict[tuple[str, str, str], list[dict]] = defaultdict(list)
    for task in args.tasks.split(","):
        for preset in args.presets.split(","):
            for seed in range(args.seeds):
                for row, numbers in measure(task, preset, seed, rows).items():
                    table[(task, preset, row)].append(numbers)
                print(f"  done {task} {preset} seed {seed}", flush=True)
    print()
    print(
        "| task | set | method | naive ratio (mean) | naive ratio (worst) | expert ratio | "
        "objective ≥ raw | closure after/before | smoothness after/before | s per set |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for (task, preset, row), runs in table.items():

        def mean(key: str, runs: list[dict] = runs) -> float:
            return float(np.mean([r[key] for r in runs]))

        worst = max(r["naive_worst"] for r in runs)
        expert_worst = max(r["expert"] for r in runs)
        utility = "—" if np.isnan(mean("utility_ok")) else f"{100 * mean('utility_ok'):.0f}%"
        seconds = "—" if np.isnan(mean("seconds")) else f"{mean('seconds'):.1f}"
        print(
            f"| {task} | {preset} | {row} | {mean('naive'):.2f} | {worst:.2f} | "
            f"{mean('expert'):.2f} (worst {expert_worst:.2f}) | {utility} | "
            f"{mean('closure'):.2f} | {mean('smooth'):.3f} | {seconds} |"
        )


if __name__ == "__main__":
    main()
