"""Task scenes: one FR3 (our light model or MuJoCo Menagerie's), one tool and one task scene.

A task scene (``scenes/<task>.xml``) holds the table and the task's objects and declares, in
MJCF ``<custom>`` fields, its task plane, workspace box, default end-effector orientation and
tool. :func:`load_scene` composes it with ``mujoco.MjSpec.attach``::

    robot MJCF (fr3_light.xml | Menagerie fr3.xml) --attach tool at attachment_site-->
    robot + tool --attach at the world origin--> task scene --compile--> SceneModel

and compiles a second, kinematic model without the free objects for the IK. Both robots have
the same names (fr3_joint1..7, attachment_site, keyframe home), so nothing downstream asks which
robot it drives.
"""

# mujoco ships compiled bindings without type stubs, so pyright cannot see MjModel, mj_step,
# mjtObj, ...: attribute checks on the mujoco module are off in this file.
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import contextlib
import logging
import os
import threading
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, get_args

import mujoco
import numpy as np

from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.tasks import GuidedTask, parse_guided_task
from bt_pipeline.exceptions import ConfigError
from bt_teleop.sim.workspace import Workspace

Robot = Literal["light", "menagerie"]
"""Which FR3 model: ``light`` (ours, primitive geoms, no download) or ``menagerie`` (meshes)."""
ROBOTS: tuple[Robot, ...] = get_args(Robot)

SCENES_DIR = Path(__file__).resolve().parents[2] / "scenes"
"""The bundled scenes (``scenes/`` at the repository root)."""
LIGHT_ROBOT_FILE = SCENES_DIR / "fr3_light.xml"
MENAGERIE_NAME = "franka_fr3"
ARM_JOINTS: tuple[str, ...] = tuple(f"fr3_joint{k}" for k in range(1, 8))
"""Arm joints and their position actuators (same names)."""
EE_SITE = "attachment_site"
HOME_KEY = "home"
TABLE_GEOM = "table"
GRIPPER_ACTUATOR = "gripper"
AVOIDING_LINKS: tuple[str, ...] = tuple(f"fr3_link{k}_collision" for k in range(3, 8))
"""Robot collision geoms the IK keeps off the table (the tool's guards are added)."""
GUARD_SUFFIX = "_guard"
"""Tool geoms named ``*_guard`` are the IK's table-avoidance proxies: spheres without physical
contact in the simulation, enabled in the IK model only. Small spheres give one well-defined
witness point each, where a box or cylinder lying flat above the table has a whole face and
mink's linearised distance constraint lets the face tilt through the table."""

_ATTACH_LOCK = threading.Lock()
_EMPTY_PREFIX = "Attaching a spec with an empty prefix"
LOGGER = logging.getLogger("bt.teleop")


