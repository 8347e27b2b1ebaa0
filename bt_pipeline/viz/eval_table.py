"""The tables of ``bt evaluate``: the terminal table (rich) and the Markdown one (Rerun)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from rich.console import Console
from rich.table import Table

from bt_pipeline.evaluate.files_conditioned import ConditionedTask, print_conditioned
from bt_pipeline.evaluate.plots import LEARNER_TITLES
from bt_pipeline.evaluate.protocol import TaskEvaluation
from bt_pipeline.viz.tables import table_console


def print_eval_table(
    evaluations: Sequence[TaskEvaluation],
    console: Console | None = None,
    conditioned: Sequence[ConditionedTask] | None = None,
) -> None:
    """One table: task × learner × dataset with R̄, L4, Ũ, training time; Δ on cleaned rows;
    with `conditioned`, the conditioned learners' table and each task's note after it."""
    console = console or table_console(130)  # piped: wide, no name cut
    table = Table(
        title="Learners trained on noisy vs cleaned demos (mean ± std over rollouts)",
        title_justify="left",
    )
    for column in ("task", "learner", "dataset"):
        table.add_column(column)
    for column in ("R̄", "Δ R̄", "R̄ paper", "cover", "L4 [mm]", "shape [mm]", "Ũ", "train [s]"):
        table.add_column(column, justify="right")
    for evaluation in evaluations:
        for learner in evaluation.learners:
            noisy_mean = float(np.mean(evaluation.result(learner, "noisy").rewards))
            for dataset in evaluation.datasets:
                r = evaluation.result(learner, dataset)
                m = r.metrics
                delta = float(np.mean(m.rewards)) - noisy_mean
                style = "" if dataset == "noisy" else ("green" if delta > 0 else "red")
                table.add_row(
                    evaluation.task,
                    LEARNER_TITLES.get(learner, learner),
                    dataset + ("" if r.finite else " (non-finite!)"),
                    f"{np.mean(m.rewards):.3f} ± {np.std(m.rewards):.3f}",
                    "" if dataset == "noisy" else f"[{style}]{delta:+.3f}[/]",
                    f"{np.mean(m.rewards_direct):.3f}",
                    f"{np.mean(m.coverage):.2f}",
                    f"{1e3 * np.mean(m.shape_losses):.1f} ± {1e3 * np.std(m.shape_losses):.1f}",
                    f"{1e3 * np.mean(m.shape_distances):.1f}",
                    f"{np.mean(m.utilities):.3f}",
                    f"{r.train_seconds:.1f}",
                )
        table.add_section()
    console.print(table)
    console.print(
        "R̄: mean V_E reward (Eq. 11 / N) in the nearest demonstrator's frame; R̄ paper: V_E read "
        "directly (best demonstrator's frame); ceiling (best raw demo): "
        + ", ".join(f"{e.task} {e.yardstick.ceiling:.3f}" for e in evaluations)
        + ". cover: share of that demonstrator's reference loop the rollout passes within V_E's "
        "bandwidth. L4: Eq. 9 to the nearest aligned reference; shape: phase-free distance to it."
    )
    if conditioned:
        print_conditioned(conditioned, console)


def markdown_table(evaluations: Sequence[TaskEvaluation]) -> str:
    """The evaluation table as Markdown (for Rerun's text view)."""
    lines = [
        "| task | learner | dataset | R̄ | R̄ paper | L4 [mm] | Ũ | train [s] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for e in evaluations:
        for r in e.results:
            m = r.metrics
            lines.append(
                f"| {e.task} | {LEARNER_TITLES.get(r.learner, r.learner)} | {r.dataset} | "
                f"{np.mean(m.rewards):.3f} ± {np.std(m.rewards):.3f} | "
                f"{np.mean(m.rewards_direct):.3f} | {1e3 * np.mean(m.shape_losses):.1f} | "
                f"{np.mean(m.utilities):.3f} | {r.train_seconds:.1f} |"
            )
    return "\n".join(lines)
