"""The scripted operator: a JSON file drives a session (IK, simulation, recorder) without a browser.

A script is a JSON object::

    {"task": "wiping", "demonstrator": "ci", "theta_deg": 5, "rho": 1.1, "robot": "light",
     "waypoints": [[t_s, u, v], ...]}

Waypoints are end-effector target positions in the scene's task-plane coordinates [m] (u, v
along the plane axes, 0 at the plane origin), linearly interpolated in time; the orientation is
held at the scene's default. With ``"frame": "world"`` the rows are ``[t_s, x, y, z]`` in the
world frame. Optional keys: ``"gripper": [[t_s, open], ...]`` (1/true opens, 0/false closes; the
gripper starts open) and ``"settle_s"`` (time to reach the first waypoint before recording,
default 1 s). The recording starts at t = 0, ends at the last waypoint's time and is saved as one
demo file.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, get_args

import numpy as np

from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.records import MIN_SAMPLES, FloatArray
from bt_pipeline.data.tasks import GuidedTask, parse_guided_task
from bt_pipeline.exceptions import ConfigError
from bt_teleop.session.control_loop import Session, SessionConfig
from bt_teleop.sim.scene import Robot, SceneModel, load_scene, parse_robot

Frame = Literal["plane", "world"]
"""Coordinates of waypoints: task plane ``[t_s, u, v]`` or world ``[t_s, x, y, z]``."""
FRAMES: tuple[Frame, ...] = get_args(Frame)
SCRIPT_KEYS = (
    "task",
    "waypoints",
    "demonstrator",
    "theta_deg",
    "rho",
    "robot",
    "frame",
    "gripper",
    "settle_s",
)
"""Keys a script may have (task and waypoints are required)."""


@dataclass(frozen=True, eq=False)  # holds arrays: compare fields explicitly
class TeleopScript:
    """A parsed, checked script."""

    task: GuidedTask
    """The task (its scene)."""
    waypoints: FloatArray
    """Rows ``[t_s, u, v]`` (plane) or ``[t_s, x, y, z]`` (world), shape (K, 3 or 4)."""
    demonstrator: str = "script"
    """Demonstrator name stored in the demo."""
    theta_deg: float = math.nan
    """Demonstrator rotation θ [deg]; NaN when unknown."""
    rho: float = math.nan
    """Demonstrator scale ρ; NaN when unknown."""
    robot: Robot = "light"
    """Which FR3 model."""
    frame: Frame = "plane"
    """Coordinates of the waypoints."""
    gripper: tuple[tuple[float, bool], ...] = ()
    """Gripper commands (t_s, open), sorted by time."""
    settle_s: float = 1.0
    """Time to reach the first waypoint before recording starts [s]."""

    @property
    def duration_s(self) -> float:
        """Length of the recording: the last waypoint's time [s]."""
        return float(self.waypoints[-1, 0])

    def target_at(self, t_s: float, plane: TaskPlane) -> FloatArray:
        """World target position at time `t_s` [s] (held before the first/after the last row)."""
        times = self.waypoints[:, 0]
        coords = np.array([np.interp(t_s, times, column) for column in self.waypoints[:, 1:].T])
        return plane.to_world(coords) if self.frame == "plane" else coords

    def gripper_open_at(self, t_s: float) -> bool:
        """The gripper command in force at `t_s` [s] (open before any command)."""
        state = True
        for t_event, is_open in self.gripper:
            if t_event <= t_s:
                state = is_open
        return state


def parse_script(raw: Mapping[str, Any], source: str = "script") -> TeleopScript:
    """Check a decoded JSON script and return it typed.

    Args:
        raw: The JSON object.
        source: Where it came from, for messages (e.g. the file name).

    Raises:
        ConfigError: Unknown keys, unknown task/robot/frame, bad numbers or bad waypoint rows;
            the message names the key or the row.
        UnknownTaskError: The task is unknown (lists the valid ones).
    """
    if not isinstance(raw, Mapping):
        raise ConfigError(f"{source}: a script is a JSON object; got {type(raw).__name__}")
    unknown = sorted(set(raw) - set(SCRIPT_KEYS))
    if unknown:
        raise ConfigError(
            f"{source}: unknown key(s) {', '.join(unknown)}; valid keys are "
            f"{', '.join(SCRIPT_KEYS)}"
        )
    for key in ("task", "waypoints"):
        if key not in raw:
            raise ConfigError(f"{source}: missing {key!r}")
    try:
        task = parse_guided_task(raw["task"])
    except ConfigError as exc:
        raise type(exc)(f"{source}: {exc}") from None
    frame = raw.get("frame", "plane")
    if frame not in FRAMES:
        raise ConfigError(f"{source}: unknown frame {frame!r}; valid frames are plane, world")
    demonstrator = raw.get("demonstrator", "script")
    if not isinstance(demonstrator, str):
        raise ConfigError(f"{source}: demonstrator must be a string; got {demonstrator!r}")
    return TeleopScript(
        task=task,
        waypoints=_waypoints(raw["waypoints"], frame, source),
        demonstrator=demonstrator,
        theta_deg=_number(raw, "theta_deg", math.nan, source),
        rho=_number(raw, "rho", math.nan, source),
        robot=parse_robot(str(raw.get("robot", "light"))),
        frame=frame,
        gripper=_gripper(raw.get("gripper", []), source),
        settle_s=_number(raw, "settle_s", 1.0, source, minimum=0.0),
    )


