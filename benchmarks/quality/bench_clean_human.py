"""Cleaning quality on demos shaped like people record them, against stored ground truth.

For each task, seed, size (D1 = 4 demos, D2 = 20) and style (``human``: rest, approach, 1-4
loops, pauses, uneven times, hidden θ/ρ in half the sets; ``single``: the default one-loop
style) it cleans the set and reports, for naive demos, the after/before ratios of

- **shape**: symmetric Chamfer distance to the true shape, both curves densified (0.1 mm spacing)
  first; "before" is the raw demo on its true loop part, "after" the cleaned output (kept span);
- **timing**: mean distance, at each output sample time, to the intended path at the demo's
  own timing; "before" is the raw demo at the same times;

plus the expert-like demo's ratios, the share of sets whose best demo is the expert, the
share of hidden-θ/ρ demos estimated within 5° and 0.05, and the naive ratios over the sets whose
θ/ρ are hidden alone (what a user whose files lack θ/ρ can expect).

Truth comes from the files' own attrs (bt_pipeline.data.synth_truth), not from the cleaner.

    python benchmarks/quality/bench_clean_human.py --seeds 2 --presets D1,D2 --styles human,single

Held-out sets: ``--hidden all --first-seed 12`` draws every human-style set with θ/ρ hidden. Passing
`hidden` to the generator skips one draw of its random stream, so these are other sets than the
default seeds' (docs/quality.md's fresh-seed figures: ``--seeds 12 --first-seed 12 --presets D1
--styles human --shapes random,varied --hidden all``).

Chunking (issue 14): ``--chunk-sizes all,8 --presets D48`` cleans each set of 48 demos once as one
Stage 2 batch and once in chunks of at most 8 demos, with the same seed, and adds each run's K and
its wall time (median over the set's runs) to the rows, so the two rows of a set compare directly.
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict

import numpy as np

from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.random_loops import LoopKind, draw_set_loop
from bt_pipeline.data.synth import make_demo_set
from bt_pipeline.data.synth_human import make_human_set
from bt_pipeline.data.synth_truth import relative_hits, truth_ratios
from bt_pipeline.data.tasks import TASKS


def measure(
    task: str,
    n: int,
    seed: int,
    style: str,
    chunk_size: int = 10**9,
    loop_kind: LoopKind = "guide",
    all_hidden: bool = False,
) -> dict[str, list[float]]:
    """Ratios and rates of one cleaned set (Stage 2 in chunks of at most `chunk_size` demos),
    its demos drawing `loop_kind` (the task's guide, a varied guide or a loop drawn at random);
    with `all_hidden`, a human-style set with θ/ρ hidden (a held-out draw, module doc)."""
    loop = None if loop_kind == "guide" else draw_set_loop(loop_kind, seed, task)
    if style == "human":
        if all_hidden:
            synth = make_human_set(task, n, seed, hidden=True, shape=loop)
        else:
            synth = make_human_set(task, n, seed, shape=loop)
        hidden, expert, recording = synth.hidden, synth.expert_index, synth.recording
    else:
        single = make_demo_set(task, n, seed, shape=loop)
        hidden, expert, recording = False, single.expert_index, single.recording
    demos = demos_from_recording(recording)
    start = time.perf_counter()
    result = clean_demos(demos, CleanOptions(seed=seed, progress=False, chunk_size=chunk_size))
    out: dict[str, list[float]] = defaultdict(list)
    out["wall_s"].append(time.perf_counter() - start)
    out["selected"].append(float(result.best_index == expert))
    for i, record in enumerate(recording.demos.values()):
        shape, timing = truth_ratios(record, demos[i].raw_samples(), result.on_raw_times(i))
        kind = "expert" if i == expert else "naive"
        out[f"{kind}_shape"].append(shape)
        out[f"{kind}_timing"].append(timing)
        if hidden and kind == "naive":  # What a user whose files lack θ/ρ can expect.
            out["hidden_naive_shape"].append(shape)
            out["hidden_naive_timing"].append(timing)
        if hidden:
            out["learned"].append(float(result.loop is not None and result.loop.source != "guide"))
            p = result.preferences[i]
            theta, rho = record.attrs["truth_theta_deg"], record.attrs["truth_rho"]
            out["hidden_ok"].append(float(abs(p.theta_deg - theta) < 5 and abs(p.rho - rho) < 0.05))
            out["hidden_theta_ok"].append(float(abs(p.theta_deg - theta) < 5))
    if hidden:
        truth = [r.attrs for r in recording.demos.values()]
        hits = relative_hits(
            np.array([p.theta_deg for p in result.preferences]),
            np.array([p.rho for p in result.preferences]),
            np.array([float(a["truth_theta_deg"]) for a in truth]),
            np.array([float(a["truth_rho"]) for a in truth]),
        )
        out["relative_ok"].extend(hits.astype(float).tolist())
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument(
        "--hidden", choices=("half", "all"), default="half", help="human sets with θ/ρ hidden"
    )
    parser.add_argument("--presets", default="D1,D2")
    parser.add_argument("--styles", default="human,single")
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument("--chunk-sizes", default="all", help="K per run: all (one batch) or ints")
    parser.add_argument(
        "--shapes",
        default="guide",
        help="loops the demos draw, comma-separated: guide, varied, random or a family "
        "(oval, rounded_polygon, d_shape, figure_eight, arch, stroke, asymmetric)",
    )
    args = parser.parse_args()
    sizes = {"D1": 4, "D2": 20, "D48": 48}
    chunks = [10**9 if k == "all" else int(k) for k in args.chunk_sizes.split(",")]
    with_k = args.chunk_sizes != "all"
    print(
        "| style | task | set | naive shape (mean / worst) | naive timing (mean / worst) | "
        "expert shape (worst) | expert timing (worst) | best = expert | hidden θ within 5° | "
        "hidden θ within 5° and ρ within 0.05 | naive shape / timing, θ/ρ hidden (mean) | "
        "relative θ within 5° and ρ within 5 %, hidden | learned loop (hidden sets) |"
        + (" K | clean wall [s] |" if with_k else "")
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|" + ("---|---|" if with_k else ""))
    for style, shape in (
        (st, sh) for st in args.styles.split(",") for sh in args.shapes.split(",")
    ):
        for task in args.tasks.split(","):
            for preset, chunk_size in ((p, k) for p in args.presets.split(",") for k in chunks):
                runs: dict[str, list[float]] = defaultdict(list)
                for seed in range(args.first_seed, args.first_seed + args.seeds):
                    measured = measure(
                        task, sizes[preset], seed, style, chunk_size, shape, args.hidden == "all"
                    )
                    for key, values in measured.items():
                        runs[key].extend(values)
                k_label = "all" if chunk_size >= sizes[preset] else str(chunk_size)
                extra = f" {k_label} | {np.median(runs['wall_s']):.1f} |" if with_k else ""

                def pair(key: str, runs: dict[str, list[float]] = runs) -> str:
                    return f"{np.mean(runs[key]):.2f} / {np.max(runs[key]):.2f}"

                def share(key: str, runs: dict[str, list[float]] = runs) -> str:
                    return f"{100 * np.mean(runs[key]):.0f}%" if runs[key] else "—"

                hidden_means = (
                    f"{np.mean(runs['hidden_naive_shape']):.2f} / "
                    f"{np.mean(runs['hidden_naive_timing']):.2f}"
                    if runs["hidden_naive_shape"]
                    else "—"
                )

                print(
                    f"| {style} | {task} ({shape}) | {preset} | {pair('naive_shape')} | "
                    f"{pair('naive_timing')} | {np.max(runs['expert_shape']):.2f} | "
                    f"{np.max(runs['expert_timing']):.2f} | {share('selected')} | "
                    f"{share('hidden_theta_ok')} | {share('hidden_ok')} | {hidden_means} | "
                    f"{share('relative_ok')} | {share('learned')} |{extra}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
