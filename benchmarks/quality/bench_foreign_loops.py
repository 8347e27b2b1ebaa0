"""Cleaning quality on loops no guide draws: ``../shared/data/foreign-loops/`` against its truth.

Four sets of 8 human-style demos (a wiping oval with θ/ρ given and hidden, a D shape filed as
``scrubbing``, a rounded square filed as ``buffing``), made by a generator written apart from
bt's. Truth (``truth.json`` and ``<set>.truth.npz``: the intended path at each raw sample, the
loop part's sample range, θ and ρ) is the generator's; the cleaner never reads it. Per set:

- **shape**: symmetric Chamfer distance (both curves densified to 0.1 mm) to the intended loop
  part, cleaned output over raw loop part; naive demos' mean and worst, the expert's;
- **timing**: mean distance at each output sample time to the intended path, over the raw's;
- **best = expert**, the loop used (guide or learned), and for hidden θ/ρ the share of demos
  whose θ relative to the set's mean θ is within 5° and ρ relative to the set's geometric-mean
  ρ within 5 % (what a learned loop can identify).

    python benchmarks/quality/bench_foreign_loops.py [--root ../shared/data/foreign-loops]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repo root: benchmarks.common

import numpy as np

from benchmarks.common.paths import SHARED
from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.recording import read_recording
from bt_pipeline.data.synth_truth import relative_hits, shape_distance


def measure(root: Path, name: str, truth: dict, seed: int = 0) -> dict[str, object]:
    """Ratios and rates of one cleaned foreign set."""
    recording = read_recording(root / name)
    demos = demos_from_recording(recording)
    paths = np.load(root / name.replace(".hdf5", ".truth.npz"))
    start = time.perf_counter()
    result = clean_demos(demos, CleanOptions(seed=seed, progress=False, write_rrd=False))
    wall = time.perf_counter() - start
    shape, timing, kinds = [], [], []
    for i, demo in enumerate(demos):
        part = truth["demos"][demo.name]
        intended = paths[demo.name]
        x, t = demo.raw_samples()
        a, b = part["loop_start"], part["loop_end"]
        times, out = result.on_raw_times(i)
        at = np.clip(np.searchsorted(t, times - 1e-9), 0, t.size - 1)
        shape.append(shape_distance(out, intended[a:b]) / shape_distance(x[a:b], intended[a:b]))
        before = np.mean(np.linalg.norm(x[at] - intended[at], axis=1))
        timing.append(np.mean(np.linalg.norm(out - intended[at], axis=1)) / before)
        kinds.append("expert" if demo.name == truth["expert"] else "naive")
    naive = np.array([k == "naive" for k in kinds])
    hits = relative_hits(
        np.array([p.theta_deg for p in result.preferences]),
        np.array([p.rho for p in result.preferences]),
        np.array([truth["demos"][d.name]["theta_deg"] for d in demos]),
        np.array([truth["demos"][d.name]["rho"] for d in demos]),
    )
    return {
        "set": name,
        "loop": result.loop.source if result.loop else "?",
        "naive_shape": np.array(shape)[naive],
        "naive_timing": np.array(timing)[naive],
        "expert_shape": float(np.array(shape)[~naive].max()),
        "expert_timing": float(np.array(timing)[~naive].max()),
        "selected": demos[result.best_index].name == truth["expert"],
        "relative_hits": float(hits.mean()) if truth["hidden_preferences"] else None,
        "wall_s": wall,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    default = SHARED / "data" / "foreign-loops"
    parser.add_argument("--root", type=Path, default=default)
    args = parser.parse_args()
    truth = json.loads((args.root / "truth.json").read_text())
    print(
        "| set | loop used | naive shape (mean / worst) | naive timing (mean / worst) | "
        "expert shape | expert timing | best = expert | relative θ/ρ hits (hidden) | clean [s] |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for name in sorted(truth):
        m = measure(args.root, name, truth[name])
        ns, nt = np.asarray(m["naive_shape"]), np.asarray(m["naive_timing"])
        hits = m["relative_hits"]
        print(
            f"| {name} | {m['loop']} | {ns.mean():.2f} / {ns.max():.2f} | "
            f"{nt.mean():.2f} / {nt.max():.2f} | {m['expert_shape']:.2f} | "
            f"{m['expert_timing']:.2f} | {'yes' if m['selected'] else 'no'} | "
            f"{'—' if hits is None else f'{100 * float(str(hits)):.0f}%'} | {m['wall_s']:.1f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
