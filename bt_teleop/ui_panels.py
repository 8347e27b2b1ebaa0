"""One tab's GUI panels: the viser controls in their folders, and the status text they show.

::

    Demonstration   Task, Demonstrator, θ [deg], ρ, Stay on task plane, Gripper
    Record          Record, Stop & save, Discard, status line (:func:`status_markdown`)
    Recordings      the task's demos with their scores
    Clean & replay  Clean, progress bar, Replay picker, Play, Stop replay
    (link)          the live Rerun viewer, or where the session's .rrd goes

:class:`TabControls` builds the controls and connects them to a tab's actions
(:class:`TabActions`, implemented by :class:`bt_teleop.ui.ClientUI`): every callback is async,
so viser runs them in order, and only stores a value or queues a command.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import viser

from bt_pipeline.data.tasks import TASKS, Task
from bt_teleop.cleaning import CleanProgress
from bt_teleop.recorder import RHO_RANGE, THETA_RANGE_DEG
from bt_teleop.replay import ReplayPlayer
from bt_teleop.session_config import SessionStatus
from bt_teleop.ui_context import UiContext

__all__ = ["NO_DEMOS", "TabActions", "TabControls", "status_markdown"]

NO_DEMOS = "(no demos yet)"
"""The Replay picker's only option while the task has no demos."""


class TabActions(Protocol):
    """What the panels' callbacks ask of a tab; each call returns at once."""

    @property
    def task(self) -> Task: ...
    def select_task(self, task: str) -> None: ...
    def record(self) -> None: ...
    def stop_and_save(self) -> None: ...
    def discard(self) -> None: ...
    def clean(self) -> None: ...
    def cancel_clean(self) -> None: ...
    def play(self, key: str) -> None: ...
    def stop_replay(self) -> None: ...
    def redraw_guide(self) -> None: ...
    def set_stay_on_plane(self, on: bool) -> None: ...
    def set_gripper(self, open: bool) -> None: ...


class TabControls:
    """The GUI handles of one tab, built in folders in its own ``client.gui``."""

    def __init__(self, gui: viser.GuiApi, ctx: UiContext) -> None:
        """Build the panels; the task starts at ``ctx.initial_task``."""
        with gui.add_folder("Demonstration"):
            self.task_input = gui.add_dropdown("Task", TASKS, initial_value=ctx.initial_task)
            self.name_input = gui.add_text("Demonstrator", initial_value="anonymous")
            lo, hi = THETA_RANGE_DEG
            self.theta_input = gui.add_slider("θ [deg]", min=lo, max=hi, step=1, initial_value=0)
            lo, hi = RHO_RANGE
            self.rho_input = gui.add_slider("ρ", min=lo, max=hi, step=0.05, initial_value=1.0)
            self.plane_input = gui.add_checkbox("Stay on task plane", initial_value=False)
            self.gripper_input = gui.add_button_group("Gripper", ("Open", "Close"))
        with gui.add_folder("Record"):
            self.record_button = gui.add_button("Record", color="red")
            self.save_button = gui.add_button("Stop & save", disabled=True)
            self.discard_button = gui.add_button("Discard", disabled=True)
            self.status_text = gui.add_markdown("")
        with gui.add_folder("Recordings"):
            self.library_text = gui.add_markdown("Loading the recordings…")
        with gui.add_folder("Clean & replay"):
            self.clean_button = gui.add_button("Clean")
            self.cancel_clean_button = gui.add_button("Cancel clean", disabled=True)
            self.clean_progress = gui.add_progress_bar(0.0, visible=False, animated=True)
            self.replay_input: viser.GuiDropdownHandle[str] = gui.add_dropdown(
                "Replay",
                [str(NO_DEMOS)],  # str, not a literal type: the options change
            )
            self.play_button = gui.add_button("Play")
            self.stop_replay_button = gui.add_button("Stop replay", disabled=True)
        if ctx.rerun.viewer_url is not None:
            gui.add_html(
                f'<p style="padding: 0 0.75em"><a href="{ctx.rerun.viewer_url}" '
                'target="_blank" rel="noopener">Open the live Rerun viewer</a></p>'
            )
        elif ctx.rerun.mode == "save":
            gui.add_markdown("Rerun: this session is saved under `recordings/rerun/`.")

    def connect(self, tab: TabActions) -> None:
        """Attach the callbacks that turn clicks and edits into `tab`'s actions."""

        @self.task_input.on_update
        async def _(_: viser.GuiEvent) -> None:
            if self.task_input.value != tab.task:
                tab.select_task(self.task_input.value)

        @self.theta_input.on_update
        async def _(_: viser.GuiEvent) -> None:
            tab.redraw_guide()

        @self.rho_input.on_update
        async def _(_: viser.GuiEvent) -> None:
            tab.redraw_guide()

        @self.plane_input.on_update
        async def _(_: viser.GuiEvent) -> None:
            tab.set_stay_on_plane(self.plane_input.value)

        @self.gripper_input.on_click
        async def _(_: viser.GuiEvent) -> None:
            tab.set_gripper(self.gripper_input.value == "Open")

        for button, action in (
            (self.record_button, tab.record),
            (self.save_button, tab.stop_and_save),
            (self.discard_button, tab.discard),
            (self.clean_button, tab.clean),
            (self.cancel_clean_button, tab.cancel_clean),
            (self.stop_replay_button, tab.stop_replay),
        ):
            button.on_click(_async_action(action))

        @self.play_button.on_click
        async def _(_: viser.GuiEvent) -> None:
            tab.play(self.replay_input.value)

    def show_clean_progress(self, progress: CleanProgress | None) -> None:
        """Show the clean job of this tab's task (None: none yet): its progress bar, Clean
        disabled and Cancel clean enabled while it runs. Jobs of other tasks do not block."""
        running = progress is not None and progress.state == "running"
        self.clean_progress.visible = running
        if progress is not None and running:
            self.clean_progress.value = 100.0 * progress.fraction
        self.clean_button.disabled = running
        self.cancel_clean_button.disabled = not running

    def show_replay_keys(self, keys: list[str]) -> None:
        """Offer `keys` in the Replay picker, keeping the current choice if it is still there."""
        keys = keys or [NO_DEMOS]
        current = self.replay_input.value
        self.replay_input.options = keys
        self.replay_input.value = current if current in keys else keys[-1]


def _async_action(action: Callable[[], None]) -> Callable[[viser.GuiEvent], Any]:
    """An async (in-order) click callback that queues `action`."""

    async def callback(_: viser.GuiEvent) -> None:
        action()

    return callback


def status_markdown(status: SessionStatus, replay: ReplayPlayer | None) -> str:
    """The tab's status line: recording / replay progress, end-effector position, warnings."""
    if status.recording:
        head = f"**● Recording** · {status.n_samples} samples · {status.duration_s:.1f} s"
    elif replay is not None:
        phase, fraction = replay.progress
        what = "moving to the start of" if phase == "approach" else f"{100 * fraction:.0f} % of"
        head = f"**▶ Replaying** {what} {replay.track.key}"
    else:
        head = "Ready: drag the gizmo, then **Record**"
    x, y, z = (1e3 * status.ee_pos).round().astype(int)
    lines = [head, f"End effector ({x}, {y}, {z}) mm"]
    if status.target_clamped:
        lines.append("⚠ target clamped to the workspace")
    if status.warning:
        lines.append(f"⚠ {status.warning}")
    return "  \n".join(lines)
