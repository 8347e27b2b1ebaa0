"""Hidden θ/ρ as the cleaner uses them (fitted per demo, pooled per demonstrator) vs the truth.

For ``make_human_set(task, n, seed, hidden=True)`` with n = 4 (the paper's D1: each of the four
demonstrators has one demo, nothing to pool) and n = 20 (D2: five demos each), seeds 0..S-1,
the three tasks, it runs the cleaner's own steps, :func:`bt_pipeline.clean.periodic.segment_all`
and :func:`bt_pipeline.clean.periodic.pool_preferences`, and reports the share of demos whose θ
is within 5° of ``truth_theta_deg`` and ρ within 0.05 of ``truth_rho`` (issue 9's aim: ≥ 90 %),
over all demos, the lopsided ones (one side drawn 20-35 % bigger) and the others, and how many
of the misses (and of the hits) the cleaner reports as uncertain (confidence below 0.5: the
note ``bt clean`` prints and the ``preference_confidence`` attr). Truth comes from the files'
attrs, never from the fit. More seeds than bench_clean_human's two: the share
is a count over few demos per set.

``--generator operators`` counts the same on the second, independent generator's sets
(:func:`bt_pipeline.testing.operator_sets.operator_set`: one steady and n − 1 wobbly operators,
θ/ρ hidden, none lopsided), against each operator's drawn θ/ρ.

    python benchmarks/quality/bench_preferences.py --seeds 16 --sizes 4,20
    python benchmarks/quality/bench_preferences.py --first-seed 64 --seeds 96 --sizes 4
    python benchmarks/quality/bench_preferences.py --generator operators --seeds 24 --sizes 5
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bt_pipeline.clean.periodic import UNCERTAIN, pool_preferences, segment_all
from bt_pipeline.data.demo import Demo, demos_from_recording
from bt_pipeline.data.synth_human import make_human_set
from bt_pipeline.data.tasks import TASKS, Task
from bt_pipeline.testing.operator_sets import operator_set


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, default=16)
    parser.add_argument("--first-seed", type=int, default=0, help="seeds run from this one")
    parser.add_argument("--sizes", default="4,20", help="demos per set, comma-separated")
    parser.add_argument("--generator", choices=("human", "operators"), default="human")
    args = parser.parse_args()
    print(
        "| task | demos per set | sets | demos | within 5° and 0.05 | lopsided | others | "
        "misses reported uncertain | hits reported uncertain | time |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for n in (int(v) for v in args.sizes.split(",")):
        for task in TASKS:
            start = time.perf_counter()
            ok, lopsided, doubt = [], [], []
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                demos, truths = _hidden_set(args.generator, task, n, seed)
                estimates = pool_preferences(demos, segment_all(demos))
                for estimate, (theta, rho, bulged) in zip(estimates, truths, strict=True):
                    ok.append(
                        abs(estimate.theta_deg - theta) < 5.0 and abs(estimate.rho - rho) < 0.05
                    )
                    lopsided.append(bulged)
                    doubt.append(estimate.confidence < UNCERTAIN)
            hit, lop, unsure = np.array(ok), np.array(lopsided), np.array(doubt)
            print(
                f"| {task} | {n} | {args.seeds} | {hit.size} | {_share(hit)} | "
                f"{_share(hit[lop])} ({lop.sum()}) | {_share(hit[~lop])} ({(~lop).sum()}) | "
                f"{_share(unsure[~hit])} | {_share(unsure[hit])} | "
                f"{time.perf_counter() - start:.0f} s |",
                flush=True,
            )


def _hidden_set(
    generator: str, task: Task, n: int, seed: int
) -> tuple[list[Demo], list[tuple[float, float, bool]]]:
    """A set with θ/ρ hidden, and per demo its true θ [deg], ρ and whether it is lopsided."""
    if generator == "operators":
        ops = operator_set(task, seed, n_demos=n, hidden=True).demos
        return [o.demo for o in ops], [(o.theta_deg, o.rho, False) for o in ops]
    synth = make_human_set(task, n, seed, hidden=True)
    truths = [
        (
            float(h.record.attrs["truth_theta_deg"]),
            float(h.record.attrs["truth_rho"]),
            "lopsided" in h.defects,
        )
        for h in synth.demos
    ]
    return demos_from_recording(synth.recording), truths


def _share(hits: np.ndarray) -> str:
    return f"{hits.mean():.0%}" if hits.size else "–"


if __name__ == "__main__":
    main()
