"""Skip, don't stop, for the cleaner: clean one task without the demos it cannot use.

A demo that does not move, is not periodic when it would be the best demo, or makes any stage
fail is dropped with a one-line note naming it and the task is cleaned from the rest
(:func:`bt_pipeline.data.skipping.skip_failing`); with ``options.strict`` the first one stops the
run, its message naming the demo. An error naming no demo (e.g. a library's "NaN or infinite
values") is traced to the first demo that fails on its own (:func:`probe_demo`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from bt_pipeline.clean.guide_fit import PreferenceRange
from bt_pipeline.clean.pipeline import CleanOptions, TaskCleanResult, check_usable, clean_demos
from bt_pipeline.clean.selection import Selection, select_demos
from bt_pipeline.clean.stage1.extract import run_stage1
from bt_pipeline.clean.stage2.config import EpochStats
from bt_pipeline.data.demo import Demo
from bt_pipeline.data.skipping import skip_failing
from bt_pipeline.score.utility import score_demos


def clean_skipping(
    demos: Sequence[Demo],
    options: CleanOptions,
    on_epoch: Callable[[EpochStats], None] | None = None,
) -> tuple[TaskCleanResult | None, list[str]]:
    """Clean one task's demos, dropping (with a note) each demo the cleaner cannot use.

    Returns:
        The result (None when no demo is usable) and one note per dropped demo.

    Raises:
        DemoError: ``options.strict`` and a demo cannot be cleaned, or an error no single demo
            explains; the message names the demo, or the task and its files.
    """

    def probe(demo: Demo) -> None:
        check_usable([demo])
        score_demos([demo], options.score)
        run_stage1([demo], 0, seed=options.seed)

    return skip_failing(
        lambda kept: clean_demos(kept, options, on_epoch=on_epoch),
        demos,
        probe,
        strict=options.strict,
    )


def select_skipping(
    demos: Sequence[Demo], allowed: PreferenceRange | None = None, *, strict: bool = False
) -> tuple[Selection | None, list[str]]:
    """One task's Ũ and best demo as ``bt score`` computes them, dropping (with a note) each
    demo that cannot be scored: the selection ``bt clean`` makes, over the same set. ``bt view``
    reads its Ũ here too, so both show the same number for a demo.

    Returns:
        The selection (None when no demo can be scored) and the notes: one per dropped demo,
        then the selection's own (estimated θ/ρ, the ★'s reason).
    """

    def periodic(kept: list[Demo]) -> Selection:
        check_usable(kept)
        return select_demos(kept, allowed=allowed)

    selection, notes = skip_failing(periodic, demos, lambda d: periodic([d]), strict=strict)
    if selection is not None:
        notes += list(selection.notes)
    return selection, notes
