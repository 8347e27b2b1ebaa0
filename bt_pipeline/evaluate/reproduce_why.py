"""Why cleaned demos do not beat noisy ones where they do not: the report's explanation, in numbers.

Every number comes from the run itself, so the explanation is re-measured with each report, and
a reason is only given where the run's numbers support it:

* **The bound of cleaning.** With ``--oracle`` every learner is also trained on the demos' ground
  truth. A cell where even the truth does not beat noisy (the truth gate: paired t-test over
  seeds, p < 0.01) cannot show a gain of any cleaning under this protocol: it cannot tell. With
  one seed there is no test, and the bullet compares means only, saying so.
* **One policy averages the demonstrators.** The four-demonstrator oracle rows: trained on
  perfect demos of the four D1 demonstrators, a learner's rollouts lie far from their own
  demonstrator's loop and near the mean-preference loop. V_E (the headline R̄) is a ridge along
  the *best* demonstrator's loop, so a mean loop scores the same whatever the data's quality.
  The conditioned four-demonstrator rows, where present, show the same learners keep each own
  loop once given the demonstrator's preference.
* **The best raw demo's own R̄** (the dotted line of Fig. 11): how far every learner stays below
  what the best demonstrator itself scores.
* **ILEED on noisy data follows one demonstrator.** Where its learned expertise singles out the
  expert-like demo of a noisy set (σ leads every other's by ≥ 0.2), it draws that
  demonstrator's loop, which V_E rewards; on cleaned demos every demonstrator looks expert and
  ILEED averages them like the other learners.
"""

from __future__ import annotations

import numpy as np

from bt_pipeline.evaluate.cells import GATE_ALPHA, verdict_test
from bt_pipeline.evaluate.reproduce_jobs import ReproduceRun

Key = tuple[str, str, str]
"""(set, task, learner)."""
ILEED_LEAD = 0.2
"""ILEED singles out a demonstrator when its σ leads every other's by at least this much."""


def why_lines(run: ReproduceRun, table: dict, lost: list[Key]) -> list[str]:
    """Bullets explaining, with numbers, the cells in `lost` (no "cleaned" verdict);
    `table` maps (set, task, learner, dataset) to its :class:`Cell`."""
    if not lost:
        return []
    tested = run.config.seeds >= 2
    cells_count = len(run.config.sets) * len(run.config.tasks) * len(run.config.learners)
    lines = [
        "",
        f"**Why cleaned does not win in {len(lost)} of {cells_count} cells** (every number from "
        "this run"
        + ("" if tested else "; one seed, so no cell is tested and these are means")
        + "):",
        "",
    ]
    if run.config.oracle:
        gain = np.mean([table[(*k, "truth")].mean - table[(*k, "noisy")].mean for k in lost])
        if tested:
            gates = {
                k: verdict_test(table[(*k, "noisy")], table[(*k, "cleaned")], table[(*k, "truth")])
                for k in lost
            }
            bound = [k for k, v in gates.items() if v.gate is not None and not v.gate.passed]
            what = (
                "the truth gate fails: the same learner trained on the demos' **ground truth** "
                f"does not beat noisy (paired t-test over seeds, p < {GATE_ALPHA}), so the "
                "protocol cannot tell whether cleaning helps there"
            )
        else:
            bound = [k for k in lost if table[(*k, "truth")].mean <= table[(*k, "noisy")].mean]
            what = (
                "the same learner trained on the demos' **ground truth** has no higher mean R̄ "
                "than noisy (one seed: means, no test)"
            )
        lines.append(
            f"- *The bound of cleaning.* In {len(bound)} of these {len(lost)} cells {what}; "
            f"over the {len(lost)} cells the truth gains {gain:+.3f} R̄ on average. No cleaning "
            "can do better than the truth under this protocol"
            + (
                "."
                if len(bound) == len(lost)
                else f"; in the other {len(lost) - len(bound)} a better cleaning could help."
            )
        )
    four = [r for r in run.competence if r.check == "four"]
    if four:
        own = [1e3 * r.shape_error_m for r in four]
        mean = [1e3 * r.mean_loop_error_m for r in four]
        nearest = float(np.mean([r.nearest_own for r in four]))
        averaging = sum(r.mean_loop_error_m < r.shape_error_m for r in four)
        lines.append(
            "- *One policy averages the demonstrators.* Trained on perfect demos of the four D1 "
            f"demonstrators, rollouts lie {min(own):.1f}-{max(own):.1f} mm from their own "
            f"demonstrator's loop and {min(mean):.1f}-{max(mean):.1f} mm from the "
            f"mean-preference loop (nearer the mean loop in {averaging} of {len(four)} (task, "
            f"learner) pairs); the nearest loop is their own for {nearest:.0%} of them (chance: "
            "25 %). The headline R̄ reads V_E, a ridge along the best demonstrator's loop, so an "
            "averaged loop scores about the same whether the demos were noisy or clean."
            + _conditioned_text(run)
            if 2 * averaging > len(four)
            else "- *Averaging does not explain it here*: on perfect demos of the four D1 "
            f"demonstrators the rollouts are nearer the mean-preference loop in only {averaging} "
            f"of {len(four)} (task, learner) pairs."
        )
    gaps = []
    for set_name in run.config.sets:
        for task in run.config.tasks:
            mine = [k for k in lost if k[:2] == (set_name, task)]
            if not mine:
                continue
            ceiling = float(
                np.mean(
                    [
                        j.evaluation.yardstick.ceiling
                        for j in run.jobs
                        if (j.set_name, j.task) == (set_name, task)
                    ]
                )
            )
            best = max(table[(*k, d)].mean for k in mine for d in ("noisy", "cleaned"))
            gaps.append(f"{set_name} {task} {ceiling:.3f} vs ≤ {best:.3f}")
    if gaps:
        lines.append(
            "- *Every learner stays below the best demonstrator.* The best raw demo's own R̄ "
            "against the best mean R̄ of any learner in those cells, noisy or cleaned: "
            + "; ".join(gaps)
            + "."
        )
    lines += _ileed_lines(run, table, [k for k in lost if k[2] == "ileed"])
    return lines


