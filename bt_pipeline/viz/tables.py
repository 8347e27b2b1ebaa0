"""Tables (rich, on stdout) and JSON documents of scores and cleaning summaries."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.markup import escape
from rich.table import Table

if TYPE_CHECKING:
    from bt_pipeline.clean.selection import Selection
    from bt_pipeline.clean.summary import TaskCleanSummary
    from bt_pipeline.data.demo import Demo
    from bt_pipeline.score.utility import TaskScores

Flagged = Sequence[tuple["Demo", tuple[str, ...]]]
"""Flagged demos and their flags (listed with ⚠, never ranked)."""


PIPED_WIDTH = 1000
"""Columns of a table printed to a pipe or a file: wide enough that no name is cut."""


def table_console(min_width: int = 120) -> Console:
    """The stdout console every bt table prints to.

    In a terminal: its width, at least `min_width` columns. Piped or redirected (not a
    terminal): :data:`PIPED_WIDTH` columns, so rich never cuts a file name to ``newcomer_…``
    and rows that differ only at the end of their names stay apart for grep and scripts.
    """
    console = Console()
    if not console.is_terminal:
        return Console(width=PIPED_WIDTH)
    if console.width < min_width:
        return Console(width=min_width)
    return console


def _console() -> Console:
    return table_console()


def _short(file: str, demo: str) -> str:
    """``<file name>:<demo>`` (the directory is in the JSON output)."""
    return f"{Path(file).name}:{demo}" if file else demo


def _fmt_pref(value: float | None, digits: int) -> str:
    return "?" if value is None or math.isnan(value) else f"{value:.{digits}f}"


def _periodic_json(selection: Selection | None, i: int) -> dict[str, Any]:
    """Demo i's kept span and how its θ/ρ were found (all None for whole-demo scores)."""
    if selection is None:
        keys = ("loop_start_s", "loop_end_s", "cycles", "preference_confidence")
        return dict.fromkeys((*keys, "preference_estimated"))
    return selection.span_json(i)


def _flagged_json(flagged: Flagged, task: str) -> list[dict[str, Any]]:
    return [
        {"file": d.file, "demo": d.name, "demonstrator": d.demonstrator, "flags": list(flags)}
        for d, flags in flagged
        if d.task == task
    ]


def score_json(
    results: Sequence[TaskScores],
    flagged: Flagged = (),
    notes: Sequence[str] = (),
    selections: Mapping[str, Selection] | None = None,
) -> dict[str, Any]:
    """The ``bt score --json`` document (flagged demos per task, unranked; skip notes).

    With `selections` (per task), each demo also has its kept span, loops and whether its θ/ρ
    were estimated; θ/ρ are then the ones used (given or estimated).
    """
    selections = selections or {}
    tasks = []
    scored = {result.task for result in results}
    for task in dict.fromkeys(d.task for d, _ in flagged):
        if task not in scored:
            tasks.append({"task": task, "best": None, "demos": [], "flagged": []})
    for result in results:
        best = result.best.demo
        selection = selections.get(result.task)
        tasks.append(
            {
                "task": result.task,
                "best": {"file": best.file, "demo": best.name},
                "best_reason": "" if selection is None else selection.best_reason,
                "demos": [
                    {
                        "file": s.demo.file,
                        "demo": s.demo.name,
                        "demonstrator": s.demo.demonstrator,
                        "theta_deg": s.demo.theta_deg,
                        "rho": s.demo.rho,
                        "mutual_information": s.mutual_information,
                        "symmetry": s.symmetry,
                        "closure": s.closure,
                        "smoothness": s.smoothness,
                        "utility": s.utility,
                        "rank": s.rank,
                    }
                    | _periodic_json(selections.get(result.task), i)
                    for i, s in enumerate(result.scores)
                ],
            }
        )
    for entry in tasks:
        entry["flagged"] = _flagged_json(flagged, entry["task"])
    return {"tasks": tasks, "notes": list(notes)}


