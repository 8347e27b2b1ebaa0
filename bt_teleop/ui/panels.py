"""One tab's GUI panels: the viser controls in their folders, and the status text they show.

::

    Demonstration   Task, Demonstrator, θ [deg], ρ, Stay on task plane, Gripper, Reset view
    Record          Record, Stop & save, Discard, status line (:func:`status_markdown`),
                    Discard this take (after a take that failed the checks)
    Recordings      Sort rows (by rank or by Ũ), the task's demos with their scores; Demo
                    picker, Exclude, Restore, Operator token (when the app has one)
    Clean & replay  Clean, progress bar, Replay picker, Play, Stop replay, the paths' legend
    (link)          this session's recording in the live Rerun viewer, or where its .rrd goes

:class:`TabControls` builds the controls and connects them to a tab's actions
(:class:`TabActions`, implemented by :class:`bt_teleop.ui.tab.ClientUI`): every callback is async,
so viser runs them in order, and only stores a value or queues a command.

The Demo and Replay pickers show each demo as the table reads it and open on the newest usable
take (Replay: the cleaned ★), following it until the person picks
(:mod:`bt_teleop.library.pickers`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Protocol

import viser

from bt_pipeline.data.tasks import TASKS, GuidedTask
from bt_teleop.clean.runner import CleanProgress
from bt_teleop.library.listing import RowOrder, TaskLibrary
from bt_teleop.library.pickers import NO_DEMOS, Picker, PickerOptions, picker_options
from bt_teleop.library.replay import ReplayPlayer
from bt_teleop.library.view import LibraryView, library_view
from bt_teleop.session.config import SessionStatus
from bt_teleop.takes.escape import html_text, markdown_text
from bt_teleop.takes.recorder import RHO_RANGE, THETA_RANGE_DEG
from bt_teleop.ui.context import UiContext
from bt_teleop.ui.tab_scene import CLEANED_RGB, RAW_RGB

__all__ = ["NO_DEMOS", "PATHS_LEGEND", "TabActions", "TabControls", "status_markdown"]

ROW_ORDERS: dict[str, RowOrder] = {"by rank": "rank", "by Ũ": "utility"}
"""The Sort rows buttons and the table order each picks."""


def _swatch(rgb: tuple[int, int, int], text: str) -> str:
    r, g, b = rgb
    return f'<span style="color: rgb({r}, {g}, {b}); font-weight: bold">{text}</span>'


PATHS_LEGEND = (
    f"Replay draws {_swatch(CLEANED_RGB, '━━')} the cleaned path (green, on top) and "
    f"{_swatch(RAW_RGB, '▬ ▬')} the raw path (light orange, wide, dashed)."
)
"""The legend under the Replay picker (no text from a browser in it)."""


class TabActions(Protocol):
    """What the panels' callbacks ask of a tab; each call returns at once."""

    @property
    def task(self) -> GuidedTask: ...
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
    def reset_view(self) -> None: ...
    def discard_take(self) -> None: ...
    def moderate(self, action: str, key: str) -> None: ...
    def set_operator_token(self, typed: str) -> None: ...


