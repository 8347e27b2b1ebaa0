"""``bt evaluate``'s conditioned protocol on files: each demonstrator's loop, from your own data.

The learners of :mod:`~bt_pipeline.evaluate.conditioned` take each demo's demonstrator preference
(θ, ρ); here the files say what it is, or not (:mod:`~bt_pipeline.evaluate.file_facts`). Per
task::

    each demo's (θ [deg], ρ): stated in its own file (NaN: unknown; in a cleaned file it may be
        the cleaner's estimate, ``preference_estimated``)
        ─else─▶ its counterpart's (noisy ↔ cleaned, paired by ``cleaned_from`` or name): for a
                raw demo, what the cleaner wrote for its cleaned version
        ─else─▶ another demo's of the same named demonstrator (the ``demonstrator`` attr)
        ─else─▶ a warning on stderr; the task keeps the unconditioned learners only
    each demonstrator's reference loop:
        the generator's truth when the noisy files carry it for every demonstrator ("gate": the
        truth note), else the best raw demo (argmax Ũ, the reference of
        :mod:`~bt_pipeline.evaluate.protocol`) turned and scaled about its centre from its own
        θ/ρ to each demonstrator's; no truth gate, and since the cleaner refines toward that
        demo's loop the note says the scores read agreement with it, not quality
    per (learner, dataset): train conditioned on noisy or cleaned, roll out per demonstrator from
        starts on its reference loop, score: success at 10 mm, shape distance [mm]

Demos without a ``demonstrator`` attr ("" or "unknown") are grouped by their preference.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

from bt_pipeline.data.demo import Demo
from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.shapes import similarity_transform
from bt_pipeline.data.tasks import Task
from bt_pipeline.evaluate.conditioned import DemonstratorLoop, evaluate_conditioned
from bt_pipeline.evaluate.file_facts import FileFacts, Key, counterparts
from bt_pipeline.evaluate.learners import LearnerName
from bt_pipeline.evaluate.plots import LEARNER_TITLES
from bt_pipeline.evaluate.protocol import DATASETS, check_pair
from bt_pipeline.exceptions import DemoError
from bt_pipeline.execute import ExecutorConfig, run_jobs
from bt_pipeline.score.utility import score_demos

log = logging.getLogger("bt")
TAU_MM = 10.0
"""τ [mm] of the success rate reported."""
TRUTH_NOTE = "truth from the files' generator attrs"
"""The gate of a task scored against the generator's true loops."""
NO_TRUTH_NOTE = "no ground truth in these files: no truth gate"
"""How the note of a task without truth begins."""
_ORIGINS = {
    "stated": "stated",
    "estimated": "the cleaner's estimates",
    "demonstrator": "from their demonstrator's other demos",
}
Found = tuple[tuple[float, float], str] | None
"""A demo's ((θ [deg], ρ), where it came from: a key of _ORIGINS), or None."""


@dataclass(frozen=True, eq=False)
class ConditionedInputs:
    """One task, ready to train: both datasets, each demo's preference, the reference loops."""

    task: Task
    positions: dict[str, FloatArray]
    """Per dataset (noisy, cleaned): the demos, shape (M, N, 2) [m]."""
    preferences: dict[str, FloatArray]
    """Per dataset: each demo's (θ [deg], ρ), shape (M, 2)."""
    demonstrators: dict[str, tuple[str, ...]]
    """Per dataset: each demo's demonstrator (or its preference group)."""
    loops: tuple[DemonstratorLoop, ...]
    """Each demonstrator's preference and reference loop."""
    gate: str | None
    """:data:`TRUTH_NOTE` when the loops are the generator's truth, else None."""
    note: str
    """One line: what the scores are against and where the preferences come from."""


@dataclass(frozen=True)
class ConditionedCell:
    """One conditioned learner trained on one dataset of a task."""

    learner: LearnerName
    dataset: str
    success: float
    """Share of the rollouts that succeed at :data:`TAU_MM`."""
    shape_mm: float
    """Mean Chamfer distance of the rollouts to their demonstrator's reference loop [mm]."""
    rollouts: int
    train_seconds: float


@dataclass(frozen=True)
class ConditionedTask:
    """The conditioned learners of one task, or (no cells) the note why there are none."""

    task: Task
    cells: tuple[ConditionedCell, ...]
    """One per (learner, dataset); empty when skipped."""
    gate: str | None
    """:data:`TRUTH_NOTE`, or None: no truth gate."""
    note: str
    """One line: the reference and the preferences' origin, or why the task was skipped."""

    def json_of(self, learner: str, dataset: str) -> dict[str, Any]:
        """The ``conditioned`` entry of a ``bt evaluate --json`` row."""
        cell = next((c for c in self.cells if (c.learner, c.dataset) == (learner, dataset)), None)
        return {
            "success_10mm": cell.success if cell else None,
            "shape_mm": cell.shape_mm if cell else None,
            "rollouts": cell.rollouts if cell else 0,
            "gate": self.gate,
            "note": self.note,
        }


