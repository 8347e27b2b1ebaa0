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
- with θ/ρ hidden, the share of estimates within 5° and 0.05, and the median error of the
  estimates (|Δθ|, |Δρ|).

``--shapes lab`` has the operators draw, per set, a loop of :mod:`bt_pipeline.testing.lab_loops`
(squircles, limaçons, lobed loops, peanuts, Lissajous figure-eights, kidneys, at their own uneven
speed: families written apart from the random loops the cleaner was developed on) instead of the
task's guide. There the hidden column is the share of relative θ within 5° and ρ within 5 %
(``synth_truth.relative_hits``: a loop learned from the demos fixes no absolute frame; θ modulo
the loop's own symmetry turn, 72° for a five-lobed loop) and the errors column is left out. The
operators' loops are stored under the task's name only for its plane, so one task is enough
(``--tasks wiping``: the three give the same table). ``--shapes d_shape`` (or another family of
``bt_pipeline.data.random_loops``) has them draw one loop of that family per set instead, read
the same way.

``--oracle`` adds a third row per task, a reference for the hidden row: each demo's θ/ρ given as
the **oracle similarity**, the least-squares fit of the operator's intended loop onto the drawn
samples with the true sample-to-phase correspondence (which no estimator has), so the part of
the wobble that looks like a rotation or a scale of the loop is in it. No estimate from the
samples alone can be expected to do better than this row by much; the gap between it and the
hidden row is what a better estimator could still gain.

    python benchmarks/quality/bench_operator_sets.py --seeds 12
    python benchmarks/quality/bench_operator_sets.py --seeds 6 --oracle
    python benchmarks/quality/bench_operator_sets.py --seeds 12 --shapes lab --tasks wiping
    python benchmarks/quality/bench_operator_sets.py --seeds 6 --shapes d_shape --tasks wiping
"""

from __future__ import annotations

import argparse
import dataclasses
from collections import defaultdict

import numpy as np

from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.data.random_loops import LOOP_FAMILIES, family_loop
from bt_pipeline.data.synth_truth import (
    oracle_similarity,
    ratios_against,
    relative_hits,
    symmetry_turn,
)
from bt_pipeline.data.tasks import TASKS
from bt_pipeline.testing.lab_loops import lab_set_loop
from bt_pipeline.testing.operator_sets import OperatorDemo, operator_set


def _oracle(op: OperatorDemo) -> tuple[float, float]:
    """θ [deg] and ρ of the oracle similarity (:func:`synth_truth.oracle_similarity`)."""
    turn, scale = oracle_similarity(op.demo.raw_samples()[0], op.intended, op.on_loop)
    return op.theta_deg + turn, op.rho * scale


def measure(task: str, seed: int, mode: str, shapes: str = "guide") -> dict[str, list[float]]:
    """The ratios and rates of one cleaned set; `mode` is given, hidden or oracle; `shapes` is
    guide, lab or a random-loop family."""
    hidden, lab = mode == "hidden", shapes != "guide"  # lab: a loop no guide draws.
    loop = None
    if shapes == "lab":
        loop = lab_set_loop(seed)
    elif lab:
        loop = family_loop(shapes, np.random.default_rng([seed, 7]))  # type: ignore[arg-type]
    ops = operator_set(task, seed, hidden=hidden, loop=loop)  # type: ignore[arg-type]
    demos = [o.demo for o in ops.demos]
    if mode == "oracle":
        demos = [
            dataclasses.replace(o.demo, theta_deg=th, rho=r)
            for o in ops.demos
            for th, r in [_oracle(o)]
        ]
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
        if hidden and not lab:
            p = result.preferences[i]
            ok = abs(p.theta_deg - op.theta_deg) < 5.0 and abs(p.rho - op.rho) < 0.05
            out["hidden_ok"].append(float(ok))
        if mode != "given" and kind == "wobbly" and not lab:  # The θ/ρ used: estimated or oracle.
            p = result.preferences[i]
            out["theta_err"].append(abs(p.theta_deg - op.theta_deg))
            out["rho_err"].append(abs(p.rho - op.rho))
    if hidden and lab:
        prefs, truth = result.preferences, ops.demos
        hits = relative_hits(
            [p.theta_deg for p in prefs],
            [p.rho for p in prefs],
            [o.theta_deg for o in truth],
            [o.rho for o in truth],
            period_deg=symmetry_turn(loop.points(1024)) if loop is not None else 360.0,
        )
        out["hidden_ok"].extend(hits.astype(float).tolist())
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--first-seed", type=int, default=0, help="seeds run from this one")
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument("--oracle", action="store_true", help="add the oracle-similarity row")
    parser.add_argument(
        "--shapes",
        choices=("guide", "lab", *LOOP_FAMILIES),
        default="guide",
        help="the loops drawn (module doc)",
    )
    args = parser.parse_args()
    print(
        "| task | θ/ρ | sets | best = steady | Ũ alone | steady shape / timing (worst) | "
        "wobbly shape / timing (mean) | hidden θ within 5° and ρ within 0.05 | "
        "median \\|Δθ\\| / \\|Δρ\\| (wobbly) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    modes = ("given", "hidden", "oracle") if args.oracle else ("given", "hidden")
    for task in args.tasks.split(","):
        for mode in modes:
            runs: dict[str, list[float]] = defaultdict(list)
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                for key, values in measure(task, seed, mode, args.shapes).items():
                    runs[key].extend(values)
            hidden_ok = f"{100 * np.mean(runs['hidden_ok']):.0f}%" if mode == "hidden" else "—"
            errors = (
                f"{np.median(runs['theta_err']):.2f}° / {np.median(runs['rho_err']):.4f}"
                if runs["rho_err"]
                else "—"
            )
            print(
                f"| {task} | {mode} | {args.seeds} | "
                f"{100 * np.mean(runs['selected']):.0f}% | "
                f"{100 * np.mean(runs['by_utility']):.0f}% | "
                f"{np.max(runs['steady_shape']):.2f} / {np.max(runs['steady_timing']):.2f} | "
                f"{np.mean(runs['wobbly_shape']):.2f} / {np.mean(runs['wobbly_timing']):.2f} | "
                f"{hidden_ok} | {errors} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
