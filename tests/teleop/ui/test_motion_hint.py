"""The live hint (issue 37): a take in progress that sees no motion for a few seconds tells the
person "drag the gizmo's handle to move the robot"; a take that moves never shows it."""

from __future__ import annotations

import numpy as np
import pytest

from bt_teleop.session.control_loop import Session
from bt_teleop.sim.scene import load_scene
from bt_teleop.testing.harness import guide_uv, wait_until
from bt_teleop.ui.motion_hint import IDLE_HINT_S, motion_hint, still_for_s
from bt_teleop.ui.panels import status_markdown

HINT = "drag the gizmo's handle to move the robot"
PERIOD_S = 0.02  # 50 Hz, the recorder's rate


def test_still_for_counts_from_the_last_motion() -> None:
    rng = np.random.default_rng(0)
    moving = np.column_stack(
        [np.linspace(0.0, 0.5, 50), np.zeros(50), np.zeros(50)]
    )  # 10 mm a step
    resting = moving[-1] + rng.uniform(-0.001, 0.001, size=(101, 3))  # 2 s of jitter < 5 mm
    path = np.vstack([moving, resting])
    assert still_for_s(path, PERIOD_S) == pytest.approx(2.0, abs=0.05)
    assert still_for_s(moving, PERIOD_S) == 0.0
    assert still_for_s(np.zeros((0, 3)), PERIOD_S) == 0.0
    assert still_for_s(np.zeros((200, 3)), PERIOD_S) == pytest.approx(199 * PERIOD_S)
    assert motion_hint(path, PERIOD_S) is None  # 2 s: not yet
    hint = motion_hint(np.vstack([path, resting]), PERIOD_S)  # 4 s
    assert hint is not None and HINT in hint and "4 s" in hint


def test_a_scripted_take_that_stays_put_gets_the_hint_and_one_that_moves_does_not(
    tmp_path,
) -> None:
    scene = load_scene("wiping")
    session = Session(scene, tmp_path)
    try:
        session.start_recording("idle")
        session.step_for(IDLE_HINT_S - 0.5)
        assert motion_hint(session.trail(), PERIOD_S) is None
        session.step_for(1.0)  # nobody dragged anything for 3.5 s
        hint = motion_hint(session.trail(), PERIOD_S)
        assert hint is not None
        assert HINT in status_markdown(session.status(), None, hint)
        session.discard()

        session.start_recording("careful")  # a scripted operator tracing the guide
        for k in range(round(8.0 / session.dt_s)):
            session.set_target(scene.plane.to_world(guide_uv(k * session.dt_s)))
            session.step(1)
            if k % 25 == 0:
                assert motion_hint(session.trail(), PERIOD_S) is None, k * session.dt_s
    finally:
        session.close()


def test_the_page_shows_the_hint_while_recording_without_motion(make_app, tabs) -> None:
    app = make_app(session_processes=False)
    tabs(app)
    (ui,) = app.wait_for_sessions(1).values()
    ui.controls.record_button.value = True  # what a click does
    assert ui.wait_idle()
    wait_until(lambda: ui.session.status().duration_s >= 1.0, what="1 s of recording")
    assert HINT not in ui.controls.status_text.content
    wait_until(lambda: HINT in ui.controls.status_text.content, 30.0, "the hint")
    assert ui.session.status().duration_s >= IDLE_HINT_S - 0.05  # not before 3 s
    plane = ui.session.scene.plane
    start = ui.session.status().sim_time_s

    def drag() -> bool:  # a person drags the gizmo along the guide
        ui.session.set_target(plane.to_world(guide_uv(ui.session.status().sim_time_s - start)))
        return HINT not in ui.controls.status_text.content

    wait_until(drag, 30.0, "the hint to go once the robot moves", poll_s=0.01)
    ui.controls.discard_button.value = True
    assert ui.wait_idle()
    wait_until(lambda: HINT not in ui.controls.status_text.content, what="no hint when idle")
