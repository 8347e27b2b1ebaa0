"""What every browser tab shares: the app's :class:`UiContext` and the :class:`TaskVersions`
counters that tell each tab when a task's recordings changed on disk."""

from __future__ import annotations

import asyncio
import concurrent.futures
import threading
from dataclasses import dataclass, field
from pathlib import Path

from bt_pipeline.data.tasks import GuidedTask
from bt_teleop.clean.runner import CleanRunner
from bt_teleop.library.loader import LibraryLoader
from bt_teleop.library.track_samples import TrackReader
from bt_teleop.library.view import DEFAULT_LISTED
from bt_teleop.rerun.live import RerunHub
from bt_teleop.session.config import SessionConfig
from bt_teleop.sim.scene import Robot

__all__ = ["TaskVersions", "UiContext"]


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
    libraries: LibraryLoader
    """Loads a task's library once for every tab, reading only changed files."""
    versions: TaskVersions = field(default_factory=TaskVersions)
    samples: TrackReader = field(default_factory=TrackReader)
    """Reads a track's samples when it is played (the libraries list tracks without them)."""
    session_config: SessionConfig = field(default_factory=SessionConfig)
    session_processes: bool = True
    """Each tab's simulation in a child process of its own (False: in the app's process)."""
    publish_hz: float = 30.0
    """Scene updates per second sent to each tab."""
    save_incomplete: bool = True
    """A closed tab's recording in progress: save it flagged incomplete (True) or discard it."""
    initial_task: GuidedTask = "wiping"
    listed_demos: int = DEFAULT_LISTED
    """Newest takes of a task the Demo and Replay pickers offer (bt_teleop/library/view.py)."""
    event_loop: asyncio.AbstractEventLoop | None = None
    """viser's event loop (where async GUI callbacks run)."""
    operator_token: str | None = None
    """The app's operator token (None: no operators; a tab moderates only its own demos)."""
    fancy_lighting: bool = False
    """viser's environment map and shadows (pretty with a GPU; software WebGL, as in headless
    browsers and GPU-less laptops, takes tens of seconds to prepare them)."""
