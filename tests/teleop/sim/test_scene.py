"""Scene composition: declared planes, both robots, and the kinematics they share."""

# mujoco ships compiled bindings without type stubs, so pyright cannot see MjModel, mj_step,
# mjtObj, ...: attribute checks on the mujoco module are off in this file.
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import os
from pathlib import Path

import mujoco
import numpy as np
import pytest

from bt_pipeline.data.shapes import canonical_shape
from bt_pipeline.data.tasks import TASKS, Task, default_plane
from bt_pipeline.exceptions import ConfigError, UnknownTaskError
from bt_teleop.sim.scene import ARM_JOINTS, EE_SITE, load_scene, robot_model
from bt_teleop.takes.recorder import RHO_RANGE, THETA_RANGE_DEG
from bt_teleop.ui.viewer import guide_loop_world

SHARED_MENAGERIE = Path(__file__).resolve().parents[4] / "shared" / "menagerie"


@pytest.fixture
def menagerie_root(monkeypatch: pytest.MonkeyPatch) -> None:
    """Point mujoco_menagerie at ../shared/menagerie unless MENAGERIE_ROOT is already set."""
    if not os.environ.get("MENAGERIE_ROOT"):
        monkeypatch.setenv("MENAGERIE_ROOT", str(SHARED_MENAGERIE))


@pytest.mark.parametrize("task", TASKS)
def test_scene_declares_the_default_plane_and_a_workspace_around_it(task: str) -> None:
    scene = load_scene(task)
    plane = default_plane(scene.task)
    np.testing.assert_allclose(scene.plane.origin, plane.origin)
    np.testing.assert_allclose(scene.plane.axes, plane.axes)
    assert scene.workspace.contains(plane.origin)
    np.testing.assert_allclose(scene.ready_pos, plane.origin)
    assert np.linalg.norm(scene.ee_quat) == pytest.approx(1.0)


_SLIDER_GRID = [
    (theta, rho)
    for theta in (THETA_RANGE_DEG[0], 0.0, THETA_RANGE_DEG[1])
    for rho in (RHO_RANGE[0], 1.0, RHO_RANGE[1])
]
# Preferences (θ [deg], ρ) whose whole guide each bundled scene's workspace must hold. Wiping and
# weaving: the app's θ/ρ slider range (corners, edges' middles, centre). Pick-and-place: the loop
# whose ends are the scene's places (θ = 0, ρ = 1), that loop turned by up to ±4° or scaled by up
# to 1.05, and smaller loops at θ = 0; not the slider range: the places are where the block
# stands, so the plane cannot rise far enough for a much tilted or larger arch.
_GUIDES_INSIDE: dict[Task, list[tuple[float, float]]] = {
    "wiping": _SLIDER_GRID,
    "weaving": _SLIDER_GRID,
    "pick_and_place": [
        (0.0, 1.0),
        (-4.0, 1.0),
        (4.0, 1.0),
        (0.0, 1.05),
        (0.0, 0.75),
        (0.0, RHO_RANGE[0]),
    ],
}
_PICK_AND_PLACE_GUIDES_OUTSIDE = [(-5.0, 1.0), (5.0, 1.0), (0.0, 1.1)]
"""Just beyond the pick-and-place preferences the box holds (README, docs/teleop.md)."""


@pytest.mark.parametrize("task", TASKS)
def test_the_workspace_holds_the_guide(task: Task) -> None:
    """A guide the demonstrator follows never drives the target out of the box (where the app
    would clamp it and flag the take)."""
    scene = load_scene(task)
    lo, hi = scene.workspace.lo, scene.workspace.hi
    for theta, rho in _GUIDES_INSIDE[task]:
        loop = guide_loop_world(scene, theta, rho, n=720)
        below, above = (lo - loop).max(axis=0), (loop - hi).max(axis=0)
        assert below.max() <= 1e-9 and above.max() <= 1e-9, (theta, rho, below, above)
    if task == "pick_and_place":
        for theta, rho in _PICK_AND_PLACE_GUIDES_OUTSIDE:
            assert guide_loop_world(scene, theta, rho, n=720)[:, 2].min() < lo[2], (theta, rho)


def test_pick_and_place_guide_places_are_the_scene_places() -> None:
    """At θ = 0 and ρ = 1 the guide's ends (φ = 0, π) lie over the place geoms, 5 mm or more above
    the workspace floor; the example script grasps and releases the block there."""
    scene = load_scene("pick_and_place")
    places = scene.plane.to_world(canonical_shape("pick_and_place", np.array([0.0, np.pi])))
    for place, name in zip(places, ("place_left", "place_right"), strict=True):
        np.testing.assert_allclose(place[:2], scene.model.geom(name).pos[:2], atol=1e-12)
    lowest = guide_loop_world(scene, 0.0, 1.0, n=720)[:, 2].min()
    assert lowest - scene.workspace.lo[2] >= 0.005 - 1e-9
    assert places[0][2] == pytest.approx(0.1625)


