"""What the app remembers of a session child to replace it when it is lost
(:class:`ChildMemory`), what became of it and its take (:class:`Recovery`), and the notice a
tab shows (:meth:`bt_teleop.session.process.SessionProcess.recover`).

::

    lost (session/process.py: the process ended, or no answer for unresponsive_s)
        -> SIGTERM + SIGCONT: a child that still can saves its take in progress flagged
           incomplete (closed_mid_take), as a closed tab's, and exits (SAVE_TIMEOUT_S, else
           killed); its last replies are read (a Stop & save that finished late counts)
    recover() -> a new child: same task, robot, session id; the same stay-on-plane, gripper
        and target; running if the old one was -> Recovery (the take: saved, or lost)
    the tab (ui_takes.TakeDesk.recover_if_lost): at once, and a notice naming the take's
        demonstrator and length, and the file saved or "was lost: record it again"

A take in progress when a child is lost is never dropped silently: killed, crashed or too
short to keep, the notice says it was lost.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.tasks import GuidedTask
from bt_teleop.session.config import SessionStatus

__all__ = ["ChildMemory", "Recovery"]

LOGGER = logging.getLogger("bt.teleop")


@dataclass(frozen=True)
class Recovery:
    """A lost child replaced by a new one with the same task, robot and settings."""

    reason: str
    """Why the old child was lost (its status line's warning until then)."""
    task: GuidedTask
    """The task both children simulate."""
    sim_time_s: float
    """The old child's last known simulation time [s] (the new one starts at 0)."""
    take_by: str | None
    """The demonstrator of the take in progress when it was lost; None when there was none."""
    take_duration_s: float
    """That take's last known duration [s] (0 when none)."""
    saved: tuple[Path, ...]
    """Takes the old child saved after the app stopped waiting for it: the take in progress
    (flagged incomplete, ``closed_mid_take``), or a Stop & save that finished late."""

    @property
    def take_lost(self) -> bool:
        """Whether a take in progress was lost (not saved)."""
        return self.take_by is not None and not self.saved

    def take_lines(self) -> list[str]:
        """What became of the take in progress, and of takes saved late (none: empty)."""
        take = f"by {self.take_by}, {self.take_duration_s:.1f} s" if self.take_by else ""
        lines = [f"The take in progress ({take}) was lost: record it again."] * self.take_lost
        for path in self.saved:
            what = f"The take in progress ({take})" if self.take_by else "A take"
            lines.append(f"{what} was saved: {path.name}")
        return lines

    def notice(self) -> tuple[str, str]:
        """The tab's notice: (title, body)."""
        lines = [f"{self.reason}.", f"A new {self.task} simulation started with your settings."]
        title = "Take lost: simulation restarted" if self.take_lost else "Simulation restarted"
        return title, "\n".join(lines + self.take_lines())


class ChildMemory:
    """What the app knows of a child beyond its latest answer: what a slow child's calls
    return meanwhile, and what a new child takes over when it is lost."""

    def __init__(self) -> None:
        self.status: SessionStatus | None = None
        """The last status it answered."""
        self.trail: FloatArray = np.zeros((0, 3))
        """The last trail it answered, shape (T, 3) [m]."""
        self.take_by: str | None = None
        """The demonstrator of its take in progress (None: none)."""
        self.settings: dict[str, tuple[Any, ...]] = {}
        """The last value of each one-way command (target, gripper, stay on plane)."""
        self.settings_lock = threading.Lock()
        self.saved_late: list[Path] = []
        """Takes it saved after the app stopped waiting (its last reply, or a late save)."""

    def note_status(self, status: SessionStatus) -> None:
        """`status` was answered (replies come in order: after start_recording's reply, a
        status that is not recording means the take ended)."""
        self.status = status
        if not status.recording:
            self.take_by = None

    def on_late(self, name: str, ok: bool, value: Any) -> None:
        """A reply that came after its call gave up, or the child's last (name "exit")."""
        if not ok:
            LOGGER.info("a session call %s failed late: %s", name, value)
        elif name == "status":
            self.note_status(value)
        elif name == "stop_and_check":
            self.saved_late.append(value.path)
        elif name == "exit" and value is not None:
            self.saved_late.append(value)

    def recovery(self, reason: str, task: GuidedTask) -> Recovery:
        """The :class:`Recovery` of the lost child (its take and late saves then forgotten)."""
        last, take_by, saved = self.status, self.take_by, tuple(self.saved_late)
        self.take_by, self.saved_late = None, []
        return Recovery(
            reason=reason,
            task=task,
            sim_time_s=0.0 if last is None else last.sim_time_s,
            take_by=take_by,
            take_duration_s=0.0 if last is None or take_by is None else last.duration_s,
            saved=saved,
        )
