"""How much of their true loops a crowd's demos cover, raw and cleaned (the conditioned
protocol's "why": a learner gets no example of a part its demos leave out).

Per (task, seed) of a crowd (:func:`bt_pipeline.evaluate.crowd_sets.prepare_crowd`): each demo's
share of its true loop within τ (default 10 mm) of its samples, raw and cleaned; the demos other
than the cleaner's best apart from the best one; the expert-like demo marked ``*``.

    python benchmarks/evaluation/bench_crowd_coverage.py --crowd shared --seeds 2
"""

from __future__ import annotations

import argparse

import numpy as np

from bt_pipeline.data.synth_crowd import make_crowd_set
from bt_pipeline.data.tasks import TASKS
from bt_pipeline.evaluate.crowd_sets import CROWDS, CrowdSettings, prepare_crowd


def main() -> None:
    parser = argparse.ArgumentParser(description="Coverage of true loops, raw and cleaned")
    parser.add_argument("--crowd", default="shared", choices=CROWDS)
    parser.add_argument("--seeds", type=int, default=2)
    args = parser.parse_args()
    others: dict[str, list[float]] = {"noisy": [], "cleaned": []}
    for task in TASKS:
        for seed in range(args.seeds):
            p = prepare_crowd((seed, "D1", task, args.crowd, CrowdSettings(), None))
            expert = (
                make_crowd_set(task, 4, seed).expert_index if args.crowd != "independent" else -1
            )
            cells = []
            for name in ("noisy", "cleaned"):
                cov = p.coverage[name]  # type: ignore[index]
                others[name] += [float(c) for i, c in enumerate(cov) if i != p.best]
                marks = " ".join(f"{c:.2f}{'*' if i == expert else ''}" for i, c in enumerate(cov))
                cells.append(f"{name} {marks}")
            print(f"{task} seed {seed} (best demo {p.best}): " + " | ".join(cells))
    for name, values in others.items():
        v = np.array(values)
        print(
            f"demos other than the best, {name}: mean {v.mean():.2f}, range {v.min():.2f}-"
            f"{v.max():.2f}, ≥ 0.9 in {np.mean(v >= 0.9):.0%}"
        )


if __name__ == "__main__":
    main()
