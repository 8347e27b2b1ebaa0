"""The scripted operator: JSON in, a recorded demo file out, through the real session code."""

# mujoco ships compiled bindings without type stubs, so pyright cannot see MjModel, mj_step,
# mjtObj, ...: attribute checks on the mujoco module are off in this file.
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest

from bt_pipeline.data.recording import read_recording
from bt_pipeline.data.shapes import canonical_shape
from bt_pipeline.exceptions import ConfigError, UnknownTaskError
from bt_teleop.session.script import load_script, parse_script, run_script
from bt_teleop.sim.scene import load_scene
from bt_teleop.takes.recorder import STATE_SIGNATURE

EXAMPLES = Path(__file__).resolve().parents[3] / "examples" / "scripts"


def _script(**overrides: Any) -> dict[str, Any]:
    script: dict[str, Any] = {
        "task": "weaving",
        "demonstrator": "ci",
        "theta_deg": 5,
        "rho": 1.1,
        "robot": "light",
        "waypoints": [[0.0, 0.0, 0.0], [0.5, 0.05, 0.0], [1.0, 0.05, 0.05]],
        "settle_s": 0.2,
    }
    script.update(overrides)
    return script


def test_wiping_example_records_the_scripted_circle(tmp_path: Path) -> None:
    path = run_script(EXAMPLES / "wiping_circle.json", tmp_path)
    assert path.parent == tmp_path / "wiping"
    recording = read_recording(path)
    demo = recording.demos["demo_0"]
    assert (demo.demonstrator, demo.theta_deg, demo.rho) == ("ci", 5.0, 1.1)
    assert demo.source == "teleop" and demo.ep_meta["incomplete"] is False
    script = load_script(EXAMPLES / "wiping_circle.json")
    assert demo.num_samples == round(script.duration_s * 50) + 1
    uv = recording.plane.to_plane(demo.ee_pos)
    expected = np.array(
        [recording.plane.to_plane(script.target_at(t, recording.plane)) for t in demo.timestamps]
    )
    late = demo.timestamps > 0.5
    rms = float(np.sqrt(np.mean(np.sum((uv[late] - expected[late]) ** 2, axis=1))))
    assert rms < 0.005
    assert np.ptp(uv[:, 0]) > 0.11  # the circle was drawn, 12 cm across


def test_pick_and_place_example_moves_the_block(tmp_path: Path) -> None:
    path = run_script(EXAMPLES / "pick_and_place.json", tmp_path)
    recording = read_recording(path)
    demo = recording.demos["demo_0"]
    assert demo.gripper is not None and demo.gripper.shape == (demo.num_samples, 1)
    assert demo.gripper.min() < 0.045 and demo.gripper[0, 0] == pytest.approx(0.08, abs=1e-3)
    kwargs = recording.env_args["env_kwargs"]
    model = mujoco.MjModel.from_xml_string(kwargs["model_xml"])
    data = mujoco.MjData(model)
    assert demo.states is not None
    block = model.body("block").id
    heights = []
    for state in demo.states:
        mujoco.mj_setState(model, data, state, STATE_SIGNATURE)
        mujoco.mj_kinematics(model, data)
        heights.append(data.xpos[block][2])
    assert max(heights) > 0.15  # lifted over the arch
    np.testing.assert_allclose(data.xpos[block][:2], [0.5, 0.15], atol=0.01)  # on the right place
    assert data.xpos[block][2] < 0.045
    # It grasps and releases at the guide's places (θ = 0, ρ = 1: its ends, φ = 0 and π), and
    # its target never leaves the workspace.
    assert demo.ep_meta["clamped_samples"] == 0
    script = load_script(EXAMPLES / "pick_and_place.json")
    (t_close, closed), (t_open, opened) = script.gripper[1:]
    assert not closed and opened
    places = canonical_shape("pick_and_place", np.array([0.0, math.pi]))
    for t_s, place in ((t_close, places[0]), (t_open, places[1])):
        target = recording.plane.to_plane(script.target_at(t_s, recording.plane))
        np.testing.assert_allclose(target, place, atol=1e-9)


