"""Time ``bt reproduce``: the quick (CI) and the full run, with the training time of each learner.

Each run is the library path of ``bt reproduce`` (synthetic D1 and D2 × 3 tasks: generate,
clean, train 4 learners on noisy and cleaned demos, roll out, measure, write the report). The
table gives wall time, CPU time (this process and its workers), the share spent cleaning, and the
optimiser-loop time of each learner summed over the run's 12 trainings per learner (6 jobs ×
noisy/cleaned). The machine is shared, so a fixed baseline workload (quick BC on wiping D1,
median of 3) is timed before and after and every run is also given in baseline units.

    python benchmarks/evaluation/bench_reproduce.py                  # quick and full
    python benchmarks/evaluation/bench_reproduce.py --runs quick     # quick only
    python benchmarks/evaluation/bench_reproduce.py --workers 2      # both cores
    python benchmarks/evaluation/bench_reproduce.py --runs quick --estimate-full --workers 2
    python benchmarks/evaluation/bench_reproduce.py --runs quick --repeats 3 --workers 2  # median

Processes against Ray, and the whole ``bt reproduce --quick`` command (conditioned protocol
included): benchmarks/evaluation/bench_reproduce_executors.py.

``--estimate-full`` projects the full run (``bt reproduce --oracle``: 3 seeds, 50 rollouts, the
truth rows) from per-job CPU costs instead of running it: for seed 0 of every (set, task) the
preparation job (generate, clean, yardstick) and its 12 learner jobs (4 learners × noisy, cleaned,
truth), and one competence check per learner (plus one conditioned four-demonstrator check,
quick presets), are run in this process and timed by CPU time. Seeds 1 and 2 are taken to cost
what seed 0 costs, and every competence check of a learner what its measured check of that kind
costs. On a busy machine ``--estimate-tasks weaving
--estimate-noisy-only`` measures less (one task per set, the noisy dataset only) and projects the
rest from it: a learner job's cost is set by the learner's steps and batch, not by the data.
The projected wall time schedules those costs on the workers exactly
as ``run_reproduce`` does (stage 1 in order, stage 2 longest first by ``job_cost``, each job to
the first free worker), plus the start-up of the two stages' worker pools (measured: a spawned
process importing the job module). CPU time is what a loaded machine inflates least, so this is
the way to estimate the full run on a shared machine.
"""

from __future__ import annotations

