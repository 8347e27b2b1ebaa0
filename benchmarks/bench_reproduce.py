"""Time ``bt reproduce``: the quick (CI) and the full run, with the training time of each learner.

Each run is the library path of ``bt reproduce`` (synthetic D1 and D2 × 3 tasks: generate,
clean, train 4 learners on noisy and cleaned demos, roll out, measure, write the report). The
table gives wall time, CPU time (this process and its workers), the share spent cleaning, and the
optimiser-loop time of each learner summed over the run's 12 trainings per learner (6 jobs ×
noisy/cleaned). The machine is shared, so a fixed baseline workload (quick BC on wiping D1,
median of 3) is timed before and after and every run is also given in baseline units.

    python benchmarks/bench_reproduce.py                  # quick and full
    python benchmarks/bench_reproduce.py --runs quick     # quick only
    python benchmarks/bench_reproduce.py --workers 2      # both cores
    python benchmarks/bench_reproduce.py --runs quick --estimate-full --workers 2

``--estimate-full`` projects the full run (3 seeds) from per-job CPU costs instead of running it:
one full-preset evaluation job of D1 and of D2 per task and one competence check per learner are
run in this process and timed by CPU time, then scaled by the number of jobs of the full run and
divided by the workers. CPU time is what a loaded machine inflates least, so this is the way to
estimate the full run on a shared machine.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.synth import make_d1
from bt_pipeline.evaluate.learners import LEARNERS, learner_config, train_learner
from bt_pipeline.evaluate.reproduce import write_outputs
from bt_pipeline.evaluate.reproduce_jobs import (
    ReproduceConfig,
    run_competence,
    run_job,
    run_reproduce,
)


def cpu_seconds() -> float:
    """User + system CPU time of this process and its finished children [s]."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def baseline_seconds(repeats: int = 3) -> float:
    """Median wall time of a fixed workload: quick BC on wiping D1 (seed 0)."""
    demos = np.stack([d.positions for d in demos_from_recording(make_d1("wiping", 0).recording)])
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        train_learner("bc", demos, None, learner_config("bc", quick=True))
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def measure(quick: bool, workers: int, out: Path | None) -> dict[str, float]:
    """One run of ``bt reproduce`` (``--quick`` or full) and its timings [s]."""
    config = ReproduceConfig.preset(quick, workers=workers)
    cpu0, wall0 = cpu_seconds(), time.perf_counter()
    run = run_reproduce(config, progress=False)
    with tempfile.TemporaryDirectory() as tmp:
        write_outputs(run, out / ("quick" if quick else "full") if out else Path(tmp))
    row = {"wall": time.perf_counter() - wall0, "cpu": cpu_seconds() - cpu0}
    row["clean"] = sum(j.clean_seconds for j in run.jobs)
    row["eval"] = sum(j.eval_seconds for j in run.jobs)
    row["jobs"] = len(run.jobs) + len(run.competence)
    for learner in LEARNERS:
        row[learner] = sum(
            r.train_seconds for j in run.jobs for r in j.evaluation.results if r.learner == learner
        )
    return row


def estimate_full(workers: int) -> dict[str, float]:
    """CPU cost of the full run (3 seeds) projected from one job of each kind [s]."""
    config = ReproduceConfig.preset(False)
    evaluation = 0.0
    for task in config.tasks:
        for set_name in config.sets:
            cpu0 = cpu_seconds()
            run_job((0, set_name, task, config))  # type: ignore[arg-type]  # a valid job
            cost = cpu_seconds() - cpu0
            print(f"  full evaluation job {set_name} {task}: {cost:.0f} s CPU", flush=True)
            evaluation += cost * config.seeds
    competence = 0.0
    for learner in config.learners:
        cpu0 = cpu_seconds()
        run_competence(("one", "weaving", learner, config))
        cost = cpu_seconds() - cpu0
        print(f"  competence check weaving {learner}: {cost:.0f} s CPU", flush=True)
        competence += cost * 2 * len(config.tasks)  # one and four demonstrators, every task
    total = evaluation + competence
    return {
        "evaluation": evaluation,
        "competence": competence,
        "cpu": total,
        "wall": total / workers,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description="Time bt reproduce (quick and full).")
    parser.add_argument("--runs", default="quick,full", help="comma-separated: quick, full")
    parser.add_argument("--workers", type=int, default=1, help="jobs in parallel (processes)")
    parser.add_argument("--out", type=Path, default=None, help="keep each run's report here")
    parser.add_argument(
        "--estimate-full", action="store_true", help="project the full run from per-job CPU costs"
    )
    args = parser.parse_args()
    runs = [r.strip() for r in args.runs.split(",") if r.strip()]
    before = baseline_seconds()
    rows = {run: measure(run == "quick", args.workers, args.out) for run in runs}
    base = statistics.mean([before, baseline_seconds()])
    header = ["run", "wall [s]", "wall / baseline", "CPU [s]", "clean [s]", "evaluate [s]"]
    header += [f"{learner} train [s]" for learner in LEARNERS]
    print(f"baseline (quick BC, wiping D1): {base:.2f} s; workers = {args.workers}\n")
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for run, row in rows.items():
        cells = [run, f"{row['wall']:.0f}", f"{row['wall'] / base:.0f}", f"{row['cpu']:.0f}"]
        cells += [f"{row['clean']:.0f}", f"{row['eval']:.0f}"]
        cells += [f"{row[learner]:.0f}" for learner in LEARNERS]
        print("| " + " | ".join(cells) + " |")
    print(
        "\nclean and evaluate: summed over the evaluation jobs (per-job wall time; with "
        "workers > 1 they overlap). Learner columns: optimiser-loop time summed over the "
        "evaluation jobs' trainings (competence checks not included)."
    )
    if args.estimate_full:
        print("\nEstimating the full run (3 seeds) from per-job CPU costs:")
        est = estimate_full(args.workers)
        print(
            f"full run: evaluation jobs {est['evaluation']:.0f} s CPU + competence checks "
            f"{est['competence']:.0f} s CPU = {est['cpu']:.0f} s CPU; on an idle machine with "
            f"{args.workers} worker(s) about {est['wall'] / 60:.1f} min wall"
        )


if __name__ == "__main__":
    main()
