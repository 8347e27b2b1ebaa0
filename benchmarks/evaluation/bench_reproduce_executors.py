"""Time ``bt reproduce --quick`` on local worker processes against a local Ray: same results?

The aim (docs/evaluation.md, *Timings*): the quick run ≤ 5 min on the 2-core machine with
``--workers 2``, and faster on Ray (``--executor ray``) than on processes. Each run here is
``bt reproduce --quick --workers W --executor E`` through the command's own Python function
(:func:`bt_pipeline.cli.evaluate_commands.reproduce`: the conditioned protocol, then the paper's,
every figure and file), into a temporary directory. The executors alternate (processes, ray,
processes, ray, ...) so that a change in the shared machine's load falls on both alike; every Ray
run starts its private local Ray and shuts it down after, as one ``bt reproduce`` process does.
The table gives each run's wall time, the median per executor and the ratio ray / processes of
the medians, all measured in this one process; the 1-minute load average before each run says
how busy the machine was. Results do not depend on the executor: the script fails unless every
run's results.json is the same, number for number, once its wall and CPU timings are removed.

    # the measurement (about 6 × the quick run's 3-5 min; nothing else should run meanwhile)
    python benchmarks/evaluation/bench_reproduce_executors.py --repeats 3 --workers 2
    # the same with the truth rows (bt reproduce --quick --oracle)
    python benchmarks/evaluation/bench_reproduce_executors.py --repeats 3 --workers 2 --oracle
    # proves the script runs (about a minute): tiny settings, one run per executor
    python benchmarks/evaluation/bench_reproduce_executors.py --smoke
    # the paper's protocol alone (bt reproduce --quick --paper-only), either way
    python benchmarks/evaluation/bench_reproduce_executors.py --smoke --paper-only

``--smoke`` runs the library path of ``bt reproduce`` (:func:`bt_pipeline.evaluate.reproduce.
reproduce`) with tiny settings instead: D1 wiping, BC and ILEED at 10 optimiser steps, 3
rollouts, 2 seeds, the truth rows and the competence checks, and a conditioned protocol of 2 seeds
of the shared crowd with 2 rollouts per demonstrator. Its timings mean nothing; it checks that
both executors run every job and give the same results.json.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

from bt_pipeline.cli.evaluate_commands import reproduce as reproduce_command
from bt_pipeline.evaluate.reproduce import CrowdSettings, reproduce
from bt_pipeline.evaluate.reproduce_jobs import ReproduceConfig
from bt_pipeline.execute import ExecutorConfig, ExecutorName

SMOKE = ReproduceConfig(
    tasks=("wiping",),
    sets=("D1",),
    learners=("bc", "ileed"),
    rollouts=3,
    steps=10,
    clean_epochs=2,
    seeds=2,
    oracle=True,
)
"""The paper protocol of ``--smoke``: every code path, almost no training."""
SMOKE_CONDITIONED = {
    "seeds": 2,
    "crowds": ("shared",),
    "per_demonstrator": 2,
    "sweeps": (),
    "held_out": False,
    "per_demonstrator_learners": (),
}
"""The conditioned protocol of ``--smoke``; the settings its :class:`CrowdSettings` lacks are
left out (its extra studies are switched off where it has them)."""
TIMING_SUFFIX = "seconds"
"""results.json keys ending in this hold wall or CPU times [s] (``seconds``, ``train_seconds``,
``clean_seconds``, ...), which differ from run to run."""


def smoke_conditioned() -> CrowdSettings:
    """The conditioned protocol's settings of ``--smoke``."""
    known = {field.name for field in dataclasses.fields(CrowdSettings)}
    return CrowdSettings(**{k: v for k, v in SMOKE_CONDITIONED.items() if k in known})  # pyright: ignore[reportArgumentType]  # each value has its field's type


def run_once(
    kind: ExecutorName, workers: int, smoke: bool, oracle: bool, paper_only: bool, out: Path
) -> float:
    """One ``bt reproduce --quick`` (or the ``--smoke`` run) into `out`; its wall time [s]."""
    start = time.perf_counter()
    try:
        if smoke:
            reproduce(
                dataclasses.replace(SMOKE, workers=workers),
                out,
                progress=False,
                executor=ExecutorConfig(kind, workers),
                conditioned=None if paper_only else smoke_conditioned(),
            )
        else:
            with contextlib.redirect_stdout(io.StringIO()):  # the command prints its files
                reproduce_command(
                    quick=True,
                    out=out,
                    workers=workers,
                    executor=kind,
                    oracle=oracle,
                    paper_only=paper_only,
                )
        return time.perf_counter() - start
    finally:
        if kind == "ray":
            import ray

            ray.shutdown()  # the next Ray run starts its own, as a new bt process would


def without_timings(value: object) -> object:
    """`value` (parsed JSON) without the entries whose key ends in :data:`TIMING_SUFFIX`,
    recursively."""
    if isinstance(value, dict):
        return {k: without_timings(v) for k, v in value.items() if not k.endswith(TIMING_SUFFIX)}
    if isinstance(value, list):
        return [without_timings(v) for v in value]
    return value


def results_text(out: Path) -> str:
    """results.json of a run without its timings, as canonical text (NaN compares equal)."""
    document = json.loads((out / "results.json").read_text(encoding="utf-8"))
    return json.dumps(without_timings(document), sort_keys=True)


def main() -> None:
    parser = argparse.ArgumentParser(description="Time bt reproduce --quick: processes vs Ray.")
    parser.add_argument("--repeats", type=int, default=3, help="runs per executor (median)")
    parser.add_argument("--workers", type=int, default=2, help="--workers of each run")
    parser.add_argument("--oracle", action="store_true", help="bt reproduce --quick --oracle")
    parser.add_argument("--smoke", action="store_true", help="tiny settings, one run each")
    parser.add_argument(
        "--paper-only", action="store_true", help="bt reproduce --paper-only: no conditioned part"
    )
    parser.add_argument("--out", type=Path, default=None, help="keep each run's outputs here")
    args = parser.parse_args()
    repeats = 1 if args.smoke else args.repeats
    kinds: tuple[ExecutorName, ...] = ("processes", "ray")
    walls: dict[str, list[float]] = {kind: [] for kind in kinds}
    reference: str | None = None
    what = "--smoke (tiny settings)" if args.smoke else "bt reproduce --quick"
    what += " --oracle" if args.oracle and not args.smoke else ""
    what += " --paper-only" if args.paper_only else ""
    print(f"{what}, --workers {args.workers}, {repeats} run(s) per executor, alternating\n")
    print("| run | executor | load (1 min) | wall [s] |")
    print("|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        root = args.out or Path(tmp)
        for k in range(repeats):
            for kind in kinds:
                out = root / f"{kind}-{k + 1}"
                load = os.getloadavg()[0]
                wall = run_once(kind, args.workers, args.smoke, args.oracle, args.paper_only, out)
                walls[kind].append(wall)
                print(f"| {k + 1} | {kind} | {load:.1f} | {wall:.1f} |", flush=True)
                text = results_text(out)
                if reference is None:
                    reference = text
                elif text != reference:
                    raise SystemExit(
                        f"{out / 'results.json'} differs from the first run's (timings aside): "
                        "the results depend on the executor"
                    )
    medians = {kind: statistics.median(walls[kind]) for kind in kinds}
    print(
        f"\nmedian wall: processes {medians['processes']:.1f} s, ray {medians['ray']:.1f} s; "
        f"ray / processes = {medians['ray'] / medians['processes']:.2f}"
        f"\nresults.json identical in all {repeats * len(kinds)} runs (timings aside)"
    )


if __name__ == "__main__":
    main()
