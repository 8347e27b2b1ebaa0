"""One browser tab: its GUI, its scene and its session (own robot, target, recorder, trail).

Data flow (everything a tab does stays in the tab)::

    browser ──gizmo drag──> async callback ──> Session.set_target   (latest target, under lock)
            ──buttons, task, θ/ρ──> async callback ──> command queue (in order)
                                                            │
    tab worker thread, every 1 / publish_hz [s]:            v
        run queued commands (switch task, record, save, discard, clean, play, ...)
        Session.status() -> MjSceneView.update(qpos), target marker, trail, status text
            (grouped with client.atomic(): one scene update per period)
        -> SessionLogger.log_state (Rerun, off this thread's critical path)
        poll: clean job progress, replay progress, library reloads
    Session thread: fixed-rate IK + physics (bt_teleop.session), never touched by viser

Callbacks never block: they store a value or queue a command. The worker is the only thread
that changes the tab's scene and the only one that swaps its Session (task switch).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import viser

from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.tasks import TASKS, Task, parse_task
from bt_pipeline.exceptions import BtError
from bt_teleop.cleaning import CleanJob, CleanRunner
from bt_teleop.replay import (
    ReplayPlayer,
    ReplayTrack,
    TaskLibrary,
    library_markdown,
    load_library,
)
from bt_teleop.rerun_live import RerunHub, SessionLogger
from bt_teleop.scene import Robot, load_scene
from bt_teleop.session import Session, SessionConfig, SessionStatus
from bt_teleop.viewer import MjSceneView, Trail, draw_path, floor_height, guide_loop_world

LOGGER = logging.getLogger("bt.teleop")
RAW_RGB = (255, 140, 0)
"""Colour of a replayed raw demo's path."""
CLEANED_RGB = (40, 200, 110)
"""Colour of a replayed cleaned demo's path."""
TRAIL_RGB = (220, 40, 60)
"""Colour of the live end-effector trail while recording."""
GUIDE_RGB = (70, 130, 255)
"""Colour of the task-shape guide."""
NO_DEMOS = "(no demos yet)"


class TaskVersions:
    """A counter per task, bumped when its files change, so every tab knows when to reload."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._versions: dict[str, int] = {}

    def bump(self, task: str) -> None:
        """Mark `task`'s files as changed."""
        with self._lock:
            self._versions[task] = self._versions.get(task, 0) + 1

    def get(self, task: str) -> int:
        """The current version of `task`'s files."""
        with self._lock:
            return self._versions.get(task, 0)


@dataclass(frozen=True)
class UiContext:
    """What every tab shares (built once by the app)."""

    recordings_dir: Path
    robot: Robot
    cleaner: CleanRunner
    rerun: RerunHub
    background: concurrent.futures.Executor
    """Runs slow reads (loading and scoring a task's demos) off the tab workers."""
    versions: TaskVersions = field(default_factory=TaskVersions)
    session_config: SessionConfig = field(default_factory=SessionConfig)
    publish_hz: float = 30.0
    """Scene updates per second sent to each tab."""
    save_incomplete: bool = True
    """A closed tab's recording in progress: save it flagged incomplete (True) or discard it."""
    initial_task: Task = "wiping"
    event_loop: asyncio.AbstractEventLoop | None = None
    """viser's event loop (where async GUI callbacks run)."""
    fancy_lighting: bool = False
    """viser's environment map and shadows (pretty with a GPU; software WebGL, as in headless
    browsers and GPU-less laptops, takes tens of seconds to prepare them)."""


@dataclass(frozen=True)
class Frame:
    """The last scene update sent to the tab."""

    index: int
    """Updates sent so far."""
    wall_time_s: float
    """``time.perf_counter()`` when it was queued [s]."""
    sim_time_s: float
    """Simulation time of the pose sent [s]."""
    ee_pos: FloatArray
    """End-effector position sent, shape (3,) [m]."""


