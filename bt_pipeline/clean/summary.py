"""What ``bt clean`` did, per demo and per task: the rows of its table and its JSON."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bt_pipeline.data.tasks import Task


@dataclass(frozen=True)
class DemoCleanSummary:
    """One demo's line in the summary."""

    file: str
    demo: str
    output_demo: str
    demonstrator: str
    utility_raw: float
    """Ũ of the raw demo over the task's set (what ``bt score`` shows)."""
    utility_cleaned: float
    """Ũ of the cleaned demo, read the same way against the raw set's normaliser."""
    shape_loss_raw: float
    """L4 [m]: the raw demo's mean distance from its aligned reference x_i^aligned."""
    shape_loss_cleaned: float
    """The cleaned demo's mean distance from that reference [m] (0: it follows it fully)."""
    beta_final: float
    moved_mean: float = 0.0
    """Mean distance [m] between the raw samples and the cleaned demo at the same times."""
    moved_max: float = 0.0
    """Largest such distance [m]."""
    objective_raw: float = 0.0
    """Stage 2's objective term (Eq. 8 with L4 and the final β) of the raw demo."""
    objective_cleaned: float = 0.0
    """The same of the cleaned demo: what refinement maximises."""
    best: bool = False
    """The task's best demo (★)."""


@dataclass(frozen=True)
class TaskCleanSummary:
    """What ``bt clean`` did for one task (printed as a table or as JSON)."""

    task: Task
    best_file: str
    best_demo: str
    output: Path
    rrd: Path | None
    seconds: float
    """Wall time for the task, reading to writing [s]."""
    stage_seconds: dict[str, float]
    """Split: ``read``, ``score``, ``stage1``, ``stage2``, ``metrics``, ``write`` [s]."""
    demos: tuple[DemoCleanSummary, ...]
    notes: tuple[str, ...]
    best_reason: str = ""
    """Why the best demo is the best when it is not the highest Ũ (empty when it is)."""

    def to_json(self) -> dict[str, Any]:
        """The task's entry of the ``bt clean --json`` document."""
        return {
            "task": self.task,
            "best": {"file": self.best_file, "demo": self.best_demo},
            "best_reason": self.best_reason,
            "output": str(self.output),
            "rrd": None if self.rrd is None else str(self.rrd),
            "seconds": self.seconds,
            "stage_seconds": self.stage_seconds,
            "demos": [
                {
                    "file": d.file,
                    "demo": d.demo,
                    "output_demo": d.output_demo,
                    "demonstrator": d.demonstrator,
                    "utility_raw": d.utility_raw,
                    "utility_cleaned": d.utility_cleaned,
                    "shape_loss_raw": d.shape_loss_raw,
                    "shape_loss_cleaned": d.shape_loss_cleaned,
                    "moved_mean_m": d.moved_mean,
                    "moved_max_m": d.moved_max,
                    "objective_raw": d.objective_raw,
                    "objective_cleaned": d.objective_cleaned,
                    "beta_final": d.beta_final,
                }
                for d in self.demos
            ],
            "notes": list(self.notes),
        }
