"""Settings of the teleop app (``bt teleop``'s flags and the ones only Python sets), checked
when they are made: a bad value is a ConfigError naming the flag, before any socket opens."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from bt_pipeline.data.tasks import GuidedTask, parse_guided_task
from bt_pipeline.exceptions import ConfigError
from bt_teleop.library.view import DEFAULT_LISTED
from bt_teleop.rerun.live import DEFAULT_GRPC_PORT, DEFAULT_WEB_PORT, RERUN_MODES, RerunMode
from bt_teleop.session.control_loop import SessionConfig
from bt_teleop.sim.scene import Robot, parse_robot

__all__ = ["AppOptions"]


@dataclass(frozen=True)
class AppOptions:
    """Settings of the teleop app (``bt teleop`` flags)."""

    host: str = "127.0.0.1"
    """Interface to bind; 127.0.0.1 keeps the app on this machine."""
    port: int = 8080
    """Port of the web app (the next free one if busy; 0: any free port)."""
    robot: Robot = "light"
    """FR3 model: light (bundled) or menagerie."""
    recordings: Path = Path("recordings")
    """Root folder of the recordings; demos go to <recordings>/<task>/."""
    rerun: RerunMode = "serve"
    """serve (live web viewer), save (.rrd files) or off."""
    max_sessions: int = 8
    """Most browser tabs with a robot at once."""
    idle_timeout_s: float = 600.0
    """A tab that sends no message for this long [s] (no drag, click, typing or camera move)
    is closed to free its place, unless it is recording a take; ``inf``: never."""
    operator_token: str | None = None
    """Typed into a tab's *Operator token* box, lets that tab exclude or restore anyone's demo
    (None: every tab moderates only its own demos)."""
    save_incomplete: bool = True
    """A closed tab's recording in progress: save it flagged incomplete, or discard it."""
    publish_hz: float = 30.0
    """Scene updates per second sent to each tab."""
    clean_epochs: int | None = None
    """Refinement epochs of the Clean button (None: the cleaner's default)."""
    clean_in_subprocess: bool = True
    """Run clean jobs in a separate process (keeps the sessions responsive)."""
    initial_task: GuidedTask = "wiping"
    """The task a new tab opens with."""
    rerun_grpc_port: int = DEFAULT_GRPC_PORT
    """Preferred port of the app's Rerun gRPC proxy (serve mode; a free one when busy). Not
    Rerun's default 9876: there a user's ``rerun FILE`` would find the app's viewer and stream
    the file into it instead of opening its own."""
    rerun_web_port: int = DEFAULT_WEB_PORT
    """Preferred port of the app's Rerun web viewer (serve mode; a free one when busy). Not
    Rerun's default 9090."""
    rerun_newest_first: bool = False
    """A Rerun viewer that connects late gets the newest data first (serve mode; off: it did
    not reach the present sooner in benchmarks/teleop/bench_teleop_rerun.py, docs/teleop.md)."""
    session: SessionConfig = field(default_factory=SessionConfig)
    """Control and recording rates of every session."""
    session_processes: bool = True
    """Run each tab's simulation (control loop, IK, recorder) in a child process of its own,
    one GIL per loop (bt_teleop/session/process.py); False: in the app's process."""
    trim_heap_every_s: float = 60.0
    """Give the C heap's free pages back to the system this often [s] (``inf``: never); the
    app's threads fragment glibc's arenas (docs/security.md, soak;
    bt_teleop/proc/native_memory.py)."""
    listed_demos: int = DEFAULT_LISTED
    """Newest takes of a task that each tab's Demo and Replay pickers offer (besides the table's
    demos): what a save sends every tab stays bounded however many takes the task has."""
    fancy_lighting: bool = False
    """viser's environment map and shadows: pretty with a GPU, but software WebGL (headless
    browsers, GPU-less laptops) needs tens of seconds to prepare them."""

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise ConfigError(f"--port must be in 0..65535; got {self.port}")
        if not self.idle_timeout_s > 0.0:
            raise ConfigError(
                f"--idle-timeout-s must be > 0 (inf: never); got {self.idle_timeout_s}"
            )
        if not self.trim_heap_every_s > 0.0:
            raise ConfigError(
                f"trim_heap_every_s must be > 0 (inf: never); got {self.trim_heap_every_s}"
            )
        if self.listed_demos < 1:
            raise ConfigError(f"--listed-demos must be ≥ 1; got {self.listed_demos}")
        if self.max_sessions < 1:
            raise ConfigError(f"--max-sessions must be ≥ 1; got {self.max_sessions}")
        if self.rerun not in RERUN_MODES:
            raise ConfigError(
                f"unknown --rerun {self.rerun!r}; valid values are {', '.join(RERUN_MODES)}"
            )
        if self.operator_token is not None and len(self.operator_token) < 8:
            raise ConfigError("--operator-token must have at least 8 characters")
        if not (self.publish_hz > 0.0 and self.publish_hz <= 240.0):
            raise ConfigError(f"publish_hz must be in (0, 240]; got {self.publish_hz}")
        parse_robot(self.robot)
        parse_guided_task(self.initial_task)
        object.__setattr__(self, "recordings", Path(self.recordings))
