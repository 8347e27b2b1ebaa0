"""``bt evaluate`` over files: read both sets, pair them by task, evaluate, and write the outputs.

Data flow (I/O at the edges of :mod:`bt_pipeline.evaluate.protocol`)::

    --noisy PATH... ──load_demos──┐
                                  ├─pair_by_task─▶ per task: evaluate_demos ─▶ TaskEvaluation
    --cleaned PATH... ─load_demos─┘                   (progress bar on stderr)
        ──▶ table (rich, stdout) or JSON (stdout, alone)
        ──▶ --plots DIR: <task>.rollouts.png (Figs. 8-10), rewards.png (Fig. 11)
        ──▶ --rrd FILE: rollouts, references and the table in one Rerun recording
        ──▶ --rollouts-out DIR: <task>.<learner>.<dataset>.rollouts.hdf5, format v1, replayable
        ──▶ --json-out FILE: the JSON document of --json
    (unless --no-conditioned) per task: conditioned learners, per demonstrator
        (:mod:`~bt_pipeline.evaluate.files_conditioned`) ──▶ a second table, ``conditioned`` in
        every JSON row

Outputs are written only after every task has been evaluated, and published as one set across
their folders (:func:`write_outputs`, :class:`~bt_pipeline.data.output_set.OutputSet`): all of
them appear, or none, and a killed run's leftovers are removed by the next run.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from bt_pipeline.data.demo import DEFAULT_SAMPLES, Demo, group_by_task
from bt_pipeline.data.output_set import OutputSet
from bt_pipeline.data.recording import write_recording
from bt_pipeline.data.records import DemoRecord, Recording, forward_difference_actions
from bt_pipeline.data.tasks import Task
from bt_pipeline.evaluate.file_facts import read_annotated
from bt_pipeline.evaluate.files_conditioned import ConditionedTask, prepare_task, run_conditioned
from bt_pipeline.evaluate.learners import LearnerName, parse_learner
from bt_pipeline.evaluate.plots import RewardBar, plot_reward_bars, plot_rollouts
from bt_pipeline.evaluate.protocol import (
    DATASETS,
    EvalConfig,
    LearnerEval,
    TaskEvaluation,
    evaluate_demos,
)
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.execute import ExecutorConfig, run_jobs

"""Rerun application id of evaluation recordings."""
ROLLOUT_ENV_NAME = "bt_rollouts"
"""``env_args["env_name"]`` of rollout recordings."""
_GYM_TYPE = 2  # robomimic's EnvType.GYM_TYPE: the closest to "no simulator" (as bt synth).


def parse_learners(text: str) -> tuple[LearnerName, ...]:
    """``"bc,ileed"`` as learner names, in the given order.

    Raises:
        ConfigError: Empty, unknown (the message lists the valid ones) or repeated names.
    """
    names = [part.strip() for part in text.split(",") if part.strip()]
    if not names:
        raise ConfigError("--learners is empty; give e.g. bc,traj_bc,ileed,node")
    learners: tuple[LearnerName, ...] = tuple(parse_learner(name) for name in names)
    if len(set(learners)) != len(learners):
        raise ConfigError(f"--learners names a learner twice: {text}")
    return learners


def pair_by_task(
    noisy: Sequence[Demo], cleaned: Sequence[Demo]
) -> dict[Task, tuple[list[Demo], list[Demo]]]:
    """Noisy and cleaned demos grouped by task, tasks in the noisy set's order.

    Raises:
        ConfigError: A task has demos in one set only (named), or a set is empty.
    """
    by_noisy, by_cleaned = group_by_task(noisy), group_by_task(cleaned)
    if not by_noisy or not by_cleaned:
        raise ConfigError("give demos with both --noisy and --cleaned")
    for task in by_noisy:
        if task not in by_cleaned:
            raise ConfigError(
                f"task {task} has noisy demos but no cleaned ones; add its cleaned file "
                f"(bt clean writes {task}.cleaned.hdf5) to --cleaned, or drop its noisy files"
            )
    for task in by_cleaned:
        if task not in by_noisy:
            raise ConfigError(
                f"task {task} has cleaned demos but no noisy ones; add its raw recordings to "
                "--noisy, or drop its cleaned file"
            )
    return {task: (by_noisy[task], by_cleaned[task]) for task in by_noisy}


def _evaluate_job(job: tuple[list[Demo], list[Demo], EvalConfig]) -> TaskEvaluation:
    return evaluate_demos(*job)


def evaluate_pairs(
    pairs: dict[Task, tuple[list[Demo], list[Demo]]],
    config: EvalConfig,
    progress: bool = True,
    label: str = "evaluate",
    executor: ExecutorConfig | None = None,
) -> list[TaskEvaluation]:
    """Evaluate every task of `pairs`, with one progress bar (stderr) over all trainings.

    With an executor that runs jobs elsewhere (``processes`` with workers > 1, or ``ray``), each
    task is one job and the bar counts tasks; the results are the same.
    """
    if executor is not None and (executor.kind == "ray" or executor.workers > 1):
        jobs = [(noisy, cleaned, config) for noisy, cleaned in pairs.values()]
        return run_jobs(
            _evaluate_job,
            jobs,
            executor,
            desc=label,
            progress=progress,
            label=lambda job: str(job[0][0].task),
        )
    total = len(pairs) * len(DATASETS) * len(config.learners)
    evaluations = []
    with tqdm(
        total=total, desc=label, unit="model", file=sys.stderr, disable=None if progress else True
    ) as bar:
        for task, (noisy, cleaned) in pairs.items():
            bar.set_postfix_str(task)

            def on_trained(result: LearnerEval) -> None:
                bar.update(1)
                bar.set_postfix_str(
                    f"{result.task} {result.learner}/{result.dataset} "
                    f"R̄ {np.mean(result.rewards):.3f}"
                )

            evaluations.append(evaluate_demos(noisy, cleaned, config, on_trained))
    return evaluations


def evaluate_paths(
    noisy: Sequence[str | Path],
    cleaned: Sequence[str | Path],
    config: EvalConfig,
    n_samples: int = DEFAULT_SAMPLES,
    progress: bool = True,
    executor: ExecutorConfig | None = None,
) -> list[TaskEvaluation]:
    """Read both sets (files, directories or globs), pair them by task and evaluate each task.

    Raises:
        RecordingError: A path matches no recording or a file is not format v1.
        ConfigError: A task in one set only.
    """
    return evaluate_files(noisy, cleaned, config, n_samples, progress, executor, False)[0]


def evaluate_files(
    noisy: Sequence[str | Path],
    cleaned: Sequence[str | Path],
    config: EvalConfig,
    n_samples: int = DEFAULT_SAMPLES,
    progress: bool = True,
    executor: ExecutorConfig | None = None,
    conditioned: bool = True,
) -> tuple[list[TaskEvaluation], list[ConditionedTask]]:
    """:func:`evaluate_paths`, and with `conditioned` the conditioned learners of every task
    (:mod:`~bt_pipeline.evaluate.files_conditioned`; empty list without).

    The conditioned inputs are checked before any training, so a bad preference fails fast.

    Raises:
        RecordingError: A path matches no recording or a file is not format v1.
        ConfigError: A task in one set only.
        DemoError: Mixed N, or a stated preference that is infinite or has ρ ≤ 0.
    """
    noisy_demos, facts = read_annotated(noisy, n_samples)
    cleaned_demos, cleaned_facts = read_annotated(cleaned, n_samples)
    pairs = pair_by_task(noisy_demos, cleaned_demos)
    facts.update(cleaned_facts)
    prepared = [prepare_task(n, c, facts) for n, c in pairs.values()] if conditioned else []
    evaluations = evaluate_pairs(pairs, config, progress, executor=executor)
    tasks = run_conditioned(
        prepared,
        config.learners,
        seed=config.seed,
        rollouts=config.rollouts,
        steps=config.steps,
        executor=executor,
        progress=progress,
    )
    return evaluations, tasks


def eval_json(
    evaluations: Sequence[TaskEvaluation], conditioned: Sequence[ConditionedTask] | None = None
) -> dict[str, Any]:
    """The ``bt evaluate --json`` document: one row per (task, learner, dataset); with
    `conditioned`, each row's ``conditioned`` entry (:meth:`ConditionedTask.json_of`)."""
    by_task = {t.task: t for t in conditioned or ()}
    rows = []
    for evaluation in evaluations:
        for result in evaluation.results:
            row = {**result.to_json(), "reward_ceiling": evaluation.yardstick.ceiling}
            if evaluation.task in by_task:
                row["conditioned"] = by_task[evaluation.task].json_of(
                    result.learner, result.dataset
                )
            rows.append(row)
    return {"results": rows}