@dataclass(frozen=True, eq=False)  # holds arrays: compare fields explicitly
class SceneModel:
    """A compiled task scene with the robot and its tool, and what the controller needs of it."""

    task: GuidedTask
    """The task the scene is for."""
    robot: Robot
    """Which FR3 model drives it."""
    model: mujoco.MjModel
    """The simulation model (shared read-only by every session using the scene)."""
    ik_model: mujoco.MjModel
    """The kinematic model for the IK: the same scene without free-floating objects."""
    plane: TaskPlane
    """The task plane declared by the scene."""
    workspace: Workspace
    """Box the end-effector targets are clamped to."""
    ee_quat: FloatArray
    """Default end-effector orientation (wxyz), shape (4,)."""
    seed_q_arm: FloatArray
    """Arm posture fr3_joint1..7 the IK starts from, shape (7,), in [rad]."""
    xml: str
    """The composed scene as MJCF (self-contained for ``light``; Menagerie meshes by path)."""
    scene_file: Path
    """The task scene file."""
    robot_source: str
    """Where the robot model came from (file, or Menagerie package and version)."""
    site_id: int
    """Id of the end-effector site ``attachment_site`` in :attr:`model`."""
    arm_qpos_adr: tuple[int, ...]
    """qpos addresses of fr3_joint1..7 in :attr:`model`."""
    ik_arm_qpos_adr: tuple[int, ...]
    """qpos addresses of fr3_joint1..7 in :attr:`ik_model`."""
    arm_actuator_ids: tuple[int, ...]
    """Ids of the position actuators fr3_joint1..7."""
    gripper_actuator_id: int | None
    """Id of the gripper's position actuator, None without a gripper."""
    gripper_qpos_adr: tuple[int, ...]
    """qpos addresses of the gripper's finger joints (empty without a gripper)."""
    avoid_geoms: tuple[str, ...]
    """Geoms the IK keeps at a distance from the table."""

    @property
    def has_gripper(self) -> bool:
        """Whether the scene's tool is a gripper with an open/close command."""
        return self.gripper_actuator_id is not None

    @property
    def gripper_ctrl_range(self) -> tuple[float, float]:
        """(closed, open) control values of the gripper actuator [m]; (0, 0) without one."""
        if self.gripper_actuator_id is None:
            return (0.0, 0.0)
        lo, hi = self.model.actuator_ctrlrange[self.gripper_actuator_id]
        return (float(lo), float(hi))

    @property
    def ready_pos(self) -> FloatArray:
        """The end-effector position a session starts at: the plane origin, shape (3,) [m]."""
        return self.workspace.clamp(self.plane.origin)[0]


