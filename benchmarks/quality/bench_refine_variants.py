"""Compare refinement variants on the synthetic sets with ground truth (a tuning script).

For every task and seed of D1 (4 demos) and D2 (20 demos): score the raw demos, run Stage 1, then
Stage 2 with each variant, and measure against the known true shapes:

* naive ratio: mean distance_to_truth of the naive demos after / before (lower is better; the bar
  is ≤ 0.4 for every task);
* expert ratio: the same for the expert-like demo (bar ≤ 1.1);
* min ΔŨ: smallest Ũ(cleaned) - Ũ(raw) over the demos, with the true KSG, the raw set's frozen
  normalisers (clipped to [0, 1]), with β = β0 and with the final β_i (bar ≥ 0);
* closure / smoothness: mean L2 and L3 after / before over the naive demos (bar < 1);
* stage 2 seconds, and epochs run.

Usage::

    .venv/bin/python benchmarks/quality/bench_refine_variants.py --variants default paper \
        --seeds 0 1 2
    .venv/bin/python benchmarks/quality/bench_refine_variants.py --timing --variants default
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import dataclass

import numpy as np

from bt_pipeline.clean.stage1.alignment import shape_loss
from bt_pipeline.clean.stage1.extract import run_stage1
from bt_pipeline.clean.stage2.config import RefineConfig
from bt_pipeline.clean.stage2.refiner import refine_demos
from bt_pipeline.clean.stage2.scales import refine_normaliser
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.synth import make_demo_set
from bt_pipeline.data.tasks import TASKS, Task
from bt_pipeline.evaluate.distance import distance_to_truth
from bt_pipeline.score.losses import closure_loss, smoothness_loss, symmetry_loss
from bt_pipeline.score.mi import mutual_information
from bt_pipeline.score.utility import normalised_utility, score_demos


@dataclass(frozen=True)
class Row:
    """One variant on one demo set."""

    task: str
    m: int
    seed: int
    variant: str
    naive_ratio: float
    expert_ratio: float
    min_delta_utility: float
    closure_ratio: float
    smoothness_ratio: float
    seconds: float
    epochs: int
    best_is_expert: bool
    reference_ratio: float


def _metrics(p: np.ndarray, ref: np.ndarray, theta: float) -> list[float]:
    actions = np.zeros_like(p)
    actions[:-1] = np.diff(p, axis=0) * (p.shape[0] - 1)
    return [
        mutual_information(p, actions),
        symmetry_loss(p, theta),
        closure_loss(p),
        smoothness_loss(p),
        shape_loss(p, ref),
    ]


def run_set(task: Task, m: int, seed: int, configs: dict[str, RefineConfig]) -> list[Row]:
    """Every variant in `configs` on one synthetic set."""
    synth = make_demo_set(task, n_demos=m, seed=seed)
    demos = demos_from_recording(synth.recording)
    scores = score_demos(demos)
    best = scores.best_index
    stage1 = run_stage1(demos, best, seed=seed)
    positions = np.stack([d.positions for d in demos])
    normaliser = refine_normaliser(scores.normaliser, stage1.shape_losses)
    truths = [d.truth for d in synth.demos]
    expert = synth.expert_index
    naive = [i for i in range(m) if i != expert]
    raw_vals = np.array(
        [_metrics(positions[i], stage1.aligned[i], stage1.thetas[i]) for i in range(m)]
    )
    before = np.array([distance_to_truth(positions[i], truths[i]) for i in range(m)])
    ref_dist = np.array([distance_to_truth(stage1.aligned[i], truths[i]) for i in range(m)])
    reference_ratio = float(np.mean(ref_dist[naive]) / np.mean(before[naive]))
    rows = []
    for name, config in configs.items():
        start = time.perf_counter()
        result = refine_demos(
            positions,
            stage1.aligned,
            thetas_deg=stage1.thetas,
            best_index=best,
            reward_fn=stage1.rewards,
            normaliser=normaliser,
            config=config,
        )
        seconds = time.perf_counter() - start
        out = result.refined
        after = np.array([distance_to_truth(out[i], truths[i]) for i in range(m)])
        new_vals = np.array(
            [_metrics(out[i], stage1.aligned[i], stage1.thetas[i]) for i in range(m)]
        )
        weights = result.settings.weights
        gains = []
        for beta in (np.full(m, result.settings.beta0), result.betas):
            u = []
            for vals in (raw_vals, new_vals):
                nv = normaliser.normalise(vals, clip=True)
                u.append(normalised_utility(nv[:, 0], nv[:, 1:], weights, beta))
            gains.append(u[1] - u[0])
        rows.append(
            Row(
                task=task,
                m=m,
                seed=seed,
                variant=name,
                naive_ratio=float(np.mean(after[naive]) / np.mean(before[naive])),
                expert_ratio=float(after[expert] / before[expert]),
                min_delta_utility=float(np.min(gains)),
                closure_ratio=float(np.mean(new_vals[naive, 2]) / np.mean(raw_vals[naive, 2])),
                smoothness_ratio=float(np.mean(new_vals[naive, 3]) / np.mean(raw_vals[naive, 3])),
                seconds=seconds,
                epochs=result.epochs,
                best_is_expert=best == expert,
                reference_ratio=reference_ratio,
            )
        )
    return rows


def _print(rows: list[Row]) -> None:
    print(
        f"{'task':15s} {'M':>3s} {'seed':>4s} {'variant':10s} {'naive':>6s} {'expert':>6s} "
        f"{'minΔŨ':>7s} {'L2':>6s} {'L3':>6s} {'sec':>6s} {'ep':>4s} best=exp"
    )
    for r in rows:
        print(
            f"{r.task:15s} {r.m:3d} {r.seed:4d} {r.variant:10s} {r.naive_ratio:6.3f} "
            f"{r.expert_ratio:6.3f} {r.min_delta_utility:+7.3f} {r.closure_ratio:6.3f} "
            f"{r.smoothness_ratio:6.3f} {r.seconds:6.2f} {r.epochs:4d} {r.best_is_expert} "
            f"ref={r.reference_ratio:.3f}"
        )


def _summary(rows: list[Row]) -> None:
    print("\nper task and variant (worst naive ratio, worst expert ratio, min ΔŨ, median s):")
    keys = sorted({(r.variant, r.task, r.m) for r in rows})
    for variant, task, m in keys:
        sel = [r for r in rows if (r.variant, r.task, r.m) == (variant, task, m)]
        print(
            f"{variant:10s} {task:15s} M={m:3d} naive≤{max(r.naive_ratio for r in sel):.3f} "
            f"(mean {statistics.mean(r.naive_ratio for r in sel):.3f}) "
            f"expert≤{max(r.expert_ratio for r in sel):.3f} "
            f"minΔŨ={min(r.min_delta_utility for r in sel):+.3f} "
            f"L2×{max(r.closure_ratio for r in sel):.3f} "
            f"L3×{max(r.smoothness_ratio for r in sel):.3f} "
            f"t={statistics.median(r.seconds for r in sel):.2f}s"
        )


def time_sizes(config: RefineConfig, sizes: list[int], repeats: int, task: Task = "wiping") -> None:
    """Median wall time of scoring, Stage 1 and Stage 2 for M demos, and growth against M = 4."""
    print(f"\ntiming {config.variant} on {task} (median of {repeats}; scoring and Stage 1 once):")
    base = None
    for m in sizes:
        synth = make_demo_set(task, n_demos=m, seed=0)
        demos = demos_from_recording(synth.recording)
        start = time.perf_counter()
        scores = score_demos(demos)
        t_score = time.perf_counter() - start
        start = time.perf_counter()
        stage1 = run_stage1(demos, scores.best_index, seed=0)
        t_stage1 = time.perf_counter() - start
        positions = np.stack([d.positions for d in demos])
        normaliser = refine_normaliser(scores.normaliser, stage1.shape_losses)
        times, epochs = [], 0
        for _ in range(repeats):
            start = time.perf_counter()
            result = refine_demos(
                positions,
                stage1.aligned,
                thetas_deg=stage1.thetas,
                best_index=scores.best_index,
                reward_fn=stage1.rewards,
                normaliser=normaliser,
                config=config,
            )
            times.append(time.perf_counter() - start)
            epochs = result.epochs
        t_stage2 = statistics.median(times)
        base = base or t_stage2
        print(
            f"M={m:3d}: score {t_score:5.2f} s, stage 1 {t_stage1:5.2f} s, stage 2 "
            f"{t_stage2:6.2f} s ({epochs} epochs, {1e3 * t_stage2 / max(epochs, 1):.0f} ms/epoch, "
            f"×{t_stage2 / base:.1f} of M=4)"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--variants", nargs="+", default=["default", "paper"])
    parser.add_argument("--tasks", nargs="+", default=list(TASKS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--sizes", nargs="+", type=int, default=[4, 20])
    parser.add_argument("--timing", action="store_true", help="time M = 4, 20, 100 only")
    parser.add_argument("--repeats", type=int, default=3, help="timing repeats (median)")
    parser.add_argument("--set", nargs="*", default=[], help="overrides, e.g. lr=0.02 hidden=16")
    args = parser.parse_args()
    overrides = {}
    for item in args.set:
        key, value = item.split("=")
        overrides[key] = eval(value)  # a tuning script: values are Python literals
    configs = {v: RefineConfig(variant=v, **overrides) for v in args.variants}
    if args.timing:
        for config in configs.values():
            time_sizes(config, [4, 20, 100], args.repeats)
        return
    rows: list[Row] = []
    for m in args.sizes:
        for task in args.tasks:
            for seed in args.seeds:
                rows.extend(run_set(task, m, seed, configs))
                _print(rows[-len(configs) :])
    _summary(rows)


if __name__ == "__main__":
    main()
