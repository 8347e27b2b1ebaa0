"""Fault injection: ≥ 100 kill -9 trials at random moments during six writers, with counts.

Writers (bt_teleop.testing.faults): ``bt clean`` (over a previous run's outputs), ``bt synth
--overwrite``, ``bt evaluate`` with four outputs (``--plots``, ``--rrd``, ``--rollouts-out``,
``--json-out``: one set, over a previous run's), the app's recorder saving takes, and ``bt
export --overwrite`` in both formats (a LeRobot dataset tree over a previous one; robomimic files
of two tasks into a folder, one set). Each writer is first run once to completion to time it;
each trial then kills it (SIGKILL to its process group) at a moment drawn uniformly from [0, 1.1
× that time], so some trials hit the imports, some the computation, some the writing and some
come too late. After each kill the next run's recovery is applied and the outputs checked:
complete (readable, matching the manifest) or absent, an overwritten file old or new, a set
from one run, no temp file left.

    nice -n 10 .venv/bin/python benchmarks/faults/bench_faults.py --trials 100
    nice -n 10 .venv/bin/python benchmarks/faults/bench_faults.py --trials 60 \
        --scenarios evaluate,export_lerobot,export_robomimic
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repo root: benchmarks.common

import numpy as np

from benchmarks.common.paths import REPO
from bt_teleop.testing.faults import SCENARIOS, prepare, run_trial


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--trials", type=int, default=100, help="trials over all writers")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scenarios", default=",".join(SCENARIOS))
    args = parser.parse_args()
    scenarios = args.scenarios.split(",")
    rng = np.random.default_rng(args.seed)
    start = time.perf_counter()
    counts: Counter[tuple[str, str]] = Counter()
    failures: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        durations = {}
        for scenario in scenarios:
            folder = Path(tmp) / scenario
            command = prepare(scenario, folder)
            if scenario == "take":
                durations[scenario] = 8.0  # it saves takes until killed: any moment will do
                continue
            t0 = time.perf_counter()
            subprocess.run(command, check=False, capture_output=True, timeout=600)
            durations[scenario] = time.perf_counter() - t0
        print("uninterrupted run [s]: " + ", ".join(f"{k} {v:.1f}" for k, v in durations.items()))
        sys.stdout.flush()
        for k in range(args.trials):
            scenario = scenarios[k % len(scenarios)]
            delay = float(rng.uniform(0.0, 1.1 * durations[scenario]))
            trial = run_trial(scenario, Path(tmp) / scenario, delay, REPO)
            counts[(scenario, "trials")] += 1
            counts[(scenario, "killed")] += trial.killed
            counts[(scenario, "left temps (removed by the next run)")] += (
                trial.temps_before_recovery > 0
            )
            counts[(scenario, "problems")] += bool(trial.problems)
            if trial.problems:
                failures.append(f"{scenario} killed at {delay:.2f} s: {trial.problems}")
    print(f"{args.trials} trials in {time.perf_counter() - start:.0f} s")
    columns = ["trials", "killed", "left temps (removed by the next run)", "problems"]
    print("| writer | " + " | ".join(columns) + " |")
    print("|---" * (len(columns) + 1) + "|")
    for scenario in scenarios:
        print(f"| {scenario} | " + " | ".join(str(counts[(scenario, c)]) for c in columns) + " |")
    print(f"failures: {len(failures)}")
    for line in failures:
        print("  " + line)


if __name__ == "__main__":
    main()
