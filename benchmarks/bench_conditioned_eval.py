"""Does cleaning help a learner that keeps each demonstrator's preference? Paired over seeds.

For each task, crowd kind (``independent``: every naive demo its own defects, bt synth's default;
``shared``: the naive demos share a corner cut, an undershot stretch, a pause place and a
backwards minority, :mod:`bt_pipeline.data.synth_crowd`) and seed, it makes a D1 set, cleans it,
and trains every learner, conditioned on each demo's (θ, ρ), on four datasets of the same set:
the noisy demos, the cleaned ones, and the generator's truth, shape-only (each true loop at the
canonical speed) and shape-plus-timing (the intended path at the demo's own timing). Each policy
is rolled out 12 times per demonstrator from its true loop (2 % noise) and scored over the second
period against that demonstrator's own true loop (:mod:`bt_pipeline.evaluate.conditioned`).

Per cell (task, kind, learner) over seeds, on success at τ = 10 mm and on shape distance:
the truth gate (shape-only truth beats noisy, paired t-test p < 0.01), then cleaned vs noisy
(paired, p < 0.05) and the share of the gap recovered with a bootstrap interval
(:mod:`bt_pipeline.evaluate.stats`). ``--unconditioned`` adds the paper's unconditioned learners
(one policy over four preferences) for the same cells.

    python benchmarks/bench_conditioned_eval.py --seeds 10 --learners bc --workers 2
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.data.demo import Demo, demos_from_recording
from bt_pipeline.data.synth import make_d1
from bt_pipeline.data.synth_crowd import make_crowd_set
from bt_pipeline.data.tasks import TASKS
from bt_pipeline.evaluate.conditioned import evaluate_conditioned, loops_by_demonstrator
from bt_pipeline.evaluate.learners import LearnerName
from bt_pipeline.evaluate.reproduce_jobs import truth_demos
from bt_pipeline.evaluate.stats import verdict

DATASETS = ("noisy", "cleaned", "truth_shape", "truth_timing")
TAU_MM = 10.0


def timed_truth(demos: list[Demo], recording_demos: list) -> list[Demo]:
    """Each demo's intended path at its own timing (the truth_uv attr), N samples."""
    out = []
    for demo, record in zip(demos, recording_demos, strict=True):
        uv = np.asarray(record.attrs["truth_uv"], dtype=np.float64)
        t = np.asarray(record.timestamps, dtype=np.float64)
        s = np.linspace(t[0], t[-1], demo.n_samples)
        out.append(demo.with_positions(np.stack([np.interp(s, t, uv[:, j]) for j in range(2)], 1)))
    return out


def run_unit(job: tuple[str, str, int, tuple[str, ...], bool, bool]) -> list[dict]:
    """Every learner on every dataset of one (task, kind, seed)."""
    task, kind, seed, learners, quick, unconditioned = job
    synth = make_d1(task, seed) if kind == "independent" else make_crowd_set(task, 4, seed)
    demos = demos_from_recording(synth.recording)
    result = clean_demos(demos, CleanOptions(seed=seed, write_rrd=False, progress=False))
    truths = [d.truth for d in synth.demos]
    datasets = {
        "noisy": demos,
        "cleaned": [d.with_positions(result.positions[i]) for i, d in enumerate(demos)],
        "truth_shape": truth_demos(demos, truths),
        "truth_timing": timed_truth(demos, list(synth.recording.demos.values())),
    }
    prefs = np.array([[d.theta_deg, d.rho] for d in demos], dtype=np.float64)
    names = [d.demonstrator for d in demos]
    loops, _ = loops_by_demonstrator(names, prefs, truths)
    rows = []
    for learner in learners:
        for conditioned in (True, False) if unconditioned else (True,):
            for name, ds in datasets.items():
                start = time.perf_counter()
                e = evaluate_conditioned(
                    learner,  # type: ignore[arg-type]
                    name,
                    np.stack([d.positions for d in ds]),
                    prefs,
                    loops,
                    seed=seed,
                    quick=quick,
                    demonstrators=names,
                    conditioned=conditioned,
                )
                rows.append(
                    {
                        "task": task,
                        "kind": kind,
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
        f"| task | crowd | learner | success@{TAU_MM:.0f} mm noisy / cleaned / truth (shape, "
        "timing) | shape [mm] noisy / cleaned / truth | robust success noisy / cleaned | "
        "verdict on success | verdict on shape |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for (task, kind, learner), by_dataset in cells.items():
        seeds = sorted(by_dataset["noisy"])

        def values(
            dataset: str, key: str, by_dataset: dict = by_dataset, seeds=seeds
        ) -> np.ndarray:
            return np.array([by_dataset[dataset][s][key] for s in seeds])

        success = {d: values(d, "success") for d in DATASETS}
        shape = {d: values(d, "shape_mm") for d in DATASETS}
        on_success = verdict(
            success["noisy"], success["cleaned"], success["truth_shape"], higher_is_better=True
        )
        on_shape = verdict(
            shape["noisy"], shape["cleaned"], shape["truth_shape"], higher_is_better=False
        )
        print(
            f"| {task} | {kind} | {learner} | "
            + " / ".join(f"{success[d].mean():.2f}" for d in DATASETS)
            + " | "
            + " / ".join(f"{shape[d].mean():.1f}" for d in DATASETS)
            + f" | {values('noisy', 'robust').mean():.2f} / "
            + f"{values('cleaned', 'robust').mean():.2f}"
            + f" | {on_success.summary()} | {on_shape.summary()} |",
            flush=True,
        )
    print(f"\n{len(jobs)} sets, {time.perf_counter() - start:.0f} s wall")


if __name__ == "__main__":
    main()