def test_world_frame_waypoints(tmp_path: Path) -> None:
    scene = load_scene("weaving")
    start = scene.plane.origin
    rows = [[0.0, *start], [1.0, *(start + np.array([0.0, 0.06, -0.04]))]]
    path = run_script(_script(frame="world", waypoints=rows), tmp_path, scene=scene)
    demo = read_recording(path).demos["demo_0"]
    np.testing.assert_allclose(demo.ee_pos[-1], rows[-1][1:], atol=3e-3)


def test_dict_and_file_scripts_agree(tmp_path: Path) -> None:
    file = tmp_path / "s.json"
    file.write_text(json.dumps(_script()))
    from_file, from_dict = load_script(file), parse_script(_script())
    np.testing.assert_array_equal(from_file.waypoints, from_dict.waypoints)
    assert (from_file.task, from_file.demonstrator, from_file.theta_deg, from_file.rho) == (
        "weaving",
        "ci",
        5.0,
        1.1,
    )
    assert (from_file.frame, from_file.settle_s) == (from_dict.frame, from_dict.settle_s)


@pytest.mark.parametrize(
    ("overrides", "error", "match"),
    [
        ({"task": "juggling"}, UnknownTaskError, "wiping, weaving, pick_and_place"),
        ({"robot": "ur5"}, ConfigError, "light, menagerie"),
        ({"frame": "camera"}, ConfigError, "plane, world"),
        ({"speed": 2}, ConfigError, r"unknown key\(s\) speed"),
        ({"waypoints": [[0, 0, 0], [1, 0, 0], [2, 0]]}, ConfigError, r"waypoints\[2\]"),
        ({"waypoints": [[0, 0, 0], [1, 0, "x"]]}, ConfigError, r"waypoints\[1\]"),
        ({"waypoints": [[0, 0, 0], [1, 0, 0], [1, 0, 0]]}, ConfigError, r"waypoints\[2\] has time"),
        ({"waypoints": [[-1, 0, 0], [1, 0, 0]]}, ConfigError, "start at >= 0"),
        ({"waypoints": [[0, 0, 0]]}, ConfigError, "at least 2 rows"),
        ({"waypoints": [[0, 0, 0, 0], [1, 0, 0, 0]]}, ConfigError, r"\[t_s, u, v\]"),
        ({"gripper": [[0, "open"]]}, ConfigError, r"gripper\[0\]"),
        ({"theta_deg": "five"}, ConfigError, "theta_deg"),
        ({"rho": math.inf}, ConfigError, "rho"),
    ],
)
def test_invalid_scripts_name_what_is_wrong(
    overrides: dict[str, Any], error: type[Exception], match: str
) -> None:
    with pytest.raises(error, match=match):
        parse_script(_script(**overrides))


def test_missing_keys_bad_files_and_short_scripts(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="missing 'waypoints'"):
        parse_script({"task": "wiping"})
    with pytest.raises(ConfigError, match="cannot read"):
        load_script(tmp_path / "nope.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ConfigError, match="not valid JSON"):
        load_script(bad)
    with pytest.raises(ConfigError, match="at least 16 samples"):
        run_script(_script(waypoints=[[0, 0, 0], [0.2, 0.01, 0]]), tmp_path)
    with pytest.raises(ConfigError, match="scene given"):
        run_script(_script(), tmp_path, scene=load_scene("wiping"))
    assert not any(p.is_file() for p in tmp_path.rglob("*.hdf5"))


def test_gripper_commands_are_stepwise() -> None:
    script = parse_script(_script(gripper=[[2.0, 1], [1.0, 0]]))
    assert script.gripper_open_at(0.5) is True
    assert script.gripper_open_at(1.0) is False
    assert script.gripper_open_at(3.0) is True
