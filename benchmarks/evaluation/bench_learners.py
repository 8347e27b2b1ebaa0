"""Benchmark of the imitation learners: training time per learner and preset, and rollout time.

Run: ``python benchmarks/evaluation/bench_learners.py [--repeats 3] [--presets quick full]
[--threads]``.
Prints Markdown tables of medians over `--repeats` runs on synthetic wiping sets of the paper's
sizes (D1: M = 4, D2: M = 20 demos of N = 300 samples, :mod:`bt_pipeline.data.synth`):

* wall time [s] of ``train_learner`` per learner, preset and M, with the CPU time of the process
  beside it (on a busy machine the wall time grows, the CPU time much less), and the ratio of the
  wall time to a baseline timed in the same process (BC, quick preset, M = 4), which is robust to
  a busy machine;
* wall time of 50 batched rollouts of N samples per learner (Euler or RK4);
* the projected learner time of the paper's evaluation: 3 tasks × 2 datasets (noisy, cleaned) ×
  (D1 + D2) trainings of every learner, plus 50 rollouts each;
* with ``--threads``: BC and Traj-BC (full preset, M = 20) with 1 vs 2 torch threads.

The first training of a process also pays torch's lazy imports (a few seconds); a warm-up run
absorbs that before any timing.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np

from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.synth import make_demo_set
from bt_pipeline.evaluate.learners import LEARNERS, LearnerName, learner_config, train_learner

N_SAMPLES = 300
N_ROLLOUTS = 50
TRAININGS_PER_SIZE = 3 * 2
"""Trainings of one learner at one M in the full evaluation: 3 tasks × (noisy, cleaned)."""


def demo_set(n_demos: int, seed: int = 0) -> tuple[np.ndarray, list[str]]:
    """Synthetic wiping demos (M, N, 2) [m] and their demonstrators."""
    demos = demos_from_recording(make_demo_set("wiping", n_demos=n_demos, seed=seed).recording)
    return np.stack([d.positions for d in demos]), [d.demonstrator for d in demos]


def median_times(fn: Callable[[], object], repeats: int) -> tuple[float, float]:
    """Median wall and CPU time of `fn` over `repeats` runs [s]."""
    walls, cpus = [], []
    for _ in range(repeats):
        wall, cpu = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - wall)
        cpus.append(time.process_time() - cpu)
    return statistics.median(walls), statistics.median(cpus)


def train_fn(
    name: LearnerName, data: tuple[np.ndarray, list[str]], quick: bool, **overrides: object
) -> Callable[[], object]:
    """A closure training `name` on `data` with a preset."""
    demos, who = data
    config = learner_config(name, quick=quick, **overrides)
    return lambda: train_learner(name, demos, who, config)


def main() -> None:
    parser = argparse.ArgumentParser(description="Benchmark of the imitation learners.")
    parser.add_argument("--repeats", type=int, default=3, help="runs per measurement (median)")
    parser.add_argument(
        "--presets", nargs="+", default=["quick", "full"], choices=["quick", "full"]
    )
    parser.add_argument("--learners", nargs="+", default=list(LEARNERS), choices=list(LEARNERS))
    parser.add_argument("--threads", action="store_true", help="also compare 1 vs 2 threads")
    args = parser.parse_args()

    sets = {4: demo_set(4), 20: demo_set(20)}
    train_fn("bc", sets[4], quick=True, steps=5)()  # warm-up: torch's lazy imports
    baseline_fn = train_fn("bc", sets[4], quick=True)

    print(f"Training time, median of {args.repeats} (wall [s] / CPU [s] / wall ÷ baseline)\n")
    print("| learner | preset | M = 4 | M = 20 | evaluation share, wall / CPU [s] |")
    print("|---|---|---|---|---|")
    totals: dict[str, float] = {}
    totals_cpu: dict[str, float] = {}
    rollout_s: dict[str, float] = {}
    for name in args.learners:
        for preset in args.presets:
            quick = preset == "quick"
            cells, share, share_cpu = [], 0.0, 0.0
            for data in sets.values():
                baseline, _ = median_times(baseline_fn, 1)
                wall, cpu = median_times(train_fn(name, data, quick), args.repeats)
                cells.append(f"{wall:.2f} / {cpu:.2f} / {wall / baseline:.1f}×")
                share += TRAININGS_PER_SIZE * wall
                share_cpu += TRAININGS_PER_SIZE * cpu
            trained = train_learner(name, *sets[4], learner_config(name, quick=quick))
            x0 = np.repeat(sets[4][0][:, 0], N_ROLLOUTS // 4 + 1, axis=0)[:N_ROLLOUTS]
            roll, roll_cpu = median_times(lambda p=trained.policy, x=x0: p.rollout(x, N_SAMPLES), 3)
            rollout_s[name] = roll
            share += 2 * TRAININGS_PER_SIZE * roll
            share_cpu += 2 * TRAININGS_PER_SIZE * roll_cpu
            totals[preset] = totals.get(preset, 0.0) + share
            totals_cpu[preset] = totals_cpu.get(preset, 0.0) + share_cpu
            row = f"| {name} | {preset} | {cells[0]} | {cells[1]} | {share:.0f} / {share_cpu:.0f} |"
            print(row, flush=True)
    print(f"\nBaseline (BC, quick, M = 4): {median_times(baseline_fn, 3)[0]:.2f} s wall\n")
    print(f"{N_ROLLOUTS} rollouts of N = {N_SAMPLES} (wall, median of 3)\n")
    print("| learner | rollouts [ms] |")
    print("|---|---|")
    for name, seconds in rollout_s.items():
        print(f"| {name} | {1e3 * seconds:.0f} |")
    print("\nProjected learner time of the evaluation (3 tasks × noisy/cleaned × D1 + D2):")
    for preset, seconds in totals.items():
        cpu = totals_cpu[preset]
        print(f"- {preset}: {seconds:.0f} s wall ({seconds / 60:.1f} min), {cpu:.0f} s CPU")

    if args.threads:
        print("\nThreads (full preset, M = 20, wall [s])\n")
        print("| learner | 1 thread | 2 threads | 2 ÷ 1 |")
        print("|---|---|---|---|")
        for name in ("bc", "traj_bc"):
            one, _ = median_times(train_fn(name, sets[20], False, threads=1), args.repeats)
            two, _ = median_times(train_fn(name, sets[20], False, threads=2), args.repeats)
            print(f"| {name} | {one:.2f} | {two:.2f} | {two / one:.2f} |", flush=True)


if __name__ == "__main__":
    main()