def reward_bars(evaluations: Sequence[TaskEvaluation], group: str = "") -> list[RewardBar]:
    """Fig. 11 bars (mean ± std of R̄ over rollouts) of every evaluated pair."""
    return [
        RewardBar(
            group=group,
            task=e.task,
            learner=r.learner,
            dataset=r.dataset,
            mean=float(np.mean(r.rewards)),
            std=float(np.std(r.rewards)),
            ceiling=e.yardstick.ceiling,
        )
        for e in evaluations
        for r in e.results
    ]


def write_plots(evaluations: Sequence[TaskEvaluation], out_dir: str | Path) -> list[Path]:
    """``<task>.rollouts.png`` per task (Figs. 8-10) and ``rewards.png`` (Fig. 11) in `out_dir`."""
    out = Path(out_dir)
    paths = [plot_rollouts(e, out / f"{e.task}.rollouts.png") for e in evaluations]
    paths.append(plot_reward_bars(reward_bars(evaluations), out / "rewards.png"))
    return paths


def rollout_recording(evaluation: TaskEvaluation, result: LearnerEval, seed: int) -> Recording:
    """One learner's rollouts as a format-v1 recording, mapped to 3-D by the noisy set's plane.

    Rollout k becomes ``demo_<k>``: ee_pos = plane.to_world(rollout), timestamps uniform over
    the noisy demos' mean duration, source "import", demonstrator ``<learner>-<dataset>``, θ/ρ
    unknown (NaN), ``ep_meta["rollout_of"]`` naming what it is a rollout of, and its metrics as
    attrs. The teleop app's replay plays it on the simulated FR3 like any demo.
    """
    n = result.rollouts.shape[1]
    timestamps = np.linspace(0.0, evaluation.duration_s, n)
    m = result.metrics
    demos: dict[str, DemoRecord] = {}
    for k, rollout in enumerate(result.rollouts):
        ee_pos = evaluation.plane.to_world(rollout)
        demos[f"demo_{k}"] = DemoRecord(
            ee_pos=ee_pos,
            timestamps=timestamps,
            demonstrator=f"{result.learner}-{result.dataset}",
            theta_deg=float("nan"),
            rho=float("nan"),
            source="import",
            actions=forward_difference_actions(ee_pos, timestamps),
            ep_meta={
                "rollout_of": {
                    "task": result.task,
                    "learner": result.learner,
                    "dataset": result.dataset,
                    "seed": seed,
                    "rollout": k,
                }
            },
            attrs={
                "reward": float(m.rewards[k]),
                "reward_direct": float(m.rewards_direct[k]),
                "shape_loss": float(m.shape_losses[k]),
                "utility": float(m.utilities[k]),
            },
        )
    return Recording(
        task=result.task,
        plane=evaluation.plane,
        demos=demos,
        env_args={
            "env_name": ROLLOUT_ENV_NAME,
            "type": _GYM_TYPE,
            "env_kwargs": {"task": result.task, "learner": result.learner, "seed": seed},
        },
        attrs={"rollouts_of": f"{result.learner} trained on {result.dataset} {result.task} demos"},
    )


