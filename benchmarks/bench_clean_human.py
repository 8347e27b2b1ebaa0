"""Cleaning quality on demos shaped like people record them, against stored ground truth.

For each task, seed, size (D1 = 4 demos, D2 = 20) and style (``human``: rest, approach, 1-4
loops, pauses, uneven times, hidden θ/ρ in half the sets; ``single``: the default one-loop
style) it cleans the set and reports, for naive demos, the after/before ratios of

- **shape**: symmetric Chamfer distance to the true shape, both curves densified (1 mm spacing)
  first; "before" is the raw demo on its true loop part, "after" the cleaned output (kept span);
- **timing**: mean distance, at each output sample time, to the intended path at the demo's
  own timing (for the single style: its truth loop at its own phase is not stored, so only
  shape is reported);

plus the expert-like demo's ratios, the share of sets whose best demo is the expert, and the
share of hidden-θ/ρ demos estimated within 5° and 0.05.

    python benchmarks/bench_clean_human.py --seeds 2 --presets D1
"""

from __future__ import annotations

import argparse
from collections import defaultdict

import numpy as np
from scipy.spatial import cKDTree

from bt_pipeline.clean.guide_fit import arc_length_resample
from bt_pipeline.clean.periodic import output_on_raw_times
from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.synth_human import make_human_set
from bt_pipeline.data.tasks import TASKS


def dense(path: np.ndarray) -> np.ndarray:
    """The polyline resampled at about 1 mm spacing."""
    length = float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1)))
    return arc_length_resample(path, max(16, int(length / 0.001)))


def chamfer(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric Chamfer distance of two densified polylines [m]."""
    da, db = dense(a), dense(b)
    return 0.5 * float(np.mean(cKDTree(db).query(da)[0]) + np.mean(cKDTree(da).query(db)[0]))


def measure(task: str, n: int, seed: int) -> dict[str, list[float]]:
    synth = make_human_set(task, n, seed)
    demos = demos_from_recording(synth.recording)
    result = clean_demos(demos, CleanOptions(seed=seed, progress=False))
    out: dict[str, list[float]] = defaultdict(list)
    out["selected"].append(float(result.best_index == synth.expert_index))
    for i, truth in enumerate(synth.demos):
        raw_uv, raw_t = demos[i].raw_samples()
        t, cleaned = output_on_raw_times(result.demos[i], result.positions[i])
        idx = np.searchsorted(raw_t, t)
        true_loop = truth.truth_uv[truth.on_loop]
        shape = chamfer(cleaned, true_loop) / chamfer(raw_uv[truth.on_loop], true_loop)
        before = np.mean(np.linalg.norm(raw_uv[idx] - truth.truth_uv[idx], axis=1))
        after = np.mean(np.linalg.norm(cleaned - truth.truth_uv[idx], axis=1))
        kind = "expert" if truth.is_expert else "naive"
        out[f"{kind}_shape"].append(shape)
        out[f"{kind}_timing"].append(after / before)
        if synth.hidden:
            p = result.preferences[i]
            ok = abs(p.theta_deg - truth.theta_deg) < 5 and abs(p.rho - truth.rho) < 0.05
            out["hidden_ok"].append(float(ok))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--presets", default="D1,D2")
    parser.add_argument("--tasks", default=",".join(TASKS))
    args = parser.parse_args()
    sizes = {"D1": 4, "D2": 20}
    print("| task | set | naive shape | naive timing | expert shape | expert timing | best = expert | hidden θ/ρ ok |")
    print("|---|---|---|---|---|---|---|---|")
    for task in args.tasks.split(","):
        for preset in args.presets.split(","):
            runs: dict[str, list[float]] = defaultdict(list)
            for seed in range(args.seeds):
                for key, values in measure(task, sizes[preset], seed).items():
                    runs[key].extend(values)

            def m(key: str, runs: dict[str, list[float]] = runs) -> str:
                return f"{np.mean(runs[key]):.2f}" if runs[key] else "—"

            hidden = f"{100 * np.mean(runs['hidden_ok']):.0f}%" if runs["hidden_ok"] else "—"
            print(
                f"| {task} | {preset} | {m('naive_shape')} | {m('naive_timing')} | "
                f"{m('expert_shape')} | {m('expert_timing')} | "
                f"{100 * np.mean(runs['selected']):.0f}% | {hidden} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