def load_scene(
    task: str, robot: str = "light", *, scene_file: str | Path | None = None
) -> SceneModel:
    """Compose and compile the scene of `task` with the chosen robot.

    Args:
        task: wiping, weaving or pick_and_place.
        robot: ``light`` (bundled, no download) or ``menagerie`` (through the
            ``mujoco_menagerie`` package, which honours ``MENAGERIE_ROOT``).
        scene_file: A task scene to use instead of ``scenes/<task>.xml``.

    Raises:
        UnknownTaskError: `task` is not a known task.
        ConfigError: `robot` is unknown, the scene file is missing or lacks a custom field, or
            the Menagerie model cannot be found.
    """
    task_name = parse_guided_task(task)
    robot_name = parse_robot(robot)
    path = Path(scene_file) if scene_file is not None else SCENES_DIR / f"{task_name}.xml"
    if not path.is_file():
        raise ConfigError(f"scene file {path} does not exist")
    spec = mujoco.MjSpec.from_file(str(path))
    declared = _text(spec, "bt_task", path)
    if declared != task_name:
        raise ConfigError(f"{path} declares bt_task {declared!r}, not {task_name!r}")
    plane = TaskPlane(
        origin=_numeric(spec, "bt_plane_origin", 3, path),
        axes=_numeric(spec, "bt_plane_axes", 6, path).reshape(2, 3),
    )
    workspace = Workspace(
        lo=_numeric(spec, "bt_workspace_lo", 3, path), hi=_numeric(spec, "bt_workspace_hi", 3, path)
    )
    ee_quat = _numeric(spec, "bt_ee_quat", 4, path)
    ee_quat = ee_quat / np.linalg.norm(ee_quat)
    seed_q_arm = _numeric(spec, "bt_seed_qpos", len(ARM_JOINTS), path)

    tool_file = path.parent / _text(spec, "bt_tool", path)
    if not tool_file.is_file():
        raise ConfigError(f"{path}: bt_tool names {tool_file}, which does not exist")
    model, ik_model, xml, tool_root, robot_source = _compose(spec, robot_name, tool_file)

    gripper_id = _id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, GRIPPER_ACTUATOR)
    gripper_qpos: tuple[int, ...] = ()
    if gripper_id is not None:
        gripper_qpos = tuple(
            int(model.jnt_qposadr[j])
            for j in range(model.njnt)
            if _in_subtree(model, int(model.jnt_bodyid[j]), tool_root)
        )
    avoid = [g for g in AVOIDING_LINKS if _id(model, mujoco.mjtObj.mjOBJ_GEOM, g) is not None]
    avoid += [
        model.geom(g).name
        for g in range(model.ngeom)
        if model.geom(g).name.endswith(GUARD_SUFFIX)
        and _in_subtree(model, int(model.geom_bodyid[g]), tool_root)
    ]
    if _id(model, mujoco.mjtObj.mjOBJ_GEOM, TABLE_GEOM) is None:
        raise ConfigError(f"{path} has no geom named {TABLE_GEOM!r}")
    return SceneModel(
        task=task_name,
        robot=robot_name,
        model=model,
        ik_model=ik_model,
        plane=plane,
        workspace=workspace,
        ee_quat=ee_quat,
        seed_q_arm=seed_q_arm,
        xml=xml,
        scene_file=path,
        robot_source=robot_source,
        site_id=_require(model, mujoco.mjtObj.mjOBJ_SITE, EE_SITE),
        arm_qpos_adr=_qpos_adr(model, ARM_JOINTS),
        ik_arm_qpos_adr=_qpos_adr(ik_model, ARM_JOINTS),
        arm_actuator_ids=tuple(
            _require(model, mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in ARM_JOINTS
        ),
        gripper_actuator_id=gripper_id,
        gripper_qpos_adr=gripper_qpos,
        avoid_geoms=tuple(avoid),
    )


def _compose(
    spec: mujoco.MjSpec, robot: Robot, tool_file: Path
) -> tuple[mujoco.MjModel, mujoco.MjModel, str, str, str]:
    """Attach tool and robot to the task scene `spec` (modified) and compile it.

    Returns:
        The simulation model, the IK model, the composed XML, the tool's root body name and the
        robot's source.
    """
    robot_spec, robot_source, meshdir = _robot_spec(robot)
    tool_spec = mujoco.MjSpec.from_file(str(tool_file))
    tool_body = tool_spec.worldbody.first_body()
    if tool_body is None:
        raise ConfigError(f"{tool_file} has no body to attach to {EE_SITE}")
    for part in (robot_spec, tool_spec):  # the real FR3 compensates gravity; so do we
        for body in part.bodies:
            if body.name != "world":
                body.gravcomp = 1.0
    site = robot_spec.site(EE_SITE)
    if site is None:
        raise ConfigError(f"{robot_source} has no site {EE_SITE!r}")
    with _quiet_attach():
        robot_spec.attach(tool_spec, site=site, prefix="")
        spec.attach(robot_spec, frame=spec.worldbody.add_frame(), prefix="")
        if meshdir is not None:
            spec.meshdir = meshdir
        model = spec.compile()
        xml = spec.to_xml()
        ik_spec = spec.copy()  # the IK sees the robot, the tool and the fixed scene only
        for body in list(ik_spec.worldbody.bodies):
            if any(j.type == mujoco.mjtJoint.mjJNT_FREE for j in body.joints):
                ik_spec.delete(body)
        for geom in ik_spec.geoms:
            if geom.name.endswith(GUARD_SUFFIX):
                geom.contype, geom.conaffinity = 1, 1
        ik_model = ik_spec.compile()
    return model, ik_model, xml, tool_body.name, robot_source


def robot_model(robot: str) -> mujoco.MjModel:
    """The bare FR3 of `robot` (no table, no tool), e.g. to compare the two models' kinematics."""
    spec, _, meshdir = _robot_spec(parse_robot(robot))
    if meshdir is not None:
        spec.meshdir = meshdir
    return spec.compile()


def parse_robot(robot: str) -> Robot:
    """Return `robot` as a :data:`Robot`, or raise a ConfigError that lists the valid names."""
    for name in ROBOTS:
        if robot == name:
            return name
    raise ConfigError(f"unknown robot {robot!r}; valid robots are {', '.join(ROBOTS)}")


def _robot_spec(robot: Robot) -> tuple[mujoco.MjSpec, str, str | None]:
    """The robot's MjSpec, a description of its source, and its mesh folder (None: no meshes)."""
    if robot == "light":
        return mujoco.MjSpec.from_file(str(LIGHT_ROBOT_FILE)), "scenes/fr3_light.xml", None
    import mujoco_menagerie  # deferred: only the menagerie robot needs it

    try:
        entry = mujoco_menagerie.get(MENAGERIE_NAME)
        xml_path = entry.xml(entry.default_model)
    except mujoco_menagerie.MenagerieError as exc:
        root = os.environ.get("MENAGERIE_ROOT")
        hint = (
            f"MENAGERIE_ROOT={root} must hold {MENAGERIE_NAME}/"
            if root
            else "connect to the network once, or set MENAGERIE_ROOT to a folder holding "
            f"{MENAGERIE_NAME}/"
        )
        raise ConfigError(f"cannot load MuJoCo Menagerie's FR3 ({exc}); {hint}") from exc
    spec = mujoco.MjSpec.from_file(str(xml_path))
    meshdir = str((xml_path.parent / (spec.meshdir or ".")).resolve())
    source = f"mujoco_menagerie {mujoco_menagerie.__version__}: {MENAGERIE_NAME}/{xml_path.name}"
    return spec, source, meshdir


@contextlib.contextmanager
def _quiet_attach() -> Iterator[None]:
    """Silence MuJoCo's warning about attaching with an empty prefix; log any other warning.

    The robot and tool keep their own names (fr3_joint1, attachment_site, ...), which are unique
    in every bundled scene, so the empty prefix is intended.
    """
    messages: list[str] = []
    with _ATTACH_LOCK, warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=_EMPTY_PREFIX)
        previous = mujoco.get_mju_user_warning()
        mujoco.set_mju_user_warning(messages.append)
        try:
            yield
        finally:
            mujoco.set_mju_user_warning(previous)
    for message in messages:
        if _EMPTY_PREFIX not in message:
            LOGGER.warning("MuJoCo: %s", message.strip())


