"""One browser tab: its controller (:class:`ClientUI`) tying the tab's GUI, scene and session.

Data flow (everything a tab does stays in the tab)::

    browser ──gizmo drag──> async callback ──> Session.set_target   (latest target, under lock)
            ──buttons, task, θ/ρ──> async callback ──> command queue (in order)
                                                            │
    tab worker thread, every 1 / publish_hz [s]:            v
        run queued commands (switch task, record, save, discard, clean, play, ...)
        Session.status() -> TabScene.show (robot, target marker, trail), status text
            (grouped with client.atomic(): one scene update per period)
        -> SessionLogger.log_state (Rerun, off this thread's critical path)
        poll: clean job progress, replay progress, library reloads
    Session: fixed-rate IK + physics in a child process (session_process), never touched by
        viser; when that child is lost the worker starts a new one (TakeDesk.recover_if_lost)

Callbacks never block: they store a value or queue a command. The worker is the only thread
that changes the tab's scene and the only one that swaps its Session (task switch).

Beside it: panels :mod:`~bt_teleop.ui.panels`, takes, moderation and a lost simulation
:mod:`~bt_teleop.ui.takes`, clean jobs :mod:`~bt_teleop.ui.clean`, 3-D view
:mod:`~bt_teleop.ui.tab_scene`, what tabs share :mod:`~bt_teleop.ui.context`.
"""

from __future__ import annotations

import asyncio
import collections
import concurrent.futures
import functools
import logging
import queue
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import viser

from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.tasks import GuidedTask, parse_guided_task
from bt_pipeline.exceptions import BtError
from bt_teleop.library.listing import TaskLibrary
from bt_teleop.library.replay import ReplayPlayer, hold_pose, read_replay
from bt_teleop.library.tracks import track_who_when
from bt_teleop.rerun.live import SessionLogger
from bt_teleop.session.process import TabSession, open_session
from bt_teleop.sim.scene import load_scene
from bt_teleop.takes.escape import breakable, display_text
from bt_teleop.ui.clean import CleanWatch
from bt_teleop.ui.context import TaskVersions, UiContext
from bt_teleop.ui.motion_hint import motion_hint
from bt_teleop.ui.panels import TabControls, status_markdown
from bt_teleop.ui.tab_scene import Frame, TabScene
from bt_teleop.ui.takes import TakeDesk

__all__ = ["ClientUI", "Frame", "TaskVersions", "UiContext", "status_markdown"]

LOGGER = logging.getLogger("bt.teleop")
MAX_MESSAGES = 100
"""Notifications a tab remembers (:attr:`ClientUI.messages`; one or two come with each take)."""