class ClientUI:
    """The GUI, scene and session of one browser tab."""

    def __init__(self, client: viser.ClientHandle, ctx: UiContext, session_id: str) -> None:
        """Build the tab's GUI and scene, start its session and its worker thread."""
        self.client = client
        self.ctx = ctx
        self.session_id = session_id
        self.logger: SessionLogger = ctx.rerun.session_logger(session_id)
        self.messages: list[tuple[str, str]] = []
        """(title, body) of every notification shown (newest last)."""
        self.saved: list[Path] = []
        """Demo files this tab saved."""
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
        self._seen_job: CleanJob | None = None
        self._status_text = ""
        self._build_gui()
        if not ctx.fancy_lighting:
            _plain_lighting(client.scene)
        self.session: Session = self._new_session(ctx.initial_task)
        self.view = MjSceneView(client.scene, self.session.scene.model, root="/robot")
        self._draw_task_scene()
        self.trail = Trail(client.scene, "/trail", TRAIL_RGB)
        self._worker = threading.Thread(target=self._run, name=f"bt-tab-{session_id}", daemon=True)
        self._worker.start()

    # -- actions (any thread; run in order by the worker) -------------------------------------

    def select_task(self, task: str) -> None:
        """Load `task`'s scene for this tab (refused while recording)."""
        self._queue(self._do_select_task, parse_task(task))

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

    def play(self, key: str) -> None:
        """Replay the demo `key` of this task's library on this tab's robot."""
        self._queue(self._do_play, key)

    def stop_replay(self) -> None:
        """Stop a replay and remove its paths."""
        self._queue(self._do_stop_replay)

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
    def task(self) -> Task:
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
                self.saved.append(path)
                self.ctx.versions.bump(self.task)
            self.logger.close()
            return path

    # -- GUI ----------------------------------------------------------------------------------

    def _build_gui(self) -> None:
        gui = self.client.gui
        task = self.ctx.initial_task
        with gui.add_folder("Demonstration"):
            self.task_input = gui.add_dropdown("Task", TASKS, initial_value=task)
            self.name_input = gui.add_text("Demonstrator", initial_value="anonymous")
            self.theta_input = gui.add_slider("θ [deg]", min=-30, max=30, step=1, initial_value=0)
            self.rho_input = gui.add_slider("ρ", min=0.5, max=1.5, step=0.05, initial_value=1.0)
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
            self.clean_progress = gui.add_progress_bar(0.0, visible=False, animated=True)
            self.replay_input: viser.GuiDropdownHandle[str] = gui.add_dropdown(
                "Replay",
                [str(NO_DEMOS)],  # str, not a literal type: the options change
            )
            self.play_button = gui.add_button("Play")
            self.stop_replay_button = gui.add_button("Stop replay", disabled=True)
        if self.ctx.rerun.viewer_url is not None:
            gui.add_html(
                f'<p style="padding: 0 0.75em"><a href="{self.ctx.rerun.viewer_url}" '
                'target="_blank" rel="noopener">Open the live Rerun viewer</a></p>'
            )
        elif self.ctx.rerun.mode == "save":
            gui.add_markdown("Rerun: this session is saved under `recordings/rerun/`.")

        @self.task_input.on_update
        async def _(_: viser.GuiEvent) -> None:
            if self.task_input.value != self.task:
                self.select_task(self.task_input.value)

        @self.theta_input.on_update
        async def _(_: viser.GuiEvent) -> None:
            self._guide_dirty = True

        @self.rho_input.on_update
        async def _(_: viser.GuiEvent) -> None:
            self._guide_dirty = True

        @self.plane_input.on_update
        async def _(_: viser.GuiEvent) -> None:
            self.session.set_stay_on_plane(self.plane_input.value)

        @self.gripper_input.on_click
        async def _(_: viser.GuiEvent) -> None:
            self.session.set_gripper(self.gripper_input.value == "Open")

        for button, action in (
            (self.record_button, self.record),
            (self.save_button, self.stop_and_save),
            (self.discard_button, self.discard),
            (self.clean_button, self.clean),
            (self.stop_replay_button, self.stop_replay),
        ):
            button.on_click(_async_action(action))

        @self.play_button.on_click
        async def _(_: viser.GuiEvent) -> None:
            self.play(self.replay_input.value)

    # -- scene --------------------------------------------------------------------------------

    def _new_session(self, task: Task) -> Session:
        scene = load_scene(task, self.ctx.robot)
        session = Session(
            scene,
            self.ctx.recordings_dir,
            config=self.ctx.session_config,
            session_id=self.session_id,
        )
        session.set_stay_on_plane(self.plane_input.value)
        session.start()
        return session

    def _draw_task_scene(self) -> None:
        """(Re)draw what depends on the task: gizmo, target marker, floor, guide, controls."""
        scene_api, scene = self.client.scene, self.session.scene
        self.gizmo = scene_api.add_transform_controls(
            "/target",
            scale=0.18,
            disable_rotations=True,
            depth_test=False,
            position=scene.ready_pos,
            wxyz=scene.ee_quat,
        )

        @self.gizmo.on_update
        async def _(event: viser.TransformControlsEvent) -> None:
            if self.replay is None:
                self.session.set_target(event.target.position)

        self.target_marker = scene_api.add_icosphere(
            "/target_marker", radius=0.008, color=(255, 200, 0), position=scene.ready_pos
        )
        floor_z = floor_height(scene.model)
        if floor_z is not None:
            scene_api.add_grid("/floor", width=4.0, height=4.0, position=(0.0, 0.0, floor_z))
        self._guide_dirty = True
        self.gripper_input.visible = scene.has_gripper
        self._library_version = -1  # reload the task's recordings

    def _publish(self) -> None:
        status = self.session.status()
        if self._guide_dirty:
            self._guide_dirty = False
            loop = guide_loop_world(
                self.session.scene, float(self.theta_input.value), float(self.rho_input.value)
            )
            draw_path(self.client.scene, "/guide", loop, GUIDE_RGB, closed=True, thickness=0.003)
        with self.client.atomic():
            self.view.update(status.qpos)
            self.target_marker.position = status.target_pos
            self.target_marker.color = (255, 60, 60) if status.target_clamped else (255, 200, 0)
            if status.recording:
                self.trail.set(self.session.trail())
            if self.replay is not None:
                self.gizmo.position = status.command_pos
            text = status_markdown(status, self.replay)
            if text != self._status_text:
                self._status_text = text
                self.status_text.content = text
            self.record_button.disabled = status.recording
            self.save_button.disabled = not status.recording
            self.discard_button.disabled = not status.recording
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
                self._library_future = self.ctx.background.submit(
                    load_library, self.ctx.recordings_dir, task
                )
            except RuntimeError:  # the app is stopping
                return
        future = self._library_future
        if future is not None and future.done():
            self._library_future = None
            try:
                library = future.result()
            except Exception as exc:
                LOGGER.exception("loading the %s recordings failed", task)
                self.library_text.content = f"Cannot read the recordings: {exc}"
            else:
                if library.task == self.task:
                    self._show_library(library)
        self._poll_clean()
        self._poll_replay()

    def _show_library(self, library: TaskLibrary) -> None:
        self.library = library
        self.library_text.content = library_markdown(library)
        keys = [track.key for track in library.tracks] or [NO_DEMOS]
        current = self.replay_input.value
        self.replay_input.options = keys
        self.replay_input.value = current if current in keys else keys[-1]

    def _poll_clean(self) -> None:
        job = self.ctx.cleaner.current
        if job is None:
            return
        progress = job.progress()
        running = progress.state == "running" and job.task == self.task
        self.clean_progress.visible = running
        if running:
            self.clean_progress.value = 100.0 * progress.fraction
        self.clean_button.disabled = progress.state == "running"
        if job.owner is self and job.finished and self._seen_job is not job:
            self._seen_job = job
            if progress.state == "done":
                self._notify("Clean done", f"{job.task}: cleaned demos in {progress.output}")
                if job.result is not None:
                    self.logger.log_clean_result(job.result)
            else:
                self._notify("Clean failed", progress.message, color="red")

    def _poll_replay(self) -> None:
        player = self.replay
        if player is None or not player.finished:
            if player is not None:
                self.stop_replay_button.disabled = False
            return
        self.replay, self.last_replay = None, player
        self.stop_replay_button.disabled = True
        status = self.session.status()
        self.session.set_target(status.ee_pos)
        self.gizmo.position = status.ee_pos
        if player.result is not None:
            error_mm = 1e3 * player.result.rms_error_m
            self._notify("Replay done", f"{player.track.key}: tracked within {error_mm:.1f} mm RMS")

    # -- commands (worker thread) ---------------------------------------------------------------

    def _do_select_task(self, task: Task) -> None:
        if task == self.task:
            return
        if self.session.recording:
            self.task_input.value = self.task
            raise BtError("stop or discard the recording before switching task")
        self._do_stop_replay()
        old = self.session
        self._time_offset_s += old.status().sim_time_s + 1.0
        old.close(save_incomplete=False)
        self.session = self._new_session(task)
        self.view.remove()
        self.view = MjSceneView(self.client.scene, self.session.scene.model, root="/robot")
        self.trail.clear()
        self._draw_task_scene()
        self.task_input.value = task

    def _do_record(self) -> None:
        self._do_stop_replay()
        self.trail.clear()
        self.session.start_recording(
            self.name_input.value, float(self.theta_input.value), float(self.rho_input.value)
        )

    def _do_save(self) -> None:
        trail = self.session.trail()
        path = self.session.stop_and_save()
        self.saved.append(path)
        self.ctx.versions.bump(self.task)
        self.logger.log_demo(path.stem, trail)
        self._notify("Saved", f"{path.parent.name}/{path.name}")

    def _do_discard(self) -> None:
        self.session.discard()
        self.trail.clear()

    def _do_clean(self) -> None:
        self.ctx.cleaner.start(self.task, owner=self)
        self._notify("Cleaning", f"cleaning the {self.task} recordings in the background")

    def _do_play(self, key: str) -> None:
        if self.session.recording:
            raise BtError("stop or discard the recording before replaying a demo")
        if self.library is None:
            raise BtError("the recordings are still loading")
        track = self.library.find(key)
        self._do_stop_replay()
        self._draw_replay_paths(track)
        self.replay = ReplayPlayer(self.session, track)
        self.replay.start()

    def _do_stop_replay(self) -> None:
        if self.replay is not None:
            self.replay.stop()
            self._poll_replay()
        for name in ("/replay/raw", "/replay/cleaned"):
            handle = self.client.scene.get_handle_by_name(name)
            if handle is not None:
                handle.remove()

    def _draw_replay_paths(self, track: ReplayTrack) -> None:
        tracks = [track]
        if track.kind == "cleaned" and self.library is not None:  # its raw source, to compare
            raw_key = "raw · " + track.key.removeprefix("cleaned · ")
            tracks += [t for t in self.library.raw if t.key == raw_key]
        for shown in tracks:
            color = CLEANED_RGB if shown.kind == "cleaned" else RAW_RGB
            draw_path(self.client.scene, f"/replay/{shown.kind}", shown.positions, color)

    def _notify(self, title: str, body: str, color: Any = None) -> None:
        self.messages.append((title, body))
        try:
            self.client.add_notification(title, body, auto_close_seconds=6.0, color=color)
        except Exception:  # the tab may be gone
            LOGGER.debug("notification not shown: %s: %s", title, body)


def _async_action(action: Callable[[], None]) -> Callable[[viser.GuiEvent], Any]:
    """An async (in-order) click callback that queues `action`."""

    async def callback(_: viser.GuiEvent) -> None:
        action()

    return callback


def _plain_lighting(scene_api: viser.SceneApi) -> None:
    """Cheap lighting: no environment map, no shadows; sky, ambient and a key light."""
    scene_api.configure_environment_map(None)
    scene_api.configure_default_lights(enabled=False, cast_shadow=False)
    scene_api.add_light_hemisphere(
        "/lights/sky", sky_color=(255, 255, 255), ground_color=(90, 90, 100), intensity=1.2
    )
    scene_api.add_light_ambient("/lights/ambient", intensity=0.6)
    scene_api.add_light_directional(
        "/lights/key", intensity=1.6, position=(1.5, -1.0, 2.5), cast_shadow=False
    )


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


__all__ = ["ClientUI", "Frame", "TaskVersions", "UiContext", "status_markdown"]