def _numeric(spec: mujoco.MjSpec, name: str, size: int, path: Path) -> FloatArray:
    element = spec.numeric(name)
    if element is None:
        raise ConfigError(f"{path} lacks <custom><numeric name={name!r}> with {size} numbers")
    values = np.array(list(element.data), dtype=np.float64)
    if values.shape != (size,) or not np.all(np.isfinite(values)):
        raise ConfigError(f"{path}: numeric {name!r} must hold {size} finite numbers; got {values}")
    return values


def _text(spec: mujoco.MjSpec, name: str, path: Path) -> str:
    element = spec.text(name)
    if element is None or not element.data:
        raise ConfigError(f"{path} lacks <custom><text name={name!r}>")
    return str(element.data)


def _id(model: mujoco.MjModel, kind: mujoco.mjtObj, name: str) -> int | None:
    index = mujoco.mj_name2id(model, kind, name)
    return None if index < 0 else int(index)


def _require(model: mujoco.MjModel, kind: mujoco.mjtObj, name: str) -> int:
    index = _id(model, kind, name)
    if index is None:
        raise ConfigError(f"the composed scene has no {kind.name[6:].lower()} named {name!r}")
    return index


def _qpos_adr(model: mujoco.MjModel, joints: tuple[str, ...]) -> tuple[int, ...]:
    return tuple(
        int(model.jnt_qposadr[_require(model, mujoco.mjtObj.mjOBJ_JOINT, j)]) for j in joints
    )


def _in_subtree(model: mujoco.MjModel, body: int, root_name: str) -> bool:
    """Whether `body` is the body `root_name` or one of its descendants."""
    while body > 0:
        if model.body(body).name == root_name:
            return True
        body = int(model.body_parentid[body])
    return False
