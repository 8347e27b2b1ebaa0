"""Cleaning quality on sets from the second, independent generator (steady and wobbly operators).

:mod:`bt_pipeline.testing.operator_sets` draws each set apart from the human-style generator:
one steady operator (0.3 mm of noise) and wobbly ones (slow sinusoids of 1-4 mm per axis, 1-3 mm
of noise), 1-5 loops, pauses, approach and retreat, 15-120 Hz. Per task and θ/ρ given or hidden,
over ``--seeds`` sets of 5 demos, it reports:

- **best = steady**: the share of sets whose best demo is the steady one, and the share Ũ alone
  (the paper's selection: the highest utility) would have picked;
- the steady demo's worst shape and timing ratios (after/before, ``synth_truth.ratios_against``
  against the operator's intended path: a wrong best shows as a ratio far above 1);
- the wobbly demos' mean shape and timing ratios;
- with θ/ρ hidden, the share of estimates within 5° and 0.05.

    python benchmarks/bench_operator_sets.py --seeds 12
"""

from __future__ import annotations

import argparse
from collections import defaultdict

import numpy as np

from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.data.synth_truth import ratios_against
from bt_pipeline.data.tasks import TASKS
from bt_pipeline.testing.operator_sets import operator_set


def measure(task: str, seed: int, hidden: bool) -> dict[str, list[float]]:
    """The ratios and rates of one cleaned set."""
    ops = operator_set(task, seed, hidden=hidden)  # type: ignore[arg-type]
    demos = [o.demo for o in ops.demos]
    result = clean_demos(demos, CleanOptions(seed=seed, progress=False))
    utility = np.array([s.utility for s in result.scores.scores])
    out: dict[str, list[float]] = defaultdict(list)
    out["selected"].append(float(result.best_index == ops.steady_index))
    out["by_utility"].append(float(int(np.argmax(utility)) == ops.steady_index))
    for i, op in enumerate(ops.demos):
        shape, timing = ratios_against(
            op.intended, op.on_loop, op.demo.raw_samples(), result.on_raw_times(i)
        )
        kind = "steady" if i == ops.steady_index else "wobbly"
        out[f"{kind}_shape"].append(shape)
        out[f"{kind}_timing"].append(timing)
        if hidden:
            p = result.preferences[i]
            ok = abs(p.theta_deg - op.theta_deg) < 5.0 and abs(p.rho - op.rho) < 0.05
            out["hidden_ok"].append(float(ok))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--tasks", default=",".join(TASKS))
    args = parser.parse_args()
    print(
        "| task | θ/ρ | sets | best = steady | Ũ alone | steady shape / timing (worst) | "
        "wobbly shape / timing (mean) | hidden θ within 5° and ρ within 0.05 |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for task in args.tasks.split(","):
        for hidden in (False, True):
            runs: dict[str, list[float]] = defaultdict(list)
            for seed in range(args.seeds):
                for key, values in measure(task, seed, hidden).items():
                    runs[key].extend(values)
            hidden_ok = f"{100 * np.mean(runs['hidden_ok']):.0f}%" if hidden else "—"
            print(
                f"| {task} | {'hidden' if hidden else 'given'} | {args.seeds} | "
                f"{100 * np.mean(runs['selected']):.0f}% | "
                f"{100 * np.mean(runs['by_utility']):.0f}% | "
                f"{np.max(runs['steady_shape']):.2f} / {np.max(runs['steady_timing']):.2f} | "
                f"{np.mean(runs['wobbly_shape']):.2f} / {np.mean(runs['wobbly_timing']):.2f} | "
                f"{hidden_ok} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