class TabControls:
    """The GUI handles of one tab, built in folders in its own ``client.gui``."""

    def __init__(self, gui: viser.GuiApi, ctx: UiContext, session_id: str = "") -> None:
        """Build the panels; the task starts at ``ctx.initial_task``; the Rerun link opens
        recording `session_id`."""
        with gui.add_folder("Demonstration"):
            self.task_input = gui.add_dropdown("Task", TASKS, initial_value=ctx.initial_task)
            self.name_input = gui.add_text("Demonstrator", initial_value="anonymous")
            lo, hi = THETA_RANGE_DEG
            self.theta_input = gui.add_slider("θ [deg]", min=lo, max=hi, step=1, initial_value=0)
            lo, hi = RHO_RANGE
            self.rho_input = gui.add_slider("ρ", min=lo, max=hi, step=0.05, initial_value=1.0)
            self.plane_input = gui.add_checkbox("Stay on task plane", initial_value=False)
            self.gripper_input = gui.add_button_group("Gripper", ("Open", "Close"))
            self.reset_view_button = gui.add_button("Reset view")
        with gui.add_folder("Record"):
            self.record_button = gui.add_button("Record", color="red")
            self.save_button = gui.add_button("Stop & save", disabled=True)
            self.discard_button = gui.add_button("Discard", disabled=True)
            self.status_text = gui.add_markdown("")
            self.take_text = gui.add_markdown("", visible=False)
            """Why the last take was flagged (shown until the next Record)."""
            self.discard_take_button = gui.add_button("Discard this take", visible=False)
        with gui.add_folder("Recordings"):
            self.order_input = gui.add_button_group("Sort rows", tuple(ROW_ORDERS))
            """Order the table's usable takes by rank (★ first) or by Ũ."""
            self.library_text = gui.add_markdown("Loading the recordings…")
            self.moderate_input: viser.GuiDropdownHandle[str] = gui.add_dropdown(
                "Demo", [str(NO_DEMOS)]
            )
            self.exclude_button = gui.add_button("Exclude", disabled=True)
            self.restore_button = gui.add_button("Restore", disabled=True)
            self.token_input = gui.add_text(
                "Operator token", initial_value="", visible=ctx.operator_token is not None
            )
        with gui.add_folder("Clean & replay"):
            self.clean_button = gui.add_button("Clean")
            self.cancel_clean_button = gui.add_button("Cancel clean", disabled=True)
            self.clean_progress = gui.add_progress_bar(0.0, visible=False, animated=True)
            self.replay_input: viser.GuiDropdownHandle[str] = gui.add_dropdown(
                "Replay",
                [str(NO_DEMOS)],  # str, not a literal type: the options change
            )
            self.play_button = gui.add_button("Play", disabled=True)
            self.stop_replay_button = gui.add_button("Stop replay", disabled=True)
            self.paths_legend = gui.add_markdown(PATHS_LEGEND)
        self._theta = 0.0
        self._rho = 1.0
        self._status_shown = ""
        self._moderation: tuple[list[str], set[str]] = ([], set())
        self.demo_picker = Picker(self.moderate_input, "Demo")
        """The Demo picker's labels, keys and default (bt_teleop/library/pickers.py)."""
        self.replay_picker = Picker(self.replay_input, "Replay")
        """The Replay picker's labels, keys and default."""
        self._listed = ctx.listed_demos
        self._order: RowOrder = "rank"
        self._library: TaskLibrary | None = None
        """The library the table shows (re-sorted when Sort rows is clicked)."""
        link = ctx.rerun.session_url(session_id)
        if link is not None:
            gui.add_html(
                f'<p style="padding: 0 0.75em"><a href="{html_text(link, 1000)}" '
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
            self._theta = _finite_or(self.theta_input, self._theta)
            tab.redraw_guide()

        @self.rho_input.on_update
        async def _(_: viser.GuiEvent) -> None:
            self._rho = _finite_or(self.rho_input, self._rho)
            tab.redraw_guide()

        @self.order_input.on_click
        async def _(_: viser.GuiEvent) -> None:
            self._order = ROW_ORDERS.get(self.order_input.value, "rank")
            if self._library is not None:
                self._show_table(self._library)

        @self.moderate_input.on_update
        async def _(_: viser.GuiEvent) -> None:
            self._moderation_buttons()

        @self.exclude_button.on_click
        async def _(_: viser.GuiEvent) -> None:
            tab.moderate("exclude", self.demo_picker.key)

        @self.restore_button.on_click
        async def _(_: viser.GuiEvent) -> None:
            tab.moderate("restore", self.demo_picker.key)

        @self.token_input.on_update
        async def _(_: viser.GuiEvent) -> None:
            tab.set_operator_token(self.token_input.value)

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
            (self.discard_take_button, tab.discard_take),
            (self.reset_view_button, tab.reset_view),
        ):
            button.on_click(_async_action(action))

        @self.play_button.on_click
        async def _(_: viser.GuiEvent) -> None:
            tab.play(self.replay_picker.key)

    @property
    def theta_deg(self) -> float:
        """θ [deg]: the slider's value, or the last valid one when the box holds no number."""
        return _finite_or(self.theta_input, self._theta, restore=False)

    @property
    def rho(self) -> float:
        """ρ: the slider's value, or the last valid one when the box holds no number."""
        return _finite_or(self.rho_input, self._rho, restore=False)

    def show_status(
        self, status: SessionStatus, replay: ReplayPlayer | None, hint: str | None = None
    ) -> None:
        """The status line (rewritten only when it changes), with `hint` (e.g. how to move the
        robot: :mod:`bt_teleop.ui.motion_hint`), and the record buttons' states."""
        text = status_markdown(status, replay, hint)
        if text != self._status_shown:
            self._status_shown = text
            self.status_text.content = text
        self.record_button.disabled = status.recording or replay is not None
        self.save_button.disabled = not status.recording
        self.discard_button.disabled = not status.recording

    def choose_demo(self, key: str) -> None:
        """Choose demo `key` in the Demo picker as a person would, and set Exclude / Restore.

        Raises:
            KeyError: The picker does not offer `key`.
        """
        self.demo_picker.choose(key)
        self._moderation_buttons()

    def show_library(self, library: TaskLibrary) -> None:
        """The recordings table, the replay picker and the moderation picker of a task, each
        bounded however many takes it has (:func:`bt_teleop.library.view.library_view`), the
        pickers' entries labelled as the table reads (:mod:`bt_teleop.library.pickers`)."""
        self._library = library
        view = self._show_table(library)
        self.show_replay_options(picker_options(library, view.replay_keys, replay=True))
        self.show_moderation_options(
            picker_options(library, view.moderation_keys, replay=False), view.excluded
        )

    def _show_table(self, library: TaskLibrary) -> LibraryView:
        """The recordings table of `library` in the chosen order; the view it was read from."""
        view = library_view(library, self._listed, order=self._order)
        if self.library_text.content != view.markdown:
            self.library_text.content = view.markdown
        return view

    def show_take_check(self, reasons: list[str] | None) -> None:
        """Say why the last take was flagged and offer to discard it (None: hide both)."""
        if reasons:
            self.take_text.content = (
                "**⚠ Saved but flagged**: "
                + "; ".join(reasons)
                + (". It will not be ranked or cleaned.")
            )
        self.take_text.visible = bool(reasons)
        self.discard_take_button.visible = bool(reasons)

    def show_clean_progress(self, progress: CleanProgress | None) -> None:
        """Show the clean job of this tab's task (None: none yet): its progress bar, Clean
        disabled and Cancel clean enabled while it runs. Jobs of other tasks do not block."""
        running = progress is not None and progress.state == "running"
        self.clean_progress.visible = running
        if progress is not None and running:
            # reading and Stage 1 come before the first epoch: never show an empty bar
            self.clean_progress.value = 5.0 + 90.0 * progress.fraction
        self.clean_button.disabled = running
        self.cancel_clean_button.disabled = not running

    def show_replay_options(self, options: PickerOptions) -> None:
        """Offer `options` in the Replay picker (:meth:`Picker.offer`)."""
        self.play_button.disabled = options.labels == (NO_DEMOS,)
        self.replay_picker.offer(options)

    def show_moderation_options(self, options: PickerOptions, excluded: set[str]) -> None:
        """Offer the raw demos `options` in the Demo picker; Exclude or Restore per the
        chosen (`excluded`: the keys of the excluded ones)."""
        self._moderation = ([k for k in options.keys if k], set(excluded))
        self.demo_picker.offer(options)
        self._moderation_buttons()

    def _moderation_buttons(self) -> None:
        keys, excluded = self._moderation
        chosen = self.demo_picker.key
        self.exclude_button.disabled = chosen not in keys or chosen in excluded
        self.restore_button.disabled = chosen not in excluded


