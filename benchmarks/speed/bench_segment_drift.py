"""What reading the span's drift (``guide_track.periodic_drift``) costs in segmentation.

Segments every demo of a human-style wiping set of 8 (θ/ρ hidden) ``--repeats`` times, after a
warm-up, and reports the median total, the median time spent inside ``periodic_drift`` and,
as the baseline in the same process, the median total with ``periodic_drift`` replaced by a
zero drift (the fits then take other paths, so the ratio is a bound, not the drift's share).

    python benchmarks/speed/bench_segment_drift.py --repeats 5
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import bt_pipeline.clean.segment as segment
import bt_pipeline.clean.span_fit as span_fit
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.synth_human import make_human_set


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    synth = make_human_set("wiping", 8, args.seed, hidden=True)
    samples = [d.raw_samples() for d in demos_from_recording(synth.recording)]
    original = span_fit.periodic_drift
    inside = [0.0]

    def timed(path, phase, degree):
        start = time.perf_counter()
        out = original(path, phase, degree)
        inside[0] += time.perf_counter() - start
        return out

    def run() -> float:
        start = time.perf_counter()
        for uv, t in samples:
            segment.segment_demo(uv, t, "wiping")
        return time.perf_counter() - start

    run()
    totals, drifts, zeros = [], [], []
    for _ in range(args.repeats):
        inside[0] = 0.0
        span_fit.periodic_drift = timed
        totals.append(run())
        drifts.append(inside[0])
        span_fit.periodic_drift = lambda path, phase, degree: np.zeros_like(path)
        zeros.append(run())
    span_fit.periodic_drift = original
    total, drift, zero = (float(np.median(v)) for v in (totals, drifts, zeros))
    print(
        "| demos | segment total [s] | inside periodic_drift [s] | per demo [ms] "
        "| zero drift [s] | total / zero drift |"
    )
    print("|---|---|---|---|---|---|")
    per_demo = 1e3 * drift / len(samples)
    print(
        f"| {len(samples)} | {total:.3f} | {drift:.3f} | {per_demo:.1f} "
        f"| {zero:.3f} | {total / zero:.2f} |"
    )


if __name__ == "__main__":
    main()