def prepare_task(
    noisy: Sequence[Demo], cleaned: Sequence[Demo], facts: Mapping[Key, FileFacts]
) -> ConditionedInputs | ConditionedTask:
    """The conditioned inputs of one task (module doc), or a task without cells whose note says
    why there are none.

    Raises:
        DemoError: Mixed tasks or N, or a stated preference that is infinite or has ρ ≤ 0.
    """
    task, _ = check_pair(noisy, cleaned)
    found = _preferences(noisy, cleaned, facts)
    demos, m = (*noisy, *cleaned), len(noisy)
    if any(f is None for f in found):
        lacking = [sum(f is None for f in part) for part in (found[:m], found[m:])]
        note = (
            f"no θ/ρ or demonstrator for {lacking[0]} noisy and {lacking[1]} cleaned demos of "
            f"{task}: conditioned learners skipped, unconditioned only"
        )
        return ConditionedTask(task, (), None, note)
    values = np.array([f[0] for f in found if f is not None], dtype=np.float64)
    who = [
        d.demonstrator if _named(d) else f"θ {p[0]:.1f}° ρ {p[1]:.3f}"
        for d, p in zip(demos, values, strict=True)
    ]
    first = {name: who.index(name) for name in dict.fromkeys(who)}
    truths = {}
    for name, demo in zip(who, noisy, strict=False):  # the noisy files carry the truth
        truths.setdefault(name, facts[(demo.file, demo.name)].true_loop)
    if all(truths.get(name) is not None for name in first):
        references = {name: np.asarray(truths[name]) for name in first}
        gate, against = TRUTH_NOTE, f"{TRUTH_NOTE}: scores are against each demonstrator's loop"
    else:
        b = score_demos(noisy).best_index
        best = noisy[b].positions
        centre = 0.5 * (best.min(axis=0) + best.max(axis=0))
        references = {
            name: centre
            + similarity_transform(
                best - centre, values[k, 0] - values[b, 0], values[k, 1] / values[b, 1]
            )
            for name, k in first.items()
        }
        gate, against = (
            None,
            (
                f"{NO_TRUTH_NOTE}; scores are against the best raw demo ({noisy[b].name}) turned "
                "and scaled to each demonstrator's θ/ρ (cleaning refines toward this demo's "
                "loop, so read the scores as agreement with it, not as quality)"
            ),
        )
    sources = [f[1] for f in found if f is not None]
    origin = "; ".join(
        f"{name} " + ", ".join(f"{part.count(o)} {_ORIGINS[o]}" for o in _ORIGINS if o in part)
        for name, part in (("noisy", sources[:m]), ("cleaned", sources[m:]))
    )
    return ConditionedInputs(
        task=task,
        positions={
            "noisy": np.stack([d.positions for d in noisy]),
            "cleaned": np.stack([d.positions for d in cleaned]),
        },
        preferences={"noisy": values[:m], "cleaned": values[m:]},
        demonstrators={"noisy": tuple(who[:m]), "cleaned": tuple(who[m:])},
        loops=tuple(
            DemonstratorLoop(name, float(values[k, 0]), float(values[k, 1]), references[name])
            for name, k in first.items()
        ),
        gate=gate,
        note=f"{against}; θ/ρ: {origin}",
    )


def _preferences(
    noisy: Sequence[Demo], cleaned: Sequence[Demo], facts: Mapping[Key, FileFacts]
) -> list[Found]:
    """Each demo's preference and its origin (module doc), noisy demos first, then cleaned."""
    demos, m = (*noisy, *cleaned), len(noisy)
    found: list[Found] = []
    for k, demo in enumerate(demos):
        p = _stated(demo)
        estimated = k >= m and facts[(demo.file, demo.name)].estimated
        found.append(None if p is None else (p, "estimated" if estimated else "stated"))
    for j, i in enumerate(counterparts(noisy, cleaned, facts)):
        if i is not None:
            found[i], found[m + j] = found[i] or found[m + j], found[m + j] or found[i]
    pool: dict[str, tuple[float, float]] = {}
    for demo, f in zip(demos, found, strict=True):
        if f is not None and _named(demo):
            pool.setdefault(demo.demonstrator, f[0])
    for k, demo in enumerate(demos):
        if found[k] is None and _named(demo) and demo.demonstrator in pool:
            found[k] = (pool[demo.demonstrator], "demonstrator")
    return found