class ClientUI:
    """The GUI, scene and session of one browser tab."""

    def __init__(self, client: viser.ClientHandle, ctx: UiContext, session_id: str) -> None:
        """Build the tab's GUI and scene, start its session and its worker thread."""
        self.client = client
        self.ctx = ctx
        self.session_id = session_id
        self.logger: SessionLogger = ctx.rerun.session_logger(session_id)
        self.messages: collections.deque[tuple[str, str]] = collections.deque(maxlen=MAX_MESSAGES)
        """(title, body) of the last notifications shown (newest last)."""
        self.last_frame: Frame | None = None
        self.library: TaskLibrary | None = None
        self.replay: ReplayPlayer | None = None
        self.last_replay: ReplayPlayer | None = None
        self._commands: queue.Queue[tuple[Callable[..., Any], tuple[Any, ...]]] = queue.Queue()
        self._stop = threading.Event()
        self._close_lock = threading.Lock()
        self._closed = False
        self._frames = 0
        self._time_offset_s = 0.0
        self._guide_dirty = True
        self._library_future: concurrent.futures.Future[TaskLibrary] | None = None
        self._library_version = -1
        self.controls = TabControls(client.gui, ctx, session_id)
        """The tab's GUI handles."""
        self.takes = TakeDesk(ctx, session_id, self.controls, self.logger, self._notify)
        """Saved takes, their checks' verdict and moderation."""
        self.saved = self.takes.saved
        self.cleans = CleanWatch(ctx, self.controls, self.logger, self._notify)
        self.controls.connect(self)
        self.session: TabSession = self._new_session(ctx.initial_task)
        self.tab_scene = TabScene(
            client.scene, self.session.scene, self._on_drag, fancy_lighting=ctx.fancy_lighting
        )
        """The tab's 3-D view."""
        self._task_shown()
        TabScene.frame(client.camera, self.session.scene)
        self._worker = threading.Thread(target=self._run, name=f"bt-tab-{session_id}", daemon=True)
        self._worker.start()

    # -- actions (any thread; run in order by the worker) -------------------------------------

    def select_task(self, task: str) -> None:
        """Load `task`'s scene for this tab (refused while recording)."""
        self._queue(self._do_select_task, parse_guided_task(task))

    def record(self) -> None:
        """Start recording with the demonstrator, θ and ρ in the GUI."""
        self._queue(self._do_record)

    def stop_and_save(self) -> None:
        """Stop recording and save the demo."""
        self._queue(self._do_save)

    def discard(self) -> None:
        """Drop the recording in progress."""
        self._queue(self._do_discard)

    def clean(self) -> None:
        """Start cleaning this task's recordings in the background."""
        self._queue(self._do_clean)

    def cancel_clean(self) -> None:
        """Stop the clean job of this task (its previous output stays)."""
        self._queue(self._do_cancel_clean)

    def play(self, key: str) -> None:
        """Replay the demo `key` of this task's library on this tab's robot."""
        self._queue(self._do_play, key)

    def stop_replay(self) -> None:
        """Stop a replay and remove its paths."""
        self._queue(self._do_stop_replay)

    def discard_take(self) -> None:
        """Discard the flagged take just saved: exclude it (the file is kept; Restore undoes)."""
        self._queue(lambda: self.takes.discard_flagged(self.task))

    def moderate(self, action: str, key: str) -> None:
        """Exclude or restore the raw demo `key` (own demos, or any as an operator)."""
        self._queue(lambda: self.takes.moderate(action, key, self.library))

    def set_operator_token(self, typed: str) -> None:
        """Become an operator when `typed` is the app's operator token (else stop being one)."""
        self.takes.set_operator_token(typed)

    def reset_view(self) -> None:
        """Put the camera back to the task's default view."""
        self._queue(lambda: TabScene.frame(self.client.camera, self.session.scene))

    def wait_idle(self, timeout_s: float = 10.0) -> bool:
        """Wait until every action asked for so far has run; whether it happened in time.

        Includes actions of GUI callbacks already scheduled on viser's event loop.
        """
        loop = self.ctx.event_loop
        if loop is not None and loop.is_running():
            asyncio.run_coroutine_threadsafe(asyncio.sleep(0), loop).result(timeout_s)
        done = threading.Event()
        self._commands.put((done.set, ()))
        return done.wait(timeout_s)

    @property
    def task(self) -> GuidedTask:
        """The tab's task."""
        return self.session.scene.task

    @property
    def frames(self) -> int:
        """Scene updates sent so far."""
        return self._frames

    def close(self, save_incomplete: bool | None = None) -> Path | None:
        """End the tab: stop its threads and settle a recording in progress.

        Args:
            save_incomplete: Save a recording in progress flagged incomplete (True) or discard
                it (False); the app's setting when None.

        Returns:
            The incomplete demo saved, or None.
        """
        with self._close_lock:  # a second caller waits for the first to finish
            if self._closed:
                return None
            self._closed = True
            self._stop.set()
            if threading.current_thread() is not self._worker:
                self._worker.join(5.0)
            if self.replay is not None:
                self.replay.stop()
            keep = self.ctx.save_incomplete if save_incomplete is None else save_incomplete
            path = self.session.close(save_incomplete=keep)
            if path is not None:
                self.takes.note_saved(path, self.task)
            self.logger.close()
            return path

    # -- what the panels' callbacks ask for (viser's event loop: store or queue, never block) -

    def redraw_guide(self) -> None:
        """Redraw the task-shape guide (θ or ρ changed) with the next frame."""
        self._guide_dirty = True

    def set_stay_on_plane(self, on: bool) -> None:
        """Project the target onto the task plane (True) or not."""
        self.session.set_stay_on_plane(on)

    def set_gripper(self, open: bool) -> None:
        """Open (True) or close (False) the gripper."""
        self.session.set_gripper(open)

    def _on_drag(self, position: FloatArray) -> None:
        if self.replay is None:
            self.session.set_target(position)

    # -- scene --------------------------------------------------------------------------------

    def _new_session(self, task: GuidedTask) -> TabSession:
        ctx = self.ctx  # a child process per tab (session/process.py) unless told otherwise
        session = open_session(
            load_scene(task, ctx.robot),
            ctx.recordings_dir,
            config=ctx.session_config,
            session_id=self.session_id,
            in_process=not ctx.session_processes,
        )
        session.set_stay_on_plane(self.controls.plane_input.value)
        session.start()
        return session

    def _task_shown(self) -> None:
        """The scene shows a (new) task: redraw its guide, reload its recordings."""
        self._guide_dirty = True
        self.controls.gripper_input.visible = self.session.scene.has_gripper
        self._library_version = -1  # reload the task's recordings

    def _publish(self) -> None:
        status = self.session.status()
        c = self.controls
        if self._guide_dirty:
            self._guide_dirty = False
            self.tab_scene.draw_guide(
                self.session.scene, float(c.theta_input.value), float(c.rho_input.value)
            )
        with self.client.atomic():
            trail = self.session.trail() if status.recording else None
            self.tab_scene.show(status, trail, follow=self.replay is not None)
            period_s = 1.0 / self.ctx.session_config.record_hz
            hint = None if trail is None else motion_hint(trail, period_s)  # "drag the gizmo"
            c.show_status(status, self.replay, hint)
        self._frames += 1
        self.last_frame = Frame(
            self._frames, time.perf_counter(), status.sim_time_s, status.ee_pos.copy()
        )
        self.logger.log_state(
            self._time_offset_s + status.sim_time_s, status.ee_pos, status.joint_pos
        )

    # -- worker -------------------------------------------------------------------------------

    def _queue(self, action: Callable[..., Any], *args: Any) -> None:
        self._commands.put((action, args))

    def _run(self) -> None:
        period = 1.0 / self.ctx.publish_hz
        next_t = time.perf_counter()
        while not self._stop.is_set():
            self._run_commands()
            try:
                self._publish()
                lost_at_s = self.takes.recover_if_lost(self.session)  # a new simulation
                if lost_at_s is not None:  # its clock starts at 0; the replay is gone
                    self._time_offset_s += lost_at_s + 1.0
                    self._do_stop_replay()
                    self.tab_scene.trail.clear()
                self._poll()
            except Exception:  # keep the tab alive; the log has the details
                LOGGER.exception("tab %s: update failed", self.session_id)
            next_t += period
            delay = next_t - time.perf_counter()
            if delay > 0.0:
                self._stop.wait(delay)
            else:
                next_t = time.perf_counter()

    def _run_commands(self) -> None:
        while True:
            try:
                action, args = self._commands.get_nowait()
            except queue.Empty:
                return
            try:
                action(*args)
            except BtError as exc:
                self._notify("Not done", str(exc), color="red")
            except Exception as exc:
                LOGGER.exception("tab %s: %s failed", self.session_id, action.__name__)
                self._notify("Error", f"{type(exc).__name__}: {exc}", color="red")

    def _poll(self) -> None:
        task = self.task
        version = self.ctx.versions.get(task)
        if version != self._library_version and self._library_future is None:
            self._library_version = version
            try:
                self._library_future = self.ctx.libraries.request(task)
            except RuntimeError:  # the app is stopping
                return
        future = self._library_future
        if future is not None and future.done():
            self._library_future = None
            try:
                library = future.result()
            except Exception as exc:
                LOGGER.exception("loading the %s recordings failed", task)
                self.controls.library_text.content = f"Cannot read the recordings: {exc}"
            else:
                if library.task == self.task:
                    self.library = library
                    self.controls.show_library(library)
        self.cleans.poll(self, self.task)
        self._poll_replay()

    def _poll_replay(self) -> None:
        player = self.replay
        if player is None or not player.finished:
            if player is not None:
                self.controls.stop_replay_button.disabled = False
            return
        self.replay, self.last_replay = None, player
        self.controls.stop_replay_button.disabled = True
        self.tab_scene.gizmo.position = hold_pose(self.session)  # inside the box: no ⚠ clamped
        if player.result is not None:
            error_mm = 1e3 * player.result.rms_error_m
            named = f"{player.track.kind}: {track_who_when(player.track)}"  # as the pickers
            self._notify("Replay done", f"{named}: tracked within {error_mm:.1f} mm RMS")

    # -- commands (worker thread) ---------------------------------------------------------------

    def _do_select_task(self, task: GuidedTask) -> None:
        if task == self.task:
            return
        if self.session.recording:
            self.controls.task_input.value = self.task
            raise BtError("stop or discard the recording before switching task")
        self._do_stop_replay()
        old = self.session
        self._time_offset_s += old.status().sim_time_s + 1.0
        old.close(save_incomplete=False)
        self.session = self._new_session(task)
        self.tab_scene.show_task(self.session.scene)
        TabScene.frame(self.client.camera, self.session.scene)
        self._task_shown()
        self.controls.task_input.value = task

    def _do_record(self) -> None:
        self._do_stop_replay()
        self.tab_scene.trail.clear()
        c = self.controls
        self.session.start_recording(c.name_input.value, c.theta_deg, c.rho)
        self.takes.started()

    def _do_save(self) -> None:
        self.takes.save(self.session)

    def _do_discard(self) -> None:
        self.session.discard()
        self.tab_scene.trail.clear()

    def _do_clean(self) -> None:
        self.ctx.cleaner.start(self.task, owner=self, rerun=self.logger.clean_target())
        self._notify("Cleaning", f"cleaning the {self.task} recordings in the background")

    def _do_cancel_clean(self) -> None:
        if self.ctx.cleaner.cancel(self.task, "cancelled from a tab"):
            self._notify("Clean cancelled", f"{self.task}: the previous cleaned demos stay")

    def _do_play(self, key: str) -> None:
        if self.session.recording:
            raise BtError("stop or discard the recording before replaying a demo")
        if self.library is None:
            raise BtError("the recordings are still loading")
        track = self.library.find(key)  # listed without samples: read them from its file now
        stale = functools.partial(self.ctx.versions.bump, self.task)  # a file gone: reload
        samples, paths = read_replay(self.library, track, self.ctx.samples, stale)
        self._do_stop_replay()
        for kind, path in sorted(paths, key=lambda p: p[0] == "cleaned"):  # cleaned on top
            self.tab_scene.draw_replay_path(kind, path)
        self.replay = ReplayPlayer(self.session, track, samples)
        self.replay.start()
        label = f"{track.kind}: {track_who_when(track)}"  # who and when, as the page
        self.logger.log_replay(label, samples.positions, track.kind)

    def _do_stop_replay(self) -> None:
        if self.replay is not None:
            self.replay.stop()
            self._poll_replay()
        self.tab_scene.clear_replay_paths()

    def _notify(self, title: str, body: str, color: Any = None) -> None:
        self.messages.append((title, "\n".join(display_text(x, 300) for x in body.split("\n"))))
        shown = "\n".join(map(breakable, body.split("\n")))  # takes/escape.py; wraps long names
        try:
            self.client.add_notification(title, shown, auto_close_seconds=6.0, color=color)
        except Exception:  # the tab may be gone
            LOGGER.debug("notification not shown: %s: %s", title, body)
