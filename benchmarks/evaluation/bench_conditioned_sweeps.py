"""The conditioned protocol's sweeps: the expert share of a crowd, and a preference held out.

1. **Expert share.** Shared-bias D1 crowds (:mod:`bt_pipeline.data.synth_crowd`) with 0, 1 or 3
   expert-like demos of 4: with none, the cleaner's best demo is itself biased.
2. **A held-out preference** (``--held-out``, at one expert): the conditioned learner is trained
   without one demonstrator's demos and rolled out for that demonstrator's preference; its
   success on that demonstrator's true loop, averaged over the four choices, beside the same
   demonstrators' success when seen (does the policy generalise to a preference it never saw?).

Per (task, experts): noisy / cleaned / shape-only truth, success at τ = 10 mm, with the truth gate
and the cleaned-vs-noisy verdict paired over seeds (:func:`bt_pipeline.evaluate.stats.verdict`).

    python benchmarks/evaluation/bench_conditioned_sweeps.py --seeds 6 --experts 0,1,3 --held-out \
        --workers 2
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from bt_pipeline.data.tasks import TASKS
from bt_pipeline.evaluate.conditioned import evaluate_conditioned
from bt_pipeline.evaluate.crowd_sets import CrowdSettings, prepare_crowd
from bt_pipeline.evaluate.learners import parse_learner
from bt_pipeline.evaluate.stats import verdict

DATASETS = ("noisy", "cleaned", "truth_shape")
TAU_MM = 10.0


def run_unit(job: tuple[str, int, int, str, bool]) -> list[dict]:
    """One (task, experts, seed): seen scores per dataset, and held-out ones when asked."""
    task, experts, seed, name_of_learner, held_out = job
    learner = parse_learner(name_of_learner)
    settings = CrowdSettings(experts=experts)
    prepared = prepare_crowd((seed, "D1", task, "shared", settings, None))  # type: ignore[arg-type]
    rows = []
    for name in DATASETS:
        x, prefs = prepared.positions[name], prepared.preferences
        e = evaluate_conditioned(
            learner,
            name,
            x,
            prefs,
            prepared.loops,
            seed=seed,
            quick=True,
        )
        row = {"task": task, "experts": experts, "seed": seed, "dataset": name}
        row["success"] = e.scores.success_rate(TAU_MM)
        if held_out:
            away = []
            for loop in prepared.loops:
                keep = np.array([n != loop.name for n in prepared.demonstrators])
                h = evaluate_conditioned(
                    learner,
                    name,
                    x[keep],
                    prefs[keep],
                    [loop],
                    seed=seed,
                    quick=True,
                )
                away.append(h.scores.success_rate(TAU_MM))
            row["held_out"] = float(np.mean(away))
        rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, default=6)
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument("--experts", default="0,1,3")
    parser.add_argument("--learner", default="bc")
    parser.add_argument("--held-out", action="store_true", help="held-out rows (at 1 expert)")
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    if args.seeds < 2:
        parser.error("--seeds must be ≥ 2: the verdicts are paired over seeds")
    jobs = [
        (task, int(k), seed, args.learner, args.held_out and int(k) == 1)
        for task in args.tasks.split(",")
        for k in args.experts.split(",")
        for seed in range(args.seeds)
    ]
    start = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        rows = [row for unit in pool.map(run_unit, jobs) for row in unit]
    cells: dict[tuple[str, int], dict[str, dict[int, dict]]] = defaultdict(
        lambda: defaultdict(dict)
    )
    for row in rows:
        cells[(row["task"], row["experts"])][row["dataset"]][row["seed"]] = row
    print(
        f"| task | experts of 4 | success@{TAU_MM:.0f} mm noisy / cleaned / truth | verdict | "
        "held-out preference: success noisy / cleaned / truth | held-out verdict |"
    )
    print("|---|---|---|---|---|---|")
    for (task, experts), by in cells.items():
        seeds = sorted(by["noisy"])

        def values(key: str, by: dict = by, seeds: list = seeds) -> dict[str, np.ndarray]:
            return {d: np.array([by[d][s][key] for s in seeds]) for d in DATASETS}

        seen = values("success")
        v = verdict(seen["noisy"], seen["cleaned"], seen["truth_shape"], higher_is_better=True)
        line = f"| {task} | {experts} | " + " / ".join(f"{seen[d].mean():.2f}" for d in DATASETS)
        line += f" | {v.summary()} | "
        if "held_out" in by["noisy"][seeds[0]]:
            away = values("held_out")
            h = verdict(away["noisy"], away["cleaned"], away["truth_shape"], higher_is_better=True)
            line += " / ".join(f"{away[d].mean():.2f}" for d in DATASETS) + f" | {h.summary()} |"
        else:
            line += "— | — |"
        print(line, flush=True)
    print(f"\n{len(jobs)} sets, {time.perf_counter() - start:.0f} s wall")


if __name__ == "__main__":
    main()