@pytest.mark.parametrize("task", TASKS)
def test_light_scene_has_the_robot_names_and_a_home_keyframe(task: str) -> None:
    scene = load_scene(task)
    model = scene.model
    for name in ARM_JOINTS:
        assert model.actuator(name).trntype == mujoco.mjtTrn.mjTRN_JOINT
    assert model.site(EE_SITE).id == scene.site_id
    assert model.key("home").qpos.shape == (model.nq,)
    assert model.geom("fr3_link7_collision") is not None
    assert scene.has_gripper == (task == "pick_and_place")
    # The IK model drops free objects only.
    free = sum(model.jnt_type == mujoco.mjtJoint.mjJNT_FREE)
    assert scene.ik_model.nq == model.nq - 7 * free
    assert "table" not in scene.avoid_geoms and scene.avoid_geoms


def test_composed_xml_compiles_on_its_own(tmp_path: Path) -> None:
    scene = load_scene("pick_and_place")
    path = tmp_path / "composed.xml"
    path.write_text(scene.xml)
    model = mujoco.MjModel.from_xml_path(str(path))
    assert (model.nq, model.nu, model.nbody) == (scene.model.nq, scene.model.nu, scene.model.nbody)


def _fk(model: mujoco.MjModel, q_arm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    data = mujoco.MjData(model)
    for name, q in zip(ARM_JOINTS, q_arm, strict=True):
        data.qpos[model.joint(name).qposadr[0]] = q
    mujoco.mj_kinematics(model, data)
    site = model.site(EE_SITE).id
    return data.site_xpos[site].copy(), data.site_xmat[site].reshape(3, 3).copy()


@pytest.mark.usefixtures("menagerie_root")
def test_light_and_menagerie_robots_give_the_same_end_effector_pose() -> None:
    light, menagerie = robot_model("light"), robot_model("menagerie")
    assert light.njnt == menagerie.njnt == 7
    np.testing.assert_allclose(light.jnt_range, menagerie.jnt_range)
    np.testing.assert_allclose(light.actuator_gainprm[:, 0], menagerie.actuator_gainprm[:, 0])
    np.testing.assert_allclose(light.dof_armature, menagerie.dof_armature)
    for k in range(1, 8):
        a, b = light.body(f"fr3_link{k}"), menagerie.body(f"fr3_link{k}")
        np.testing.assert_allclose(a.mass, b.mass)
        np.testing.assert_allclose(a.inertia, b.inertia)
        np.testing.assert_allclose(a.ipos, b.ipos, atol=1e-12)
    rng = np.random.default_rng(0)
    lo, hi = light.jnt_range[:, 0], light.jnt_range[:, 1]
    for q in [light.key("home").qpos, *rng.uniform(lo, hi, size=(8, 7))]:
        p_light, r_light = _fk(light, q)
        p_men, r_men = _fk(menagerie, q)
        np.testing.assert_allclose(p_light, p_men, atol=1e-9)
        np.testing.assert_allclose(r_light, r_men, atol=1e-9)


@pytest.mark.usefixtures("menagerie_root")
def test_menagerie_scene_matches_the_light_scene() -> None:
    light, menagerie = load_scene("wiping", "light"), load_scene("wiping", "menagerie")
    assert menagerie.robot_source.startswith("mujoco_menagerie")
    rng = np.random.default_rng(1)
    lo, hi = light.model.jnt_range[:7, 0], light.model.jnt_range[:7, 1]
    for q in rng.uniform(lo, hi, size=(5, 7)):
        p_light, r_light = _fk(light.model, q)
        p_men, r_men = _fk(menagerie.model, q)
        np.testing.assert_allclose(p_light, p_men, atol=1e-9)
        np.testing.assert_allclose(r_light, r_men, atol=1e-9)


def test_missing_menagerie_names_the_fix(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("MENAGERIE_ROOT", str(tmp_path))
    with pytest.raises(ConfigError, match="MENAGERIE_ROOT"):
        load_scene("wiping", "menagerie")


def test_unknown_task_and_robot_list_the_valid_names() -> None:
    with pytest.raises(UnknownTaskError, match="wiping, weaving, pick_and_place"):
        load_scene("juggling")
    with pytest.raises(ConfigError, match="light, menagerie"):
        load_scene("wiping", "ur5")


def test_scene_file_must_declare_its_fields(tmp_path: Path) -> None:
    path = tmp_path / "bare.xml"
    path.write_text(
        '<mujoco><custom><text name="bt_task" data="wiping"/></custom><worldbody/></mujoco>'
    )
    with pytest.raises(ConfigError, match="bt_plane_origin"):
        load_scene("wiping", scene_file=path)


def test_composition_prints_no_mujoco_warnings(capfd: pytest.CaptureFixture[str]) -> None:
    load_scene("pick_and_place")
    captured = capfd.readouterr()
    assert "WARNING" not in captured.err and "WARNING" not in captured.out
