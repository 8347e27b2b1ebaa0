"""Per naive demo, the relative θ/ρ the cleaner reads on loops no guide draws, against the truth.

For ``make_human_set(task, 4, seed, hidden=True, shape=draw_set_loop(kind, seed, task))`` (D1,
human style, θ/ρ hidden in every set), each naive demo's θ and ρ relative to the expert-like
demo's, as ``bt clean`` reads them, minus the same from the generator's truth attrs; and the
demo's shape ratio after / before against its true loop (``synth_truth.truth_ratios``). The
summary splits the naive demos into lopsided (one side drawn 20-35 % bigger) or not, and single
loops (under 1.5) or several, and counts those read more than 8 % off in ρ or 10° off in θ.
``--per-demo`` prints every demo. The truth is never used by the cleaner.

    python benchmarks/quality/bench_relative_errors.py --kinds random --seeds 12
"""

from __future__ import annotations

import argparse
from collections import defaultdict

from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.random_loops import draw_set_loop
from bt_pipeline.data.synth_human import make_human_set
from bt_pipeline.data.synth_truth import truth_ratios
from bt_pipeline.data.tasks import TASKS


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--kinds", default="random,varied")
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument("--per-demo", action="store_true")
    args = parser.parse_args()
    groups: dict[tuple[str, str, str], list[tuple[float, float, float]]] = defaultdict(list)
    for kind in args.kinds.split(","):
        for task in args.tasks.split(","):
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                synth = make_human_set(
                    task, 4, seed, hidden=True, shape=draw_set_loop(kind, seed, task)
                )
                demos = demos_from_recording(synth.recording)
                result = clean_demos(demos, CleanOptions(seed=seed, progress=False))
                e = synth.expert_index
                expert, read = synth.demos[e], result.preferences[e]
                for i, truth in enumerate(synth.demos):
                    if i == e:
                        continue
                    p = result.preferences[i]
                    turn = (p.theta_deg - read.theta_deg) - (truth.theta_deg - expert.theta_deg)
                    turn = (turn + 180.0) % 360.0 - 180.0
                    scale = (p.rho / read.rho) / (truth.rho / expert.rho) - 1.0
                    shape, _ = truth_ratios(
                        truth.record, demos[i].raw_samples(), result.on_raw_times(i)
                    )
                    lopsided = "lopsided" if "lopsided" in truth.defects else "not lopsided"
                    loops = "single loop" if truth.cycles < 1.5 else "several loops"
                    groups[(kind, lopsided, loops)].append((turn, scale, shape))
                    if args.per_demo:
                        print(
                            f"{kind} {task} seed {seed} demo {i}: {truth.cycles:.2f} loops, "
                            f"Δθ {turn:+.1f}°, Δρ {100 * scale:+.1f} %, shape {shape:.2f}, "
                            f"{','.join(truth.defects)}",
                            flush=True,
                        )
    print(
        "| loops | naive demos | lopsided | loops drawn | ρ off > 8 % | θ off > 10° | "
        "worst Δρ | mean shape |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for (kind, lopsided, loops), rows in sorted(groups.items()):
        scales = [r[1] for r in rows]
        print(
            f"| {kind} | {len(rows)} | {lopsided} | {loops} | "
            f"{sum(abs(s) > 0.08 for s in scales)} | {sum(abs(r[0]) > 10.0 for r in rows)} | "
            f"{100 * max(scales, key=abs):+.1f} % | {sum(r[2] for r in rows) / len(rows):.2f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
