"""What an export reads: format-v1 recordings grouped by task, scored, flagged takes left out.

Both exporters (:mod:`~bt_pipeline.interop.export_lerobot`,
:mod:`~bt_pipeline.interop.export_robomimic`) start from the same :class:`ExportTask` records::

    PATH... ──expand_paths, read_recording──▶ Recording ──group by task──▶ ExportTask
                                              (flagged takes skipped)      (demos + Ũ, best)
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bt_pipeline.data.demo import DEFAULT_SAMPLES, Demo
from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.records import DemoRecord, Recording
from bt_pipeline.data.skipping import read_usable
from bt_pipeline.data.tasks import Task
from bt_pipeline.exceptions import DemoError
from bt_pipeline.score.utility import score_demos

log = logging.getLogger("bt")


@dataclass(frozen=True)
class ExportDemo:
    """One demo to export, with where it came from and its score."""

    record: DemoRecord
    """The demo as stored (world frame, original sample times)."""
    demo: Demo
    """The pipeline's view of it (task plane, resampled): what scoring and Stage 1 take."""
    file: str
    """The recording file it was read from."""
    name: str
    """Its name in that file (``demo_<k>``)."""
    utility: float
    """Ũ (Eq. 8) among the task's exported demos, in [0, 1]."""


@dataclass(frozen=True)
class ExportTask:
    """Every exported demo of one task, in input order."""

    task: Task
    """The task."""
    plane: TaskPlane
    """The task plane of the first recording of the task."""
    demos: tuple[ExportDemo, ...]
    """Demos in input order (files in command-line order, demos by k)."""
    best_index: int
    """Index into :attr:`demos` of the best demo (highest Ũ)."""
    masks: dict[str, list[str]]
    """The inputs' robomimic filter keys, as export names (``demo_<i>``) of :attr:`demos`."""


def load_export_tasks(
    paths: Sequence[str | Path], n_samples: int = DEFAULT_SAMPLES
) -> list[ExportTask]:
    """Read, group and score the recordings under `paths` (files, directories or globs).

    Excluded files and demos with take-check flags (``DemoRecord.flags``) are left out with a
    note on logger ``"bt"`` (the rules of :func:`bt_pipeline.data.skipping.read_usable`): they
    are never training data. Scores are Ũ over each task's exported demos.

    Raises:
        RecordingError: A path matches nothing, or a file breaks format v1 (named).
        DemoError: No demo is left to export.
    """
    # The same skip rules as bt score / bt clean: excluded files and flagged takes are left out.
    usable = read_usable(paths, n_samples, strict=True)
    for note in usable.notes:
        log.info("%s", note)
    by_label = {str(r.path) if r.path else "": r for r in usable.recordings}
    records = usable.records()
    grouped: dict[Task, list[tuple[Recording, str, DemoRecord, Demo]]] = {}
    for view in usable.demos:
        recording = by_label[view.file]
        record = records[(view.file, view.name)]
        grouped.setdefault(recording.task, []).append((recording, view.name, record, view))
    if not grouped:
        raise DemoError(
            f"no demos to export in {', '.join(str(p) for p in paths)} "
            f"({len(usable.notes)} skipped: excluded or flagged)"
        )
    tasks = []
    for task, items in grouped.items():
        scores = score_demos([view for *_, view in items])
        export_names = {
            (str(rec.path) if rec.path else "", name): f"demo_{i}"
            for i, (rec, name, _, _) in enumerate(items)
        }
        tasks.append(
            ExportTask(
                task=task,
                plane=items[0][0].plane,
                demos=tuple(
                    ExportDemo(
                        record=record,
                        demo=view,
                        file=view.file,
                        name=name,
                        utility=score.utility,
                    )
                    for (_, name, record, view), score in zip(items, scores.scores, strict=True)
                ),
                best_index=scores.best_index,
                masks=_carried_masks([rec for rec, *_ in items], export_names),
            )
        )
    return tasks


def top_k_indices(utilities: Sequence[float], k: int) -> list[int]:
    """Indices of the `k` highest Ũ (ties to the earlier demo), in input order."""
    order = np.argsort(-np.asarray(utilities, dtype=np.float64), kind="stable")[:k]
    return sorted(int(i) for i in order)


def _carried_masks(
    recordings: Sequence[Recording], export_names: dict[tuple[str, str], str]
) -> dict[str, list[str]]:
    """Filter keys of the inputs mapped onto export names; demos not exported drop out."""
    masks: dict[str, list[str]] = {}
    seen: set[int] = set()
    for recording in recordings:
        if id(recording) in seen:
            continue
        seen.add(id(recording))
        label = str(recording.path) if recording.path else ""
        for key, members in recording.masks.items():
            names = [export_names[(label, m)] for m in members if (label, m) in export_names]
            masks.setdefault(key, []).extend(names)
    return masks
