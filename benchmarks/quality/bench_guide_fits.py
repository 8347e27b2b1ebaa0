"""Per-demo θ/ρ fits (no pooling) on two generators, with the guide fit's consensus rule varied.

For each task and seed it segments every demo of a human-style set of 4 and of an operator set
of 5, both with θ/ρ hidden (:func:`bt_pipeline.clean.segment.segment_demo`, which fits the guide
to the demo's kept span), and counts the fits within 5° and 0.05 of the demonstrator's true θ/ρ,
apart for the human-style lopsided demos and the others, and for the steady and the wobbly
operators. Truth comes from the generators, not from the cleaner. The flags set the consensus
constants of :mod:`bt_pipeline.clean.guide_consensus`, so the rules compared in docs/quality.md
("Centred fits alone") can be run again:

    python benchmarks/quality/bench_guide_fits.py --seeds 12
    python benchmarks/quality/bench_guide_fits.py --seeds 12 --centred-reach 0    # the rule before
    python benchmarks/quality/bench_guide_fits.py --seeds 12 --centred-slack 2.5
    python benchmarks/quality/bench_guide_fits.py --seeds 12 --centred-bulge 0.06

``--refine-both`` runs every row twice in the same process, without and with the last step of
the estimate (:func:`bt_pipeline.clean.guide_refine.refine_fit`, the robust least-squares
similarity over every sample), and adds the median |Δθ| / |Δρ| per kind of demo; ``--first-seed``
moves the seed range (the refinement's constants were chosen on seeds 0-7, so 8 and up are
held apart):

    python benchmarks/quality/bench_guide_fits.py --first-seed 8 --seeds 16 --refine-both

``--oracle`` adds a row per task for the **oracle similarity**: the least-squares similarity
(free translation) that maps each demo's intended path onto its drawn samples over the true
loop part, with the true sample-to-phase correspondence, which no estimator has. On a lopsided
loop it shows whether the truth (the generator's θ/ρ before one side was bulged) is the
similarity that best explains what was drawn.
"""

from __future__ import annotations

import argparse
import time
from typing import cast

import numpy as np

from bt_pipeline.clean import guide_consensus, span_fit
from bt_pipeline.clean.guide_fit import GuideFit
from bt_pipeline.clean.segment import segment_demo
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.synth_human import make_human_set
from bt_pipeline.data.synth_truth import oracle_similarity
from bt_pipeline.data.tasks import TASKS, Task
from bt_pipeline.testing.operator_sets import operator_set


def _error(
    demo_samples: tuple[np.ndarray, np.ndarray], task: Task, theta: float, rho: float
) -> tuple[float, float]:
    """|Δθ| [deg] and |Δρ| of the demo's per-demo estimate."""
    positions, times = demo_samples
    fit = segment_demo(positions, times, task).guide
    return abs(fit.theta_deg - theta), abs(fit.rho - rho)


def _oracle(
    demo_samples: tuple[np.ndarray, np.ndarray],
    intended: np.ndarray,
    on_loop: np.ndarray,
    rho: float,
) -> tuple[float, float]:
    """|Δθ| [deg] and |Δρ| of the oracle similarity (module doc)."""
    turn, scale = oracle_similarity(demo_samples[0], intended, on_loop)
    return abs(turn), abs(rho * (scale - 1.0))


def _unrefined(positions: np.ndarray, fit: GuideFit, *args: object, **kwargs: object) -> GuideFit:
    return fit


def measure(
    task: Task, seeds: int, first: int = 0, oracle: bool = False
) -> dict[str, list[tuple[float, float]]]:
    """Estimate errors per kind of demo over `seeds` sets of each generator from seed `first`
    (with `oracle`, the oracle similarity's errors instead)."""
    kinds: dict[str, list[tuple[float, float]]] = {
        "lopsided": [],
        "other": [],
        "steady": [],
        "wobbly": [],
    }
    for seed in range(first, first + seeds):
        synth = make_human_set(task, 4, seed, hidden=True)
        demos = demos_from_recording(synth.recording)
        for i, record in enumerate(synth.recording.demos.values()):
            theta, rho = record.attrs["truth_theta_deg"], record.attrs["truth_rho"]
            kind = "lopsided" if "lopsided" in synth.demos[i].defects else "other"
            samples = demos[i].raw_samples()
            human = synth.demos[i]
            kinds[kind].append(
                _oracle(samples, human.truth_uv, human.on_loop, rho)
                if oracle
                else _error(samples, task, theta, rho)
            )
        ops = operator_set(task, seed, hidden=True)
        for i, op in enumerate(ops.demos):
            kind = "steady" if i == ops.steady_index else "wobbly"
            samples = op.demo.raw_samples()
            kinds[kind].append(
                _oracle(samples, op.intended, op.on_loop, op.rho)
                if oracle
                else _error(samples, task, op.theta_deg, op.rho)
            )
    return kinds


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--refine-both", action="store_true", help="rows without and with it")
    parser.add_argument("--oracle", action="store_true", help="add the oracle similarity's row")
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument("--centred-reach", type=float, default=guide_consensus.CENTRED_REACH)
    parser.add_argument("--centred-slack", type=float, default=guide_consensus._CENTRED_SLACK)
    parser.add_argument("--centred-bulge", type=float, default=guide_consensus._CENTRED_BULGE)
    args = parser.parse_args()
    guide_consensus.CENTRED_REACH = args.centred_reach
    guide_consensus._CENTRED_SLACK = args.centred_slack
    guide_consensus._CENTRED_BULGE = args.centred_bulge
    print(
        f"centred reach {args.centred_reach}, slack {args.centred_slack}, "
        f"bulge {args.centred_bulge}; θ within 5° and ρ within 0.05, per-demo fits"
    )
    print(
        "| task | refined | human: lopsided | human: others | operators: steady | "
        "operators: wobbly | time |"
    )
    print("|---|---|---|---|---|---|---|")
    refined = span_fit.refine_fit
    for task in args.tasks.split(","):
        for refine in (False, True) if args.refine_both else (True,):
            span_fit.refine_fit = refined if refine else _unrefined  # type: ignore[assignment]
            start = time.perf_counter()
            kinds = measure(cast(Task, task), args.seeds, args.first_seed)
            cells = " | ".join(_cell(np.array(v), args.refine_both) for v in kinds.values())
            seconds = time.perf_counter() - start
            print(
                f"| {task} | {'yes' if refine else 'no'} | {cells} | {seconds:.0f} s |", flush=True
            )
        if args.oracle:
            kinds = measure(cast(Task, task), args.seeds, args.first_seed, oracle=True)
            cells = " | ".join(_cell(np.array(v), True) for v in kinds.values())
            print(f"| {task} | oracle similarity | {cells} | — |", flush=True)
    span_fit.refine_fit = refined


def _cell(errors: np.ndarray, medians: bool) -> str:
    """Share within 5° and 0.05 (count), and with `medians` the median |Δθ| / |Δρ|."""
    hit = np.mean((errors[:, 0] < 5.0) & (errors[:, 1] < 0.05))
    cell = f"{100 * hit:.0f}% ({len(errors)})"
    if medians:
        cell += f", {np.median(errors[:, 0]):.2f}° / {np.median(errors[:, 1]):.4f}"
    return cell


if __name__ == "__main__":
    main()