def write_rollouts(
    evaluations: Sequence[TaskEvaluation], out_dir: str | Path, seed: int = 0
) -> list[Path]:
    """``<task>.<learner>.<dataset>.rollouts.hdf5`` per evaluated pair in `out_dir` (replaced)."""
    out = Path(out_dir)
    return [
        write_recording(
            out / f"{e.task}.{r.learner}.{r.dataset}.rollouts.hdf5",
            rollout_recording(e, r, seed),
            overwrite=True,
        )
        for e in evaluations
        for r in e.results
    ]


def write_outputs(
    evaluations: Sequence[TaskEvaluation],
    *,
    plots: Path | None = None,
    rrd: Path | None = None,
    rollouts_out: Path | None = None,
    json_out: Path | None = None,
    seed: int = 0,
    conditioned: Sequence[ConditionedTask] | None = None,
) -> list[Path]:
    """Write the chosen outputs of ``bt evaluate`` as one set: all of them or none.

    Every file is staged in a hidden folder beside its destination and published by one commit
    (a manifest ``bt-outputs.json`` lands in each folder). An error, Ctrl-C or kill before the
    commit leaves every folder as it was; the next run removes what a killed one left.

    Args:
        evaluations: The evaluated tasks.
        plots: Folder of the PNG figures (:func:`write_plots`).
        rrd: The Rerun recording (.rrd file).
        rollouts_out: Folder of the rollout recordings (:func:`write_rollouts`).
        json_out: File of the JSON document (:func:`eval_json`).
        seed: Seed recorded in the rollout files.
        conditioned: The conditioned learners, in the JSON document's rows.

    Returns:
        The files published (manifests not included); empty when no output was asked for.
    """
    from bt_pipeline.viz.rerun_eval import save_eval_rrd

    folders = [plots, rollouts_out, *(p.parent for p in (rrd, json_out) if p is not None)]
    primary = next((Path(f) for f in folders if f is not None), None)
    if primary is None:
        return []
    with OutputSet(primary) as outputs:
        if plots is not None:
            write_plots(evaluations, outputs.staging_of(plots))
        if rrd is not None:
            save_eval_rrd(evaluations, outputs.path(rrd.name, rrd.parent))
        if rollouts_out is not None:
            write_rollouts(evaluations, outputs.staging_of(rollouts_out), seed=seed)
        if json_out is not None:
            text = json.dumps(eval_json(evaluations, conditioned), indent=2) + "\n"
            outputs.path(json_out.name, json_out.parent).write_text(text, encoding="utf-8")
        return outputs.commit()
