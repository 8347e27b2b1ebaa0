"""``bt reproduce``: the paper's Sec. IV end to end on synthetic D1 and D2, for every task.

Data flow, in two stages of jobs run in parallel with ``workers``
(:mod:`~bt_pipeline.evaluate.reproduce_jobs`)::

    stage 1, one job per (seed, set, task):
    make_d1 / make_d2 (bt_pipeline.data.synth) ──demos_from_recording──▶ noisy demos
        ──clean_demos (default variant)──▶ cleaned demos (+ distance of both to the true shapes)
        ──▶ yardstick (V_E, true loops) and rollout starts
    stage 2, one job per (seed, set, task, dataset, learner) and per competence check, longest
    first: train, R rollouts, metrics ──▶ LearnerEval ──(per seed, set, task)──▶ TaskEvaluation
    all jobs ──▶ DIR/rewards.png (Fig. 11), DIR/<set>.<task>.rollouts.png (Figs. 8-10, seed 0),
                 DIR/results.json (every row), DIR/report.md (tables, paper side by side, verdict)

Presets (docs/evaluation.md): ``--quick`` is the CI-sized run: D1 and D2 for the three tasks,
the learners' quick presets, 20 rollouts; the full run uses the learners' full presets and the
paper's 50 rollouts. Results depend only on the config and seeds, not on ``workers``.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

from bt_pipeline.evaluate.reproduce_jobs import ReproduceConfig, ReproduceRun, run_reproduce
from bt_pipeline.evaluate.reproduce_report import cells, report_markdown, results_json, reward_bars
from bt_pipeline.execute import ExecutorConfig
from bt_pipeline.viz.plots import plot_reward_bars, plot_rollouts

log = logging.getLogger("bt")


def write_outputs(run: ReproduceRun, out_dir: str | Path) -> list[Path]:
    """Figures, results.json and report.md of `run` in `out_dir`; returns the written paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    what = "quick" if run.config.quick else "full"
    paths = [
        plot_reward_bars(
            reward_bars(run),
            out / "rewards.png",
            f"bt reproduce ({what}): mean R̄ of the rollouts, noisy vs cleaned (± 1 std)",
        )
    ]
    for job in run.jobs:
        if job.seed == 0:
            paths.append(
                plot_rollouts(
                    job.evaluation,
                    out / f"{job.set_name}.{job.task}.rollouts.png",
                    f"{job.set_name} {job.task}: rollouts of learners trained on noisy (top) vs "
                    "cleaned (bottom) demos",
                )
            )
    paths.append(_write_text(out / "results.json", json.dumps(results_json(run), indent=1)))
    paths.append(_write_text(out / "report.md", report_markdown(run, cells(run))))
    return paths


def _write_text(path: Path, text: str) -> Path:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text + "\n", encoding="utf-8")
    tmp.replace(path)
    return path


def reproduce(
    config: ReproduceConfig,
    out_dir: str | Path,
    progress: bool = True,
    executor: ExecutorConfig | None = None,
) -> list[Path]:
    """Run `config` (jobs on `executor`; default: ``config.workers`` processes) and write its
    outputs into `out_dir` (see the module doc)."""
    run = run_reproduce(config, progress, executor)
    log.info("reproduce: %d jobs in %.0f s", len(run.jobs), run.seconds)
    return write_outputs(run, out_dir)
