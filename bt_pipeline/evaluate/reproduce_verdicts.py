"""The paper protocol's verdicts in ``bt reproduce``: paired over seeds, behind the truth gate.

Per (set, task, learner) the samples are the per-seed mean R̄ of noisy, cleaned and (with
``--oracle``) truth learners, paired by seed (:func:`~bt_pipeline.evaluate.cells.verdict_test`,
:mod:`~bt_pipeline.evaluate.stats`); never the rollouts of one trained model. The report's
verdict section and the ``verdicts`` list of results.json.
"""

from __future__ import annotations

import numpy as np
import scipy.stats

from bt_pipeline.data.tasks import Task
from bt_pipeline.evaluate.cells import (
    ALPHA,
    GATE_ALPHA,
    Cell,
    CellVerdict,
    cells,
    verdict_shape,
    verdict_test,
)
from bt_pipeline.evaluate.learners import LearnerName
from bt_pipeline.evaluate.protocol import DATASETS
from bt_pipeline.evaluate.reproduce_jobs import ReproduceRun, SetName
from bt_pipeline.evaluate.reproduce_why import why_lines
from bt_pipeline.evaluate.stats import holm


def cell_verdict(
    table: dict[tuple[SetName, Task, LearnerName, str], Cell],
    set_name: SetName,
    task: Task,
    learner: LearnerName,
) -> CellVerdict:
    """The verdict of one (set, task, learner): paired over seeds, behind the truth gate where
    the table has truth rows (:func:`~bt_pipeline.evaluate.cells.verdict_test`)."""
    noisy, cleaned = (table[(set_name, task, learner, d)] for d in DATASETS)
    return verdict_test(noisy, cleaned, table.get((set_name, task, learner, "truth")))


def verdict_cell(
    table: dict[tuple[SetName, Task, LearnerName, str], Cell],
    set_name: SetName,
    task: Task,
    learner: LearnerName,
) -> str:
    """The report's verdict cell of one (set, task, learner), e.g. ``one seed: no test``."""
    return cell_verdict(table, set_name, task, learner).text()


def verdict_section(run: ReproduceRun, table: dict) -> list[str]:
    keys: list[tuple[SetName, Task, LearnerName]] = [
        (s, t, lr) for s in run.config.sets for t in run.config.tasks for lr in run.config.learners
    ]
    verdicts = {key: cell_verdict(table, *key) for key in keys}
    words = {key: v.word for key, v in verdicts.items()}
    count = {w: sum(1 for x in words.values() if x == w) for w in _WORDS}
    shape_wins = sum(
        1
        for key in keys
        if verdict_shape(table[(*key, "noisy")], table[(*key, "cleaned")]) == "cleaned"
    )
    lines = ["## Where cleaned beats noisy, and where it does not", ""]
    if count["no test"] == len(keys):
        higher = sum(
            1 for key in keys if table[(*key, "cleaned")].mean > table[(*key, "noisy")].mean
        )
        lines += [
            f"Of {len(keys)} (set, task, learner) cells, none is tested: "
            + (
                "one seed gives one trained model per dataset, and the rollouts of one model "
                "are not independent samples of a learner trained on that data, so there is no "
                "verdict (run with --seeds 3 or more). "
                if run.config.seeds < 2
                else "a seed's mean R̄ is not finite. "
            )
            + f"Descriptively, mean R̄ (the paper's reading) is higher on cleaned demos in "
            f"{higher}; against the true loops, the phase-free shape distance is lower on "
            f"cleaned demos in {shape_wins} cells.",
            "",
        ]
    else:
        gated = (
            f"the truth gate fails in **{count['cannot tell']}**, where the protocol cannot "
            f"tell; of the other {len(keys) - count['cannot tell']}, "
            if run.config.oracle
            else ""
        )
        lines += [
            f"Of {len(keys)} (set, task, learner) cells, {gated}R̄ (the paper's reading) is "
            f"higher on cleaned demos in **{count['cleaned']}**, lower in **{count['noisy']}**, "
            f"and not different in **{count['tie']}**"
            + (f", no test in {count['no test']} (non-finite R̄)" if count["no test"] else "")
            + f" (paired t-test over {run.config.seeds} seeds, p < {ALPHA}). Against the true "
            f"loops, the phase-free shape distance is lower on cleaned demos in {shape_wins} "
            "cells.",
            "",
            _how_verdicts(run, verdicts),
            "",
        ]
    for label, which in (
        ("Cleaned worse", "noisy"),
        ("No clear difference", "tie"),
        ("Cannot tell (truth gate failed)", "cannot tell"),
    ):
        worse = [key for key in keys if words[key] == which]
        if worse:
            items = ", ".join(
                f"{s} {t} {lr} ({table[(s, t, lr, 'noisy')].mean:.3f} → "
                f"{table[(s, t, lr, 'cleaned')].mean:.3f})"
                for s, t, lr in worse
            )
            lines += [f"- {label}: {items}."]
    partial = [
        key
        for key in keys
        if min(table[(*key, "noisy")].coverage, table[(*key, "cleaned")].coverage) < 0.5
    ]
    if partial:
        items = ", ".join(
            f"{s} {t} {lr} ({table[(s, t, lr, 'noisy')].coverage:.2f} → "
            f"{table[(s, t, lr, 'cleaned')].coverage:.2f})"
            for s, t, lr in partial
        )
        lines += [
            "- Rollouts cover less than half of the nearest demonstrator's true loop "
            f"(coverage < 0.5) on at least one side in: {items}. A single policy trained on "
            "several demonstrators draws a loop near their mean preference (see the oracle rows: "
            "0.2 coverage of each own loop even on perfect demos), so coverage here measures "
            "the averaging as much as the data."
        ]
    shape_better = sum(
        1
        for key in keys
        if table[(*key, "cleaned")].shape_distance < table[(*key, "noisy")].shape_distance
    )
    l4_better = sum(
        1 for key in keys if table[(*key, "cleaned")].shape_loss < table[(*key, "noisy")].shape_loss
    )
    nearest_better = sum(
        1 for key in keys if table[(*key, "cleaned")].nearest > table[(*key, "noisy")].nearest
    )
    if run.config.oracle:
        gains = []
        for task in run.config.tasks:
            mine = [key for key in keys if key[1] == task]
            truth, clean = (
                np.mean([table[(*key, d)].mean - table[(*key, "noisy")].mean for key in mine])
                for d in ("truth", "cleaned")
            )
            gains.append(f"{task} {truth:+.3f} with the truth, {clean:+.3f} cleaned")
        lines += [
            "- Mean gain in R̄ over noisy, by task (all sets and learners): "
            + "; ".join(gains)
            + ". The truth column bounds what any cleaning can give to these learners."
        ]
    lines += [
        f"- Phase-free shape distance lower on cleaned demos in {shape_better} of {len(keys)} "
        f"cells; L4 lower in {l4_better}; R̄ nearest frame higher in {nearest_better}.",
        *why_lines(run, table, [key for key in keys if words[key] != "cleaned"]),
        "",
    ]
    return lines