def load_script(path: str | Path) -> TeleopScript:
    """Read and check a JSON script file.

    Raises:
        ConfigError: The file is missing, not JSON, or not a valid script.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot read script {path}: {exc.strerror or exc}") from None
    try:
        raw = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path} is not valid JSON: {exc}") from None
    return parse_script(raw, str(path))


def run_script(
    script: str | Path | Mapping[str, Any] | TeleopScript,
    recordings_dir: str | Path,
    *,
    scene: SceneModel | None = None,
    config: SessionConfig | None = None,
) -> Path:
    """Drive a session through `script`, record the demo and save it.

    Args:
        script: A script file, a decoded JSON object or a parsed script.
        recordings_dir: Root folder; the demo goes to ``<recordings_dir>/<task>/``.
        scene: A loaded scene to reuse (must match the script's task and robot).
        config: Session rates and policies.

    Returns:
        The file written.

    Raises:
        ConfigError: The script is invalid, too short to record, or `scene` does not match it.
        RecordingError: The demo cannot be written.
    """
    if isinstance(script, TeleopScript):
        parsed = script
    elif isinstance(script, Mapping):
        parsed = parse_script(script)
    else:
        parsed = load_script(script)
    if scene is None:
        scene = load_scene(parsed.task, parsed.robot)
    elif (scene.task, scene.robot) != (parsed.task, parsed.robot):
        raise ConfigError(
            f"the script is for {parsed.task} with robot {parsed.robot}; the scene given is "
            f"{scene.task} with robot {scene.robot}"
        )
    session = Session(scene, recordings_dir, config=config, session_id="script")
    record_hz = session.config.record_hz
    if parsed.duration_s * record_hz + 1 < MIN_SAMPLES:
        raise ConfigError(
            f"the waypoints span {parsed.duration_s:g} s; a demo needs at least {MIN_SAMPLES} "
            f"samples at {record_hz:g} Hz, so the last waypoint must be at t >= "
            f"{(MIN_SAMPLES - 1) / record_hz:.2f} s"
        )
    try:
        session.set_gripper(parsed.gripper_open_at(0.0))
        session.set_target(parsed.target_at(0.0, scene.plane))
        session.step_for(parsed.settle_s)
        session.start_recording(parsed.demonstrator, parsed.theta_deg, parsed.rho)
        for k in range(round(parsed.duration_s / session.dt_s)):
            t_s = k * session.dt_s
            session.set_target(parsed.target_at(t_s, scene.plane))
            session.set_gripper(parsed.gripper_open_at(t_s))
            session.step(1)
        return session.stop_and_save()
    finally:
        session.close(save_incomplete=False)


def _number(
    raw: Mapping[str, Any], key: str, default: float, source: str, minimum: float | None = None
) -> float:
    value = raw.get(key, default)
    if value is None:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, int | float) or math.isinf(value):
        raise ConfigError(f"{source}: {key} must be a finite number; got {value!r}")
    if minimum is not None and not value >= minimum:
        raise ConfigError(f"{source}: {key} must be >= {minimum:g}; got {value!r}")
    return float(value)


def _waypoints(rows: Any, frame: Frame, source: str) -> FloatArray:
    width = 3 if frame == "plane" else 4
    form = "[t_s, u, v]" if frame == "plane" else "[t_s, x, y, z]"
    if not isinstance(rows, list) or len(rows) < 2:
        raise ConfigError(f"{source}: waypoints must be a list of at least 2 rows {form}")
    table = np.empty((len(rows), width))
    for i, row in enumerate(rows):
        ok = (
            isinstance(row, list)
            and len(row) == width
            and all(isinstance(x, int | float) and not isinstance(x, bool) for x in row)
            and all(math.isfinite(x) for x in row)
        )
        if not ok:
            raise ConfigError(
                f"{source}: waypoints[{i}] = {row!r}; expected {form} ({width} finite numbers) "
                f"for frame {frame!r}"
            )
        table[i] = row
        if i == 0 and row[0] < 0.0:
            raise ConfigError(f"{source}: waypoints[0] has time {row[0]} s; times start at >= 0")
        if i > 0 and not row[0] > table[i - 1, 0]:
            raise ConfigError(
                f"{source}: waypoints[{i}] has time {row[0]} s, not after waypoints[{i - 1}] "
                f"({table[i - 1, 0]:g} s); times must increase strictly"
            )
    return table


def _gripper(events: Any, source: str) -> tuple[tuple[float, bool], ...]:
    if not isinstance(events, list):
        raise ConfigError(f"{source}: gripper must be a list of [t_s, open] rows")
    parsed: list[tuple[float, bool]] = []
    for i, event in enumerate(events):
        ok = (
            isinstance(event, list)
            and len(event) == 2
            and isinstance(event[0], int | float)
            and not isinstance(event[0], bool)
            and math.isfinite(event[0])
            and event[1] in (0, 1)  # also True / False
        )
        if not ok:
            raise ConfigError(
                f"{source}: gripper[{i}] = {event!r}; expected [t_s, open] with open 1/true "
                "(open) or 0/false (close)"
            )
        parsed.append((float(event[0]), bool(event[1])))
    return tuple(sorted(parsed, key=lambda e: e[0]))
