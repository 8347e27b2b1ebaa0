"""Replay (issue 37): a replay nobody touched never makes the page warn "target clamped to the
workspace", and its raw and cleaned paths are drawn so that both show (colour, width, dashes,
a legend under the Replay picker)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, cast

import numpy as np
import pytest
import viser

from bt_teleop.library.replay import ReplayPlayer, hold_pose, replay_sync
from bt_teleop.library.track_samples import TrackSamples
from bt_teleop.session.control_loop import Session
from bt_teleop.sim.scene import SceneModel, load_scene
from bt_teleop.testing.harness import circle_uv, wait_until
from bt_teleop.ui.panels import PATHS_LEGEND, status_markdown
from bt_teleop.ui.tab_scene import CLEANED_RGB, RAW_RGB, TabScene
from bt_teleop.ui.viewer import dashed_segments, segments

CLAMPED = "target clamped"


@pytest.fixture(scope="module")
def wiping() -> SceneModel:
    return load_scene("wiping")


def pressed_take(scene: SceneModel, seconds: float = 1.5) -> TrackSamples:
    """A wiping take's end-effector path as recorded: a circle on the table, 0.4 mm below the
    workspace box's floor (the plane; the wiper pressed onto the table), sampled at 50 Hz."""
    times = np.arange(0.0, seconds + 1e-9, 0.02)
    uv = np.array([circle_uv(t, radius_m=0.04, period_s=seconds) for t in times])
    positions = scene.plane.to_world(uv) - np.array([0.0, 0.0, 0.0004])
    assert np.all(positions[:, 2] < scene.workspace.lo[2])  # every sample outside the box
    return TrackSamples(positions, times)


def test_a_replay_synchronously_leaves_nothing_clamped(wiping: SceneModel, tmp_path: Path) -> None:
    session = Session(wiping, tmp_path)
    try:
        result = replay_sync(session, pressed_take(wiping))
        assert result.rms_error_m < 0.005  # played: the box's floor is 0.4 mm from the path
        status = session.status()
        assert not status.target_clamped
        assert CLAMPED not in status_markdown(status, None)
        held = hold_pose(session)  # what the tab does when a replay ends
        session.step(10)
        assert wiping.workspace.contains(held) and not session.status().target_clamped
    finally:
        session.close()


def test_a_replay_in_real_time_never_flags_the_target(wiping: SceneModel, tmp_path: Path) -> None:
    session = Session(wiping, tmp_path)
    session.start()
    track = cast(Any, type("Listed", (), {"key": "raw · pressed", "kind": "raw"})())
    player = ReplayPlayer(session, track, pressed_take(wiping))
    flagged = []
    try:
        player.start()
        while not player.finished:
            flagged.append(session.status().target_clamped)
            time.sleep(0.005)
        assert player.result is not None and len(flagged) > 10
        hold_pose(session)
        wait_until(lambda: session.status().sim_time_s > player.samples.duration_s + 3.2)
        assert not any(flagged) and not session.status().target_clamped
    finally:
        player.stop()
        session.close()


def test_a_target_a_person_drags_out_of_the_box_is_still_flagged(
    wiping: SceneModel, tmp_path: Path
) -> None:
    session = Session(wiping, tmp_path)
    try:
        session.set_target(wiping.plane.origin - np.array([0.0, 0.0, 0.05]))  # into the table
        session.step(2)
        assert CLAMPED in status_markdown(session.status(), None)
    finally:
        session.close()


def test_dashes_leave_gaps_along_the_path() -> None:
    t = np.linspace(0.0, 1.0, 501)
    line = np.column_stack([0.2 * t, np.zeros_like(t), np.zeros_like(t)])  # 0.2 m, 0.4 mm steps
    kept = dashed_segments(line, dash_m=0.01, gap_m=0.006)
    length = np.linalg.norm(kept[:, 1] - kept[:, 0], axis=1).sum()
    assert length == pytest.approx(0.2 * 10 / 16, rel=0.05)
    starts = kept[:, 0, 0]
    assert np.max(np.diff(starts)) == pytest.approx(0.006, abs=0.001)  # the gaps
    assert len(dashed_segments(line[:1])) == 0


@pytest.fixture
def scene_api() -> Iterator[viser.SceneApi]:
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    yield server.scene
    server.stop()


def test_raw_and_cleaned_paths_are_told_apart(
    scene_api: viser.SceneApi, wiping: SceneModel
) -> None:
    view = TabScene(scene_api, wiping, lambda _: None)
    raw = pressed_take(wiping).positions
    cleaned = raw + np.array([0.0, 0.0, 0.0004])  # a cleaned path right on its raw one
    view.draw_replay_path("raw", raw)
    view.draw_replay_path("cleaned", cleaned)
    raw_node = scene_api.get_handle_by_name("/replay/raw")
    cleaned_node = scene_api.get_handle_by_name("/replay/cleaned")
    assert isinstance(raw_node, viser.LineSegmentsHandle)
    assert isinstance(cleaned_node, viser.LineSegmentsHandle)
    # the raw path shows on both sides of the cleaned one, which lies on top of it as seen
    # from the default camera (above the wiping table)
    assert raw_node.thickness >= 2.0 * cleaned_node.thickness
    lift = np.asarray(cleaned_node.points, dtype=np.float64)[:, 0] - cleaned[:-1]
    assert np.all(lift[:, 2] >= 0.001) and np.allclose(lift[:, :2], 0.0, atol=1e-6)
    assert np.allclose(np.asarray(raw_node.points, dtype=np.float64)[0, 0], raw[0], atol=1e-6)
    assert len(cleaned_node.points) == len(segments(cleaned))  # solid
    assert 0.4 * len(segments(raw)) < len(raw_node.points) < 0.8 * len(segments(raw))  # dashed
    assert tuple(np.reshape(cleaned_node.colors, (-1, 3))[0]) == CLEANED_RGB != RAW_RGB
    assert tuple(np.reshape(raw_node.colors, (-1, 3))[0]) == RAW_RGB
    for rgb in (CLEANED_RGB, RAW_RGB):  # the legend names both, in their colours
        assert "rgb({}, {}, {})".format(*rgb) in PATHS_LEGEND
    assert "cleaned" in PATHS_LEGEND and "raw" in PATHS_LEGEND and "dashed" in PATHS_LEGEND
    view.clear_replay_paths()
    assert scene_api.get_handle_by_name("/replay/raw") is None