_WORDS = ("cleaned", "noisy", "tie", "cannot tell", "no test")


def _how_verdicts(run: ReproduceRun, verdicts: dict) -> str:
    """How the verdicts are made, and where the protocol cannot tell (one paragraph)."""
    seeds = run.config.seeds
    text = (
        "*How the verdicts are made.* The samples are the seeds: noisy, cleaned and truth of one "
        "seed share its synthetic set, yardstick and rollout starts, so each seed gives one pair "
        "of mean R̄; the rollouts of one trained model are its measurement, never independent "
        f"samples. Cleaned vs noisy: paired t-test over the {seeds} seeds, two-sided, "
        f"p < {ALPHA} (the Wilcoxon signed-rank p beside it where ≥ 6 seeds differ). "
    )
    if run.config.oracle:
        critical = float(scipy.stats.t.ppf(1 - GATE_ALPHA / 2, seeds - 1))
        gated = [v for v in verdicts.values() if v.gate is not None]
        passed = sum(1 for v in gated if v.gate.passed)
        text += (
            "First the truth gate, as in the conditioned protocol: the learner trained on the "
            f"ground truth must beat the noisy-trained one, paired t-test over seeds, "
            f"p < {GATE_ALPHA}; it passes in {passed} of {len(gated)} cells. Where it fails, "
            "the protocol cannot tell whether cleaning helps, whatever the cleaned-vs-noisy "
            f"test says, and no verdict is stated. With {seeds} seeds the gate needs "
            f"t > {critical:.1f}: truth better in every seed by a steady margin. "
        )
    else:
        text += (
            "Without --oracle there is no truth gate, so a tie cannot be told apart from a "
            "protocol that could not show a gain of even perfect data (run with --oracle). "
        )
    tested = [v for v in verdicts.values() if v.word in ("cleaned", "noisy", "tie")]
    if tested:
        adjusted = holm([v.test.p_t if np.isfinite(v.test.p_t) else 1.0 for v in tested])
        kept = int(np.sum(adjusted < ALPHA))
        text += (
            f"Not adjusted for the {len(tested)} tested cells; Holm's adjustment over them "
            f"keeps {kept} cleaned-or-noisy verdict(s) at p < {ALPHA}."
        )
    return text.rstrip()


def verdicts_json(run: ReproduceRun) -> list[dict[str, object]]:
    """Each (set, task, learner)'s verdict, its paired test and its truth gate (None: no test)."""
    table, out = cells(run), []
    for set_name in run.config.sets:
        for task in run.config.tasks:
            for learner in run.config.learners:
                v = cell_verdict(table, set_name, task, learner)
                t, g = v.test, v.gate
                out.append(
                    {
                        "set": set_name,
                        "task": task,
                        "learner": learner,
                        "verdict": v.word,
                        "text": v.text(),
                        "seeds": run.config.seeds,
                        "mean_diff": None if t is None else t.mean_diff,
                        "p_t": None if t is None else _finite(t.p_t),
                        "p_wilcoxon": None if t is None else _finite(t.p_wilcoxon),
                        "better_seeds": None if t is None else t.wins,
                        "gate_passed": None if g is None else g.passed,
                        "gate_p_t": None if g is None else _finite(g.test.p_t),
                    }
                )
    return out


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None