def _named(demo: Demo) -> bool:
    return demo.demonstrator.strip().lower() not in ("", "unknown")


def _stated(demo: Demo) -> tuple[float, float] | None:
    if demo.theta_deg is None or demo.rho is None:
        return None
    if not (math.isfinite(demo.theta_deg) and math.isfinite(demo.rho) and demo.rho > 0.0):
        raise DemoError(
            f"{demo.label} has θ = {demo.theta_deg}, ρ = {demo.rho}; a preference must be finite "
            "with ρ > 0 (NaN marks an unknown one)"
        )
    return demo.theta_deg, demo.rho


CellJob = tuple[ConditionedInputs, str, LearnerName, int, int, int | None]
"""(inputs, dataset, learner, seed, rollouts per demonstrator, steps)."""


def run_cell(job: CellJob) -> ConditionedCell:
    """Train one conditioned learner on one dataset and score it (runs in a worker)."""
    inputs, dataset, learner, seed, per_demonstrator, steps = job
    e = evaluate_conditioned(
        learner,
        dataset,
        inputs.positions[dataset],
        inputs.preferences[dataset],
        inputs.loops,
        seed=seed,
        per_demonstrator=per_demonstrator,
        quick=True,  # as bt reproduce's conditioned protocol: enough to draw each loop
        steps=steps,
        demonstrators=inputs.demonstrators[dataset],
    )
    return ConditionedCell(
        learner=learner,
        dataset=dataset,
        success=e.scores.success_rate(TAU_MM),
        shape_mm=float(np.mean(e.scores.shape_mm)),
        rollouts=int(e.scores.shape_mm.shape[0]),
        train_seconds=e.train_seconds,
    )


def run_conditioned(
    prepared: Sequence[ConditionedInputs | ConditionedTask],
    learners: Sequence[LearnerName],
    *,
    seed: int,
    rollouts: int,
    steps: int | None = None,
    executor: ExecutorConfig | None = None,
    progress: bool = True,
) -> list[ConditionedTask]:
    """Every prepared task's conditioned learners on noisy and on cleaned; a skipped task's note
    is logged (warning) and kept. A task's `rollouts` are shared among its demonstrators."""
    jobs: list[CellJob] = []
    for p in prepared:
        if isinstance(p, ConditionedTask):
            log.warning("%s", p.note)
            continue
        per = max(1, math.ceil(rollouts / len(p.loops)))
        for learner in learners:
            jobs.extend((p, dataset, learner, seed, per, steps) for dataset in DATASETS)
    cells = run_jobs(
        run_cell,
        jobs,
        executor or ExecutorConfig(),
        desc="evaluate: conditioned learners",
        progress=progress,
        label=lambda job: f"{job[0].task} {job[2]} {job[1]}",
    )
    out = []
    for p in prepared:
        if isinstance(p, ConditionedTask):
            out.append(p)
        else:
            mine = tuple(c for c, job in zip(cells, jobs, strict=True) if job[0] is p)
            out.append(ConditionedTask(p.task, mine, p.gate, p.note))
    return out


def print_conditioned(tasks: Sequence[ConditionedTask], console: Console) -> None:
    """The conditioned learners' table (when any ran) and each task's note line."""
    table = Table(
        title=f"Conditioned learners (θ/ρ as input), per demonstrator; success at {TAU_MM:g} mm",
        title_justify="left",
    )
    for column in ("task", "learner", "dataset"):
        table.add_column(column)
    for column in ("success", "shape \\[mm]", "Δ shape \\[mm]", "rollouts", "train \\[s]"):
        table.add_column(column, justify="right")
    for t in tasks:
        noisy = {c.learner: c.shape_mm for c in t.cells if c.dataset == "noisy"}
        for c in t.cells:
            delta = c.shape_mm - noisy[c.learner]
            table.add_row(
                t.task,
                LEARNER_TITLES.get(c.learner, c.learner),
                c.dataset,
                f"{c.success:.2f}",
                f"{c.shape_mm:.1f}",
                ""
                if c.dataset == "noisy"
                else f"[{'green' if delta < 0 else 'red'}]{delta:+.1f}[/]",
                str(c.rollouts),
                f"{c.train_seconds:.1f}",
            )
        table.add_section()
    if any(t.cells for t in tasks):
        console.print(table)
    for t in tasks:
        console.print(f"{t.task}: {t.note}", highlight=False, markup=False, soft_wrap=True)
