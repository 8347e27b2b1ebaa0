"""A tab's takes after Stop & save: the take checks' verdict, "Discard this take", moderation.

::

    save(session)             Stop & save -> file (+ attr flags) -> "Saved" (with a remark:
                              "off the guide: ...; kept and cleaned") or "Saved but flagged:
                              <why>" with a Discard this take button
    discard_flagged()         that take is excluded (sidecar; the file is kept, Restore undoes)
    moderate(action, key)     exclude / restore a raw demo of the task (library/moderation.py)
    set_operator_token(text)  the tab becomes an operator when the text is the app's token
    recover_if_lost(session)  its simulation was lost: a new one at once, and a notice of what
                              became of the take in progress (saved flagged, or lost)

Runs on the tab's worker thread (:class:`bt_teleop.ui.tab.ClientUI` queues the calls), except
:meth:`TakeDesk.set_operator_token`, which only stores a bool.
"""

from __future__ import annotations

import collections
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bt_pipeline.data.moderation import exclude
from bt_pipeline.data.tasks import GuidedTask
from bt_pipeline.exceptions import BtError, SessionLostError
from bt_teleop.library.listing import TaskLibrary
from bt_teleop.library.moderation import Moderator, token_matches
from bt_teleop.rerun.live import SessionLogger
from bt_teleop.session.control_loop import Session
from bt_teleop.session.process import SessionProcess, TabSession
from bt_teleop.ui.context import UiContext
from bt_teleop.ui.panels import TabControls

__all__ = ["MAX_SAVED_KEPT", "TakeDesk"]

Notify = Callable[..., None]
MAX_SAVED_KEPT = 100
"""The last saved takes a tab keeps (:attr:`TakeDesk.saved`; the files list them all)."""


class TakeDesk:
    """What one tab does with its saved takes and the task's demos."""

    def __init__(
        self,
        ctx: UiContext,
        session_id: str,
        controls: TabControls,
        logger: SessionLogger,
        notify: Notify,
    ) -> None:
        self.ctx = ctx
        self.session_id = session_id
        self.controls = controls
        self.logger = logger
        self.notify = notify
        self.saved: collections.deque[Path] = collections.deque(maxlen=MAX_SAVED_KEPT)
        """The last demo files this tab saved (oldest first)."""
        self.saved_count = 0
        """Demo files this tab saved in all."""
        self.flagged: Path | None = None
        """The last take, when it failed a check and was neither discarded nor followed."""
        self.operator = False
        """Whether the tab typed the operator token."""

    def started(self) -> None:
        """A new take started: forget the last one's verdict."""
        self.flagged = None
        self.controls.show_take_check(None)

    def save(self, session: Session | SessionProcess) -> Path:
        """Stop & save `session`'s take; tell the person whether it passed the checks."""
        trail = session.trail()
        take = session.stop_and_check()
        path = take.path
        self.note_saved(path, session.scene.task)
        self.logger.log_demo(path.stem, trail)
        if take.check.ok:
            lines = [f"{path.parent.name}/", path.name, *take.check.remarks()]
            self.notify("Saved", "\n".join(lines))
        else:
            self.flagged = path
            reasons = take.check.reasons()
            self.controls.show_take_check(reasons)
            self.notify("Saved but flagged", f"{path.name}\n{'; '.join(reasons)}", color="yellow")
        return path

    def note_saved(self, path: Path, task: GuidedTask) -> None:
        """A take of `task` was saved to `path`: remember it, and tell every tab to reload."""
        self.saved.append(path)
        self.saved_count += 1
        self.ctx.versions.bump(task)

    def discard_flagged(self, task: GuidedTask) -> None:
        """Exclude the flagged take just saved (its file stays; Restore brings it back)."""
        path, self.flagged = self.flagged, None
        self.controls.show_take_check(None)
        if path is None:
            return
        exclude(path, reason="discarded by its demonstrator", by=f"session {self.session_id}")
        self.ctx.versions.bump(task)
        self.notify("Discarded", f"{path.name}\nexcluded; the file is kept (Restore undoes it)")

    def moderate(self, action: str, key: str, library: TaskLibrary | None) -> None:
        """Exclude (`action` "exclude") or restore the raw demo `key` of `library`.

        Raises:
            BtError: The library is not loaded, no such demo, or not this tab's to moderate.
        """
        if library is None:
            raise BtError("the recordings are still loading")
        track = library.find(key)
        moderator = Moderator(self.session_id, operator=self.operator)
        done = moderator.apply("restore" if action == "restore" else "exclude", track)
        self.ctx.versions.bump(library.task)
        self.notify("Restored" if action == "restore" else "Excluded", done)

    def set_operator_token(self, typed: Any) -> None:
        """Become an operator when `typed` is the app's token (else stop being one)."""
        self.operator = token_matches(str(typed), self.ctx.operator_token)

    def recover_if_lost(self, session: TabSession) -> float | None:
        """Replace `session`'s child if it was lost (:meth:`SessionProcess.recover
        <bt_teleop.session.process.SessionProcess.recover>`) and say what became of the take in
        progress; the lost child's last simulation time [s] (None: nothing was lost)."""
        if not isinstance(session, SessionProcess) or not session.lost or not session.can_recover:
            return None
        try:
            recovery = session.recover()
        except SessionLostError as exc:  # the status line keeps saying it
            self.notify("Simulation stopped", str(exc), color="red")
            return None
        for path in recovery.saved:
            self.note_saved(path, recovery.task)
        title, body = recovery.notice()
        self.notify(title, body, color="red" if recovery.take_lost else "yellow")
        return recovery.sim_time_s
