"""A tab's view of its clean jobs (:class:`bt_teleop.clean.runner.CleanRunner`): the progress of
its task's job, and a notice once for each job the tab started that finished (the job's process
logs the cleaned demos to the tab's Rerun recording; the tab's layout then grows the task's tab)."""

from __future__ import annotations

import weakref
from collections.abc import Callable

from bt_teleop.clean.runner import CleanJob
from bt_teleop.rerun.live import SessionLogger
from bt_teleop.ui.context import UiContext
from bt_teleop.ui.panels import TabControls, clean_done_text

__all__ = ["CleanWatch"]


class CleanWatch:
    """Polled by the tab's worker thread (:class:`bt_teleop.ui.tab.ClientUI`)."""

    def __init__(
        self,
        ctx: UiContext,
        controls: TabControls,
        logger: SessionLogger,
        notify: Callable[..., None],
    ) -> None:
        self.ctx = ctx
        self.controls = controls
        self.logger = logger
        self.notify = notify
        self._seen: weakref.WeakSet[CleanJob] = weakref.WeakSet()

    def poll(self, owner: object, task: str) -> None:
        """Show `task`'s clean progress; notify each finished job of `owner` (the tab) once."""
        cleaner = self.ctx.cleaner
        mine = cleaner.job_for(task)
        self.controls.show_clean_progress(None if mine is None else mine.progress())
        for job in cleaner.jobs():
            if job.owner is not owner or not job.finished or job in self._seen:
                continue
            self._seen.add(job)
            progress = job.progress()
            if progress.state == "done":
                self.notify("Clean done", clean_done_text(job.task, progress))
                self.logger.show_cleaned(job.task)  # the job logged the result itself
            else:
                self.notify(f"Clean {progress.state}", progress.message, color="red")