def _finite_or(slider: viser.GuiSliderHandle[Any], last: float, *, restore: bool = True) -> float:
    """The slider's value as a finite float in its range, else `last` (put back in the box when
    `restore`: text such as "abc" typed into the number box must not blank it)."""
    try:
        value = float(slider.value)
    except (TypeError, ValueError):
        value = math.nan
    if math.isfinite(value) and slider.min <= value <= slider.max:
        return value
    if restore:
        slider.value = last
    return last


def _async_action(action: Callable[[], None]) -> Callable[[viser.GuiEvent], Any]:
    """An async (in-order) click callback that queues `action`."""

    async def callback(_: viser.GuiEvent) -> None:
        action()

    return callback


def clean_done_text(task: str, progress: CleanProgress) -> str:
    """The notice of a finished clean: the output's file name (never a server path), skips."""
    name = "" if progress.output is None else progress.output.name
    skipped = f"; {len(progress.notes)} skipped" if progress.notes else ""
    return f"{task}: cleaned demos in .cleaned/{name}{skipped}"


def status_markdown(
    status: SessionStatus, replay: ReplayPlayer | None, hint: str | None = None
) -> str:
    """The tab's status line: recording / replay progress, end-effector position, warnings,
    then `hint` (the app's own text; text from elsewhere is escaped)."""
    if status.recording:
        head = f"**● Recording** · {status.n_samples} samples · {status.duration_s:.1f} s"
    elif replay is not None:
        phase, fraction = replay.progress
        what = "moving to the start of" if phase == "approach" else f"{100 * fraction:.0f} % of"
        head = f"**▶ Replaying** {what} {markdown_text(replay.track.key, 120)}"
    else:
        head = "Ready: drag the gizmo, then **Record**"
    x, y, z = (1e3 * status.ee_pos).round().astype(int)
    lines = [head, f"End effector ({x}, {y}, {z}) mm"]
    if status.target_clamped:
        lines.append("⚠ target clamped to the workspace")
    if status.warning:
        lines.append(f"⚠ {markdown_text(status.warning, 200)}")
    if hint:
        lines.append(f"**{hint}**")
    return "  \n".join(lines)