import argparse
import heapq
import multiprocessing
import resource
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.synth import make_d1
from bt_pipeline.evaluate.learners import LEARNERS, learner_config, train_learner
from bt_pipeline.evaluate.reproduce import write_outputs
from bt_pipeline.evaluate.reproduce_jobs import (
    COMPETENCE_COST,
    LearnerJob,
    ReproduceConfig,
    job_cost,
    prepare_set,
    run_competence,
    run_learner,
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


def makespan(costs: list[float], workers: int) -> float:
    """Wall time of jobs with these costs [s] handed in order to the first free of `workers`."""
    free = [0.0] * workers
    for cost in costs:
        heapq.heappush(free, heapq.heappop(free) + cost)
    return max(free)


def _import_jobs() -> None:
    import bt_pipeline.evaluate.reproduce_jobs  # noqa: F401  # what a worker imports


def startup_seconds() -> float:
    """Wall time to spawn a process that imports the job module and exits [s]."""
    start = time.perf_counter()
    process = multiprocessing.get_context("spawn").Process(target=_import_jobs)
    process.start()
    process.join()
    return time.perf_counter() - start


def estimate_full(workers: int, tasks: tuple[str, ...], all_datasets: bool) -> dict[str, float]:
    """CPU cost and projected wall time of the full run (3 seeds, oracle) from one seed [s].

    Only `tasks` are measured (a task not measured costs what the measured ones of its set cost
    on average, learner by learner); without `all_datasets` only the noisy dataset is trained and
    the cleaned and truth jobs are taken to cost the same (same learner, steps and batch; the
    demos differ only in their positions).
    """
    config = ReproduceConfig.preset(False, oracle=True)
    prepare: list[float] = []
    measured: dict[tuple[str, str, str, str], float] = {}  # (set, task, dataset, learner): CPU
    for set_name in config.sets:
        for task in config.tasks:
            if task not in tasks:
                continue
            cpu0 = cpu_seconds()
            p = prepare_set((0, set_name, task, config))
            prepare.append(cpu_seconds() - cpu0)
            for dataset, (positions, demonstrators) in p.data.items():
                if dataset != "noisy" and not all_datasets:
                    continue
                for learner in config.learners:
                    job = LearnerJob(
                        task,
                        learner,
                        dataset,
                        positions,
                        demonstrators,
                        config.eval_config(0),
                        p.yardstick,
                        p.x0,
                    )
                    cpu0 = cpu_seconds()
                    run_learner(job)
                    measured[(set_name, task, dataset, learner)] = cpu_seconds() - cpu0
            print(
                f"  {set_name} {task}: prepare {prepare[-1]:.0f} s CPU; learner jobs [s CPU]: "
                + ", ".join(
                    f"{d} {lr} {c:.0f}"
                    for (s, t, d, lr), c in measured.items()
                    if (s, t) == (set_name, task)
                ),
                flush=True,
            )
    prepare = [statistics.mean(prepare)] * (len(config.sets) * len(config.tasks))
    stage2: list[tuple[float, float]] = []  # (job_cost, projected CPU)
    for set_name in config.sets:
        for task in config.tasks:
            for dataset in ("noisy", "cleaned", "truth"):
                for learner in config.learners:
                    same = [
                        c for (s, t, d, lr), c in measured.items()
                        if s == set_name and lr == learner and (t == task or task not in tasks)
                        and (d == dataset or not all_datasets)
                    ]  # fmt: skip
                    demos = 4 if set_name == "D1" else 20
                    stage2.append((job_cost(learner, config, demos), statistics.mean(same)))
    competence: dict[str, float] = {}
    conditioned: dict[str, float] = {}  # the four_conditioned check: quick presets
    for learner in config.learners:
        cpu0 = cpu_seconds()
        run_competence(("one", "weaving", learner, config))
        competence[learner] = cpu_seconds() - cpu0
        cpu0 = cpu_seconds()
        run_competence(("four_conditioned", "weaving", learner, config))
        conditioned[learner] = cpu_seconds() - cpu0
        print(
            f"  competence checks weaving {learner}: {competence[learner]:.0f} s CPU, "
            f"conditioned {conditioned[learner]:.0f} s CPU",
            flush=True,
        )
    stage2 = stage2 * config.seeds
    quick = replace(config, quick=True)
    stage2 += [
        (job_cost(learner, config) * COMPETENCE_COST, competence[learner])
        for _ in range(2 * len(config.tasks))
        for learner in config.learners
    ]
    stage2 += [
        (job_cost(learner, quick) * COMPETENCE_COST, conditioned[learner])
        for _ in config.tasks
        for learner in config.learners
    ]
    checks_cpu = sum(competence.values()) * 2 * len(config.tasks) + sum(conditioned.values()) * len(
        config.tasks
    )
    stage2.sort(key=lambda pair: -pair[0])  # the order run_reproduce submits them in
    startup = startup_seconds()
    cpu_prepare = sum(prepare) * config.seeds
    cpu_stage2 = sum(cost for _, cost in stage2)
    wall = (
        makespan(prepare * config.seeds, workers)
        + makespan([cost for _, cost in stage2], workers)
        + 2 * startup
    )
    return {
        "prepare": cpu_prepare,
        "learners": cpu_stage2 - checks_cpu,
        "competence": checks_cpu,
        "cpu": cpu_prepare + cpu_stage2,
        "startup": startup,
        "wall": wall,
        "ideal": (cpu_prepare + cpu_stage2) / workers,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description="Time bt reproduce (quick and full).")
    parser.add_argument("--runs", default="quick,full", help="comma-separated: quick, full")
    parser.add_argument("--workers", type=int, default=1, help="jobs in parallel (processes)")
    parser.add_argument("--out", type=Path, default=None, help="keep each run's report here")
    parser.add_argument("--repeats", type=int, default=1, help="runs of each kind (median shown)")
    parser.add_argument(
        "--estimate-full", action="store_true", help="project the full run from per-job CPU costs"
    )
    parser.add_argument(
        "--estimate-tasks", default="wiping,weaving,pick_and_place", help="tasks to measure"
    )
    parser.add_argument(
        "--estimate-noisy-only",
        action="store_true",
        help="train only the noisy dataset; cleaned and truth jobs cost the same",
    )
    args = parser.parse_args()
    runs = [r.strip() for r in args.runs.split(",") if r.strip()]
    before = baseline_seconds()
    rows: dict[str, dict[str, float]] = {}
    for run in runs:
        repeats = [measure(run == "quick", args.workers, args.out) for _ in range(args.repeats)]
        for k, row in enumerate(repeats):
            rows[f"{run} #{k + 1}" if args.repeats > 1 else run] = row
        if args.repeats > 1:
            rows[f"{run} median"] = {
                key: statistics.median(r[key] for r in repeats) for key in repeats[0]
            }
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
        "\nclean: summed over the preparation jobs; evaluate: summed over the learner jobs "
        "(per-job wall time; with workers > 1 they overlap). Learner columns: optimiser-loop "
        "time summed over the learner jobs' trainings (competence checks not included)."
    )
    if args.estimate_full:
        print("\nEstimating the full run (3 seeds) from per-job CPU costs:")
        tasks = tuple(t.strip() for t in args.estimate_tasks.split(",") if t.strip())
        est = estimate_full(args.workers, tasks, not args.estimate_noisy_only)
        print(
            f"full run: preparation {est['prepare']:.0f} s CPU + learner jobs "
            f"{est['learners']:.0f} s CPU + competence checks {est['competence']:.0f} s CPU = "
            f"{est['cpu']:.0f} s CPU; worker start-up {est['startup']:.1f} s per stage.\n"
            f"On an idle machine with {args.workers} worker(s): about {est['wall'] / 60:.1f} min "
            f"wall as scheduled (CPU / workers: {est['ideal'] / 60:.1f} min)"
        )


if __name__ == "__main__":
    main()
