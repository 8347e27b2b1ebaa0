"""CPU time of one full-preset learner job per learner: train, 50 rollouts, rollout metrics.

The unit of work of ``bt reproduce``'s second stage, on D2 weaving (seed 0), timed by CPU time of
this process. It uses only functions every version of bt since the learners had phase state has
(``train_learner``, ``rollout``, ``rollout_metrics``), so the same script compares two commits on
a shared machine: run it alternately from a checkout of each (``git archive <rev> bt_pipeline``
into a folder, ``PYTHONPATH=<folder>``), so both see the same load.

    PYTHONPATH=old python benchmarks/evaluation/bench_learner_jobs.py --label old
    PYTHONPATH=.   python benchmarks/evaluation/bench_learner_jobs.py --label new

The mean R̄ of each job is printed too: equal in both runs when the change kept results.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.synth import make_d2
from bt_pipeline.evaluate.learners import LEARNERS, learner_config, train_learner
from bt_pipeline.evaluate.metrics import build_yardstick, initial_states, rollout_metrics


def main() -> None:
    parser = argparse.ArgumentParser(description="CPU time of one full learner job per learner.")
    parser.add_argument("--label", default="this code", help="name printed with the numbers")
    parser.add_argument("--repeats", type=int, default=1, help="sweeps over the learners")
    args = parser.parse_args()
    synth = make_d2("weaving", 0)
    demos = demos_from_recording(synth.recording)
    loops = list({d.record.demonstrator: d.truth for d in synth.demos}.values())
    yardstick = build_yardstick(demos, seed=0, true_loops=loops)
    x0 = initial_states(demos, 50, 0.02 * yardstick.size, 0, True)
    positions = np.stack([d.positions for d in demos])
    who = [d.demonstrator for d in demos]
    for _ in range(args.repeats):
        row: dict[str, float] = {}
        for name in LEARNERS:
            start = time.process_time()
            trained = train_learner(name, positions, who, learner_config(name, seed=0))
            metrics = rollout_metrics(trained.policy.rollout(x0, positions.shape[1]), yardstick)
            row[f"{name} CPU [s]"] = round(time.process_time() - start, 2)
            row[f"{name} mean R̄"] = float(np.mean(metrics.rewards))
        total = sum(v for k, v in row.items() if k.endswith("[s]"))
        print(args.label, f"total {total:.1f} s CPU", json.dumps(row, ensure_ascii=False))


if __name__ == "__main__":
    main()