def print_score_tables(
    results: Sequence[TaskScores],
    flagged: Flagged = (),
    notes: Sequence[str] = (),
    selections: Mapping[str, Selection] | None = None,
    console: Console | None = None,
) -> None:
    """One table per task: demo, demonstrator, θ, ρ, MI, L1, L2, L3, Ũ, rank; best marked ★.

    With `selections`, also each demo's loops (its kept span is in the JSON), and estimated θ/ρ
    marked ≈.
    Flagged demos follow their task's ranked rows, marked ⚠ with their flags and no rank.
    """
    console = console or _console()
    selections = selections or {}
    for result in results:
        selection = selections.get(result.task)
        files = {s.demo.file for s in result.scores}
        one_file = len(files) == 1

        def label(file: str, demo: str, one_file: bool = one_file) -> str:
            return demo if one_file else _short(file, demo)

        where = f" in {next(iter(files))}" if one_file else f" from {len(files)} files"
        table = Table(
            title=(
                f"{result.task}: {len(result.scores)} demos{where}, best = "
                f"{label(result.best.demo.file, result.best.demo.name)} ★"
            ),
            title_justify="left",
        )
        for column in ("", "demo", "demonstrator", "θ [°]", "ρ"):
            table.add_column(escape(column))
        periodic = ("loops",) if selection is not None else ()
        for column in (*periodic, "MI [nats]", "L1 sym [mm]", "L2 close [mm]", "L3 smooth"):
            table.add_column(escape(column), justify="right")
        for column in ("Ũ", "rank"):
            table.add_column(escape(column), justify="right")
        for index, s in enumerate(result.scores):
            mark, span = "", ()
            if selection is not None:
                segment = selection.segments[index]
                mark = "≈" if selection.preferences[index].estimated else ""
                span = (f"{segment.cycles:.2f}",)
            table.add_row(
                "★" if index == result.best_index else "",
                label(s.demo.file, s.demo.name),
                s.demo.demonstrator,
                mark + _fmt_pref(s.demo.theta_deg, 1),
                mark + _fmt_pref(s.demo.rho, 2),
                *span,
                f"{s.mutual_information:.3f}",
                f"{1e3 * s.symmetry:.2f}",
                f"{1e3 * s.closure:.2f}",
                f"{s.smoothness:.3g}",
                f"{s.utility:.3f}",
                str(s.rank),
            )
        for demo, flags in flagged:
            if demo.task == result.task:
                table.add_row(
                    "⚠",
                    label(demo.file, demo.name),
                    demo.demonstrator,
                    _fmt_pref(demo.theta_deg, 1),
                    _fmt_pref(demo.rho, 2),
                    *[""] * (1 if selection is not None else 0),
                    escape(f"flagged: {', '.join(flags)}"),
                    *[""] * 4,
                    "–",
                )
        console.print(table)
        if selection is not None and selection.best_reason:
            console.print(f"★ {selection.best_reason}", markup=False)
    scored = {result.task for result in results}
    for demo, flags in flagged:
        if demo.task not in scored:
            console.print(
                f"⚠ {demo.task}: {_short(demo.file, demo.name)} flagged {', '.join(flags)}; "
                "no unflagged demo to rank",
                markup=False,
            )
    reasons = {s.best_reason for s in selections.values()}
    for note in notes:
        if note not in reasons:
            console.print(f"note: {note}", markup=False)


def clean_json(summaries: Sequence[TaskCleanSummary]) -> dict[str, Any]:
    """The ``bt clean --json`` document."""
    return {"tasks": [summary.to_json() for summary in summaries]}


def print_clean_summary(
    summaries: Sequence[TaskCleanSummary], console: Console | None = None
) -> None:
    """One table per cleaned task: Ũ before and after (as ``bt score`` reads it), the distance
    to the aligned reference before and after, how far cleaning moved each demo, β, the files.
    """
    console = console or _console()
    for summary in summaries:
        table = Table(
            title=(
                f"{summary.task}: best = {summary.best_file}:{summary.best_demo} ★, "
                f"{summary.seconds:.1f} s → {summary.output}"
            ),
            caption=CLEAN_CAPTION,
            caption_justify="left",
            title_justify="left",
        )
        for column in ("", "demo", "demonstrator"):
            table.add_column(column)
        columns = ("Ũ raw", "Ũ cleaned", "L4 raw [mm]", "off ref. [mm]", "moved [mm]", "β final")
        for column in columns:
            table.add_column(escape(column), justify="right")
        for demo in summary.demos:
            table.add_row(
                "★" if demo.best else "",
                _short(demo.file, demo.demo),
                demo.demonstrator,
                f"{demo.utility_raw:.3f}",
                f"{demo.utility_cleaned:.3f}",
                f"{1e3 * demo.shape_loss_raw:.2f}",
                f"{1e3 * demo.shape_loss_cleaned:.2f}",
                f"{1e3 * demo.moved_mean:.2f} / {1e3 * demo.moved_max:.2f}",
                f"{demo.beta_final:.2f}",
            )
        console.print(table)
        if summary.best_reason:
            console.print(f"★ {summary.best_reason}", markup=False)
        for note in summary.notes:
            if note != summary.best_reason:
                console.print(f"note: {note}", markup=False)


CLEAN_CAPTION = (
    "Ũ: over the task's demos, as bt score reads them (cleaned: against the raw set's scale). "
    "L4 raw: mean distance of the raw demo from its aligned reference x_i^aligned (Eq. 9); "
    "off ref.: the cleaned demo's (0 when cleaning followed the reference fully). "
    "moved: mean / max distance between each raw sample and the cleaned demo at the same time."
)
"""Under ``bt clean``'s table: what its columns measure."""
