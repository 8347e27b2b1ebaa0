"""Does cleaning help a learner that keeps each demonstrator's preference? Paired over seeds.

For each task, crowd kind (``independent``: every naive demo its own defects, bt synth's default;
``shared``: the naive demos share a corner cut, an undershot stretch, a pause place and a
backwards minority, :mod:`bt_pipeline.data.synth_crowd`) and seed, it makes a D1 set, cleans it,
and trains every learner, conditioned on each demo's (θ, ρ), on five datasets of the same set
(:func:`bt_pipeline.evaluate.crowd_sets.prepare_crowd`, as ``bt reproduce`` does): the noisy
demos, the cleaned ones, the best demo's loop aligned to each demo, and the generator's truth,
shape-only and shape-plus-timing. Each policy
is rolled out 12 times per demonstrator from its true loop (2 % noise) and scored over the second
period against that demonstrator's own true loop (:mod:`bt_pipeline.evaluate.conditioned`).

Per cell (task, kind, learner) over seeds, on success at τ = 10 mm and on shape distance:
the truth gate (shape-only truth beats noisy, paired t-test p < 0.01), then cleaned vs noisy
(paired, p < 0.05) and the share of the gap recovered with a bootstrap interval
(:mod:`bt_pipeline.evaluate.stats`). ``--unconditioned`` adds the paper's unconditioned learners
(one policy over four preferences) for the same cells.

    python benchmarks/evaluation/bench_conditioned_eval.py --seeds 10 --learners bc --workers 2
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from bt_pipeline.data.tasks import TASKS
from bt_pipeline.evaluate.conditioned import evaluate_conditioned
from bt_pipeline.evaluate.crowd_sets import CROWD_DATASETS, CrowdSettings, prepare_crowd
from bt_pipeline.evaluate.learners import LearnerName
from bt_pipeline.evaluate.stats import verdict

TAU_MM = 10.0


def run_unit(job: tuple[str, str, int, tuple[str, ...], bool, bool]) -> list[dict]:
    """Every learner on every dataset of one (task, crowd, seed)."""
    task, crowd, seed, learners, quick, unconditioned = job
    prepared = prepare_crowd((seed, "D1", task, crowd, CrowdSettings(), None))  # type: ignore[arg-type]
    rows = []
    for learner in learners:
        for conditioned in (True, False) if unconditioned else (True,):
            for name in CROWD_DATASETS:
                start = time.perf_counter()
                e = evaluate_conditioned(
                    learner,  # type: ignore[arg-type]
                    name,
                    prepared.positions[name],
                    prepared.preferences,
                    prepared.loops,
                    seed=seed,
                    quick=quick,
                    demonstrators=prepared.demonstrators,
                    conditioned=conditioned,
                )
                rows.append(
                    {
                        "task": task,
                        "kind": crowd,
                        "seed": seed,
                        "learner": learner if conditioned else f"{learner} (paper)",
                        "dataset": name,
                        "success": e.scores.success_rate(TAU_MM),
                        "shape_mm": float(np.mean(e.scores.shape_mm)),
                        "robust": e.robust.success_rate(TAU_MM),
                        "seconds": time.perf_counter() - start,
                    }
                )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument("--kinds", default="independent,shared")
    parser.add_argument("--learners", default="bc")
    parser.add_argument("--full", action="store_true", help="full learner presets (not quick)")
    parser.add_argument("--unconditioned", action="store_true", help="also the paper's learners")
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    learners: tuple[LearnerName, ...] = tuple(args.learners.split(","))  # type: ignore[assignment]
    jobs = [
        (task, kind, seed, learners, not args.full, args.unconditioned)
        for task in args.tasks.split(",")
        for kind in args.kinds.split(",")
        for seed in range(args.seeds)
    ]
    start = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        rows = [row for unit in pool.map(run_unit, jobs) for row in unit]
    cells: dict[tuple[str, str, str], dict[str, dict[int, dict]]] = defaultdict(
        lambda: defaultdict(dict)
    )
    for row in rows:
        cells[(row["task"], row["kind"], row["learner"])][row["dataset"]][row["seed"]] = row
    print(
        f"| task | crowd | learner | success@{TAU_MM:.0f} mm noisy / cleaned / best aligned / "
        "truth (shape, timing) | shape [mm] noisy / cleaned / best aligned / truth (shape, timing) "
        "| robust success noisy / cleaned | "
        "verdict on success | verdict on shape |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for (task, kind, learner), by_dataset in cells.items():
        seeds = sorted(by_dataset["noisy"])

        def values(
            dataset: str, key: str, by_dataset: dict = by_dataset, seeds=seeds
        ) -> np.ndarray:
            return np.array([by_dataset[dataset][s][key] for s in seeds])

        success = {d: values(d, "success") for d in CROWD_DATASETS}
        shape = {d: values(d, "shape_mm") for d in CROWD_DATASETS}
        on_success = verdict(
            success["noisy"], success["cleaned"], success["truth_shape"], higher_is_better=True
        )
        on_shape = verdict(
            shape["noisy"], shape["cleaned"], shape["truth_shape"], higher_is_better=False
        )
        print(
            f"| {task} | {kind} | {learner} | "
            + " / ".join(f"{success[d].mean():.2f}" for d in CROWD_DATASETS)
            + " | "
            + " / ".join(f"{shape[d].mean():.1f}" for d in CROWD_DATASETS)
            + f" | {values('noisy', 'robust').mean():.2f} / "
            + f"{values('cleaned', 'robust').mean():.2f}"
            + f" | {on_success.summary()} | {on_shape.summary()} |",
            flush=True,
        )
    print(f"\n{len(jobs)} sets, {time.perf_counter() - start:.0f} s wall")


if __name__ == "__main__":
    main()
