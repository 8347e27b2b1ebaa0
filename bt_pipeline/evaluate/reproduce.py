"""``bt reproduce``: the paper's Sec. IV end to end on synthetic D1 and D2, for every task.

The report leads with the conditioned protocol (:mod:`~bt_pipeline.evaluate.crowd_sets`,
:mod:`~bt_pipeline.evaluate.crowd_jobs`, :mod:`~bt_pipeline.evaluate.crowd_report`,
:mod:`~bt_pipeline.evaluate.crowd_figures`): learners that take each demonstrator's (θ, ρ) as an
input, trained on noisy, cleaned and true demos of independent and shared-bias crowds (with a
held-out preference, a per-demonstrator learner, a sweep of the expert share, a θ = 0, ρ = 1
ablation and random loops), and scored per demonstrator against its own true loop, with a truth
gate and paired verdicts over seeds. The paper's protocol follows (``--paper-only`` runs it
alone), in two stages of jobs run in parallel with ``workers``
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

from bt_pipeline.evaluate.crowd_figures import plot_success_tau, plot_task_rollouts
from bt_pipeline.evaluate.crowd_jobs import CrowdRun, run_crowd
from bt_pipeline.evaluate.crowd_report import crowd_cells, crowd_json, crowd_section
from bt_pipeline.evaluate.crowd_sets import CrowdSettings
from bt_pipeline.evaluate.plots import plot_reward_bars, plot_rollouts
from bt_pipeline.evaluate.reproduce_jobs import ReproduceConfig, ReproduceRun, run_reproduce
from bt_pipeline.evaluate.reproduce_report import cells, report_markdown, results_json, reward_bars
from bt_pipeline.execute import ExecutorConfig

log = logging.getLogger("bt")


def write_outputs(
    run: ReproduceRun, out_dir: str | Path, crowd: CrowdRun | None = None
) -> list[Path]:
    """Figures, results.json and report.md of `run` (and of the conditioned protocol's `crowd`
    run, which leads the report) in `out_dir`; returns the written paths."""
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
    results = results_json(run)
    title, *paper = report_markdown(run, cells(run)).split("\n")
    lines = [title, ""]
    if crowd is not None:
        table = crowd_cells(crowd)
        paths.append(plot_success_tau(crowd, out / "success_tau.png"))
        for task in run.config.tasks:
            figure = plot_task_rollouts(crowd, task, out / f"rollouts.{task}.png")
            paths += [] if figure is None else [figure]
        results["conditioned"] = crowd_json(crowd, table)
        lines += [*crowd_section(crowd, table), "## The paper's protocol (unconditioned learners)"]
    lines += paper
    paths.append(_write_text(out / "results.json", json.dumps(results, indent=1)))
    paths.append(_write_text(out / "report.md", "\n".join(lines)))
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
    conditioned: CrowdSettings | None = None,
) -> list[Path]:
    """Run `config` (jobs on `executor`; default: ``config.workers`` processes), and first the
    conditioned protocol of `conditioned` when given, and write the outputs into `out_dir` (see
    the module doc)."""
    executor = executor or ExecutorConfig("processes", config.workers)
    crowd = None
    if conditioned is not None:
        crowd = run_crowd(
            conditioned,
            tasks=config.tasks,
            learners=config.learners,
            quick=config.quick or conditioned.quick_learners,
            executor=executor,
            steps=config.steps,
            clean_epochs=config.clean_epochs,
            progress=progress,
        )
        log.info(
            "reproduce: conditioned protocol, %d rows in %.0f s", len(crowd.rows), crowd.seconds
        )
    run = run_reproduce(config, progress, executor)
    log.info("reproduce: %d jobs in %.0f s", len(run.jobs), run.seconds)
    return write_outputs(run, out_dir, crowd)
