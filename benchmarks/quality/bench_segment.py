"""Segmentation and θ/ρ estimation on human-style demos, against their stored ground truth.

For every demo of ``make_human_set(task, 4, seed, hidden=True)`` (seeds 0..S-1, the three
tasks) it runs :func:`bt_pipeline.clean.segment.segment_demo` with θ/ρ unknown and compares

- the kept span with the true loop part (``truth_on_loop``): start and end errors [s];
- the estimated θ/ρ with ``truth_theta_deg`` / ``truth_rho``: the share within 5° and 0.05,

overall, for the expert-like demos and per defect. Truth comes from the files' own attrs, never
from the segmentation.

    python benchmarks/quality/bench_segment.py --seeds 10
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bt_pipeline.clean.segment import segment_demo
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.synth_human import make_human_set
from bt_pipeline.data.tasks import TASKS

_DEFECTS = ("lopsided", "drift", "jitter", "tremor", "spikes", "incomplete", "speed", "hesitation")


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    args = parser.parse_args()
    rows = []
    start = time.perf_counter()
    for task in TASKS:
        for seed in range(args.seeds):
            synth = make_human_set(task, 4, seed, hidden=True)
            for demo, human in zip(demos_from_recording(synth.recording), synth.demos, strict=True):
                x, t = demo.raw_samples()
                segment = segment_demo(x, t, task, demo.label)
                on_t = t[human.on_loop]
                rows.append(
                    (
                        segment.guide.theta_deg - human.theta_deg,
                        segment.guide.rho - human.rho,
                        segment.start_s - on_t[0],
                        segment.end_s - on_t[-1],
                        human.defects or ("expert",),
                    )
                )
    seconds = time.perf_counter() - start
    errors = np.array([r[:4] for r in rows])
    ok = (np.abs(errors[:, 0]) < 5.0) & (np.abs(errors[:, 1]) < 0.05)
    span_ok = np.all(np.abs(errors[:, 2:]) <= 0.4, axis=1)
    print(f"{len(rows)} demos, {seconds:.1f} s")
    print(
        "| demos | n | θ within 5° and ρ within 0.05 | start error p10 / p50 / p90 [s] | "
        "end error p10 / p50 / p90 [s] | span within 0.4 s |"
    )
    print("|---|---|---|---|---|---|")
    for name in ("all", "expert", *_DEFECTS):
        pick = np.array([name == "all" or name in r[4] for r in rows])
        if not pick.any():
            continue
        s, e = errors[pick, 2], errors[pick, 3]
        print(
            f"| {name} | {pick.sum()} | {100 * ok[pick].mean():.0f}% | "
            f"{' / '.join(f'{v:+.2f}' for v in np.percentile(s, [10, 50, 90]))} | "
            f"{' / '.join(f'{v:+.2f}' for v in np.percentile(e, [10, 50, 90]))} | "
            f"{100 * span_ok[pick].mean():.0f}% |"
        )


if __name__ == "__main__":
    main()