def _conditioned_text(run: ReproduceRun) -> str:
    """The conditioned four-demonstrator rows in one sentence (empty without them)."""
    rows = [r for r in run.competence if r.check == "four_conditioned"]
    if not rows:
        return ""
    worst = [1e3 * r.worst_own_error_m for r in rows]
    passed = sum(r.passed for r in rows)
    return (
        " Given each demonstrator's (θ, ρ) as an input "
        + ("the same learners keep each own loop: " if passed == len(rows) else "(oracle rows): ")
        + f"the worst demonstrator's rollouts lie {min(worst):.1f}-{max(worst):.1f} mm from its "
        f"own loop, within 2 mm in {passed} of {len(rows)} (task, learner) pairs."
    )


def _ileed_lines(run: ReproduceRun, table: dict, lost: list[Key]) -> list[str]:
    """ILEED's expertise on noisy vs cleaned demos in the cells it does not win on cleaned."""
    items = []
    for set_name, task, learner in lost:
        spread = {}
        for dataset in ("noisy", "cleaned"):
            sigmas = [
                sorted(j.evaluation.result(learner, dataset).expertise.values())
                for j in run.jobs
                if (j.set_name, j.task) == (set_name, task)
            ]
            top = float(np.mean([s[-1] for s in sigmas if s]))
            rest = [x for s in sigmas for x in s[:-1]]
            spread[dataset] = (top, min(rest, default=top), max(rest, default=top))
        n, c = spread["noisy"], spread["cleaned"]
        if n[0] - n[2] < ILEED_LEAD or c[0] - c[2] >= n[0] - n[2]:
            continue  # no single demonstrator singled out on noisy data: not this explanation
        noisy, cleaned = (table[(set_name, task, learner, d)] for d in ("noisy", "cleaned"))
        items.append(
            f"{set_name} {task}: noisy σ {n[0]:.2f} for the top demonstrator vs {n[1]:.2f}-"
            f"{n[2]:.2f} for the others (coverage {noisy.coverage:.2f}); cleaned {c[0]:.2f} vs "
            f"{c[1]:.2f}-{c[2]:.2f} (coverage {cleaned.coverage:.2f})"
        )
    if not items:
        return []
    return [
        "- *ILEED follows one demonstrator on noisy data only.* Its learned expertise singles "
        "out the expert-like demo of a noisy set, so it draws that demonstrator's loop, which V_E "
        "rewards; on cleaned demos every demonstrator looks expert and it averages them: "
        + "; ".join(items)
        + "."
    ]
