"""The teleop web app without a browser: server, one session per tab, files, Clean, replay, Rerun.

Tabs are simulated by :class:`bt_teleop.testing.harness.FakeTab`, a raw viser websocket client that
behaves like a tab. GUI actions are driven through the same handles the browser drives
(setting a handle's value runs its callbacks).
"""

from __future__ import annotations

import math
import os
import socket
import threading
import urllib.request
from pathlib import Path

import numpy as np
import psutil
import pytest
import viser

from bt_pipeline.clean.pipeline import CleanOptions
from bt_pipeline.data.recording import read_recording
from bt_pipeline.exceptions import ConfigError
from bt_teleop.app import AppOptions, TeleopApp
from bt_teleop.clean.runner import CleanRunner, cleaned_path
from bt_teleop.library.replay import load_library, replay_sync
from bt_teleop.library.track_samples import TrackReader
from bt_teleop.rerun.clean_log import CleanLogTarget
from bt_teleop.rerun.live import RerunHub, SessionLogger
from bt_teleop.session.control_loop import Session
from bt_teleop.session.process import SessionProcess
from bt_teleop.session.script import run_script
from bt_teleop.session.tick_stats import TimedSession
from bt_teleop.testing.harness import guide_script, wait_until
from bt_teleop.ui.tab import ClientUI
from bt_teleop.ui.viewer import Trail, guide_loop_world


def only_session(app: TeleopApp) -> ClientUI:
    (ui,) = app.wait_for_sessions(1).values()
    return ui


def record(ui: ClientUI, seconds: float) -> Path:
    """Record for `seconds` [s] of simulation time through the GUI buttons, then save."""
    ui.controls.record_button.value = True  # what a click does
    assert ui.wait_idle()
    wait_until(lambda: ui.session.status().duration_s >= seconds, what="recording")
    ui.controls.save_button.value = True
    assert ui.wait_idle()
    return ui.saved[-1]


SPAWNER_PREFIX = "bt-rerun-spawner"  # bt_teleop/rerun/proxy.py: _SPAWNER


def bt_threads() -> list[str]:
    """bt's live threads, but the Rerun spawner: it lives as long as the process by design (the
    children it starts get SIGTERM when it ends; bt_teleop/rerun/proxy.py), so a test run that
    started Rerun earlier (tests/teleop/test_crowd.py) must not fail this one."""
    return [
        t.name
        for t in threading.enumerate()
        if t.name.startswith("bt-") and not t.name.startswith(SPAWNER_PREFIX) and t.is_alive()
    ]


# -- server -------------------------------------------------------------------------------------


def test_server_serves_the_page_on_a_free_port_and_stops_cleanly(make_app, tabs) -> None:
    app = make_app()
    assert app.port != 0 and app.url == f"http://127.0.0.1:{app.port}/"
    with urllib.request.urlopen(app.url, timeout=10) as response:
        page = response.read().decode()
    assert response.status == 200 and "<html" in page.lower() and "<script" in page.lower()
    tabs(app)
    session = only_session(app).session
    assert isinstance(session, SessionProcess)  # the default: a child process per tab
    assert session.pid is not None and psutil.pid_exists(session.pid)
    app.stop()
    assert wait_until(lambda: not bt_threads(), 10.0, "bt threads to end") is True
    assert not psutil.pid_exists(session.pid)  # ended and reaped


def test_sessions_can_stay_in_the_apps_process(make_app, tabs) -> None:
    app = make_app(session_processes=False)
    tabs(app)
    ui = only_session(app)
    assert isinstance(ui.session, TimedSession)
    assert any(name.startswith("bt-session") for name in bt_threads())
    goal = ui.session.scene.plane.to_world(np.array([0.05, 0.0]))
    ui.session.set_target(goal)
    wait_until(lambda: np.linalg.norm(ui.session.status().ee_pos - goal) < 5e-3, what="goal")
    assert ui.session.tick_stats().n_ticks > 0
    app.stop()
    assert wait_until(lambda: not bt_threads(), 10.0, "bt threads to end") is True
    with pytest.raises(OSError):
        urllib.request.urlopen(app.url, timeout=2)


def test_options_are_validated() -> None:
    with pytest.raises(ConfigError, match="max-sessions"):
        AppOptions(max_sessions=0)
    with pytest.raises(ConfigError, match="--rerun"):
        AppOptions(rerun="loud")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="robot"):
        AppOptions(robot="ur5")  # type: ignore[arg-type]
    assert AppOptions().host == "127.0.0.1"


# -- sessions -----------------------------------------------------------------------------------


def test_every_tab_has_its_own_robot(make_app, tabs) -> None:
    app = make_app()
    tab_a, tab_b = tabs(app), tabs(app)
    uis = app.wait_for_sessions(2)
    ui_a, ui_b = (uis[k] for k in sorted(uis))
    assert ui_a.session is not ui_b.session and ui_a.session_id != ui_b.session_id
    start_b = ui_b.session.status().ee_pos
    goal = ui_a.session.scene.plane.to_world(np.array([0.06, 0.04]))
    ui_a.tab_scene.gizmo.position = goal  # what a drag does, then the callback sets the target
    ui_a.session.set_target(goal)
    wait_until(lambda: np.linalg.norm(ui_a.session.status().ee_pos - goal) < 5e-3, what="A")
    assert np.linalg.norm(ui_b.session.status().ee_pos - start_b) < 1e-3
    # Each tab's robot is drawn into that tab only: the moved link poses go to A's socket.
    wait_until(lambda: ui_a.frames > 5 and ui_b.frames > 5, what="scene updates")
    assert "/robot/body_" in tab_a.text() and "/robot/body_" in tab_b.text()
    ui_a.controls.task_input.value = "pick_and_place"
    assert ui_a.wait_idle()
    assert ui_a.task == "pick_and_place" and ui_a.controls.gripper_input.visible
    assert ui_b.task == "wiping"


def test_a_closed_tab_saves_its_recording_flagged_incomplete(make_app, tabs) -> None:
    app = make_app()
    tab = tabs(app)
    ui = only_session(app)
    ui.controls.record_button.value = True
    wait_until(lambda: ui.session.status().n_samples >= 40, what="samples")
    tab.close()
    wait_until(lambda: not app.sessions() and app.settled(), what="the session to end")
    (path,) = ui.saved
    demo = read_recording(path).demos["demo_0"]
    assert demo.ep_meta["incomplete"] is True and demo.num_samples >= 40
    assert path.parent == app.options.recordings / "wiping"


def test_a_closed_tab_discards_its_recording_when_configured(make_app, tabs) -> None:
    app = make_app(save_incomplete=False)
    tab = tabs(app)
    ui = only_session(app)
    ui.controls.record_button.value = True
    wait_until(lambda: ui.session.status().n_samples >= 40, what="samples")
    tab.close()
    wait_until(lambda: not app.sessions() and app.settled(), what="the session to end")
    assert not ui.saved and not list(app.options.recordings.rglob("*.hdf5"))


def test_more_tabs_than_max_sessions_get_a_full_message(make_app, tabs) -> None:
    app = make_app(max_sessions=1)
    tabs(app)
    only_session(app)
    refused = tabs(app)
    wait_until(lambda: "server is full" in refused.text(), what="the full message")
    assert len(app.sessions()) == 1 and "/robot/" not in refused.text()


def test_a_name_from_the_browser_never_leaves_the_recordings_folder(make_app, tabs) -> None:
    app = make_app()
    tabs(app)
    ui = only_session(app)
    ui.controls.name_input.value = "../../etc/passwd"
    path = record(ui, 0.5)
    task_dir = (app.options.recordings / "wiping").resolve()
    assert path.resolve().parent == task_dir
    assert path.name.startswith("etc-passwd_") and ".." not in path.name
    assert read_recording(path).demos["demo_0"].demonstrator == "../../etc/passwd"
    assert any(path.name in body for _, body in ui.messages)  # the toast names the file whole


def test_the_recordings_list_shows_scores_after_saving(make_app, tabs) -> None:
    app = make_app()
    tabs(app)
    ui = only_session(app)
    ui.controls.theta_input.value = 10
    ui.controls.rho_input.value = 1.2
    record(ui, 0.5)
    wait_until(lambda: ui.library is not None and len(ui.library.raw) == 1, what="library")
    # The table, the options and the picker follow the library one after another on the
    # loader's thread: wait for the last of them (under load the test read between).
    wait_until(
        lambda: ui.controls.replay_picker.key == ui.library.raw[0].key,  # type: ignore[union-attr]
        what="the replay picker on the new take",
    )
    listed = ui.controls.library_text.content
    assert "10°, 1.20" in listed and "★" in listed
    assert len(ui.controls.replay_input.options) == 1
    assert app.reader is not None and app.reader.pid is not None  # read and scored in the child
    # The loads list the takes on a thread below the sessions' control loops (nice +10).
    (loader,) = [t for t in threading.enumerate() if t.name.startswith("bt-read")]
    assert loader.native_id is not None
    loader_nice = os.getpriority(os.PRIO_PROCESS, loader.native_id)
    assert loader_nice == min(19, os.getpriority(os.PRIO_PROCESS, 0) + 10)
    pid = app.reader.pid
    app.stop()
    assert app.reader.pid is None and not Path(f"/proc/{pid}").exists()


# -- clean and replay ---------------------------------------------------------------------------


@pytest.fixture
def three_recordings(tmp_path: Path) -> Path:
    root = tmp_path / "recordings"
    for rho, theta in ((0.8, 0.0), (1.0, 5.0), (0.7, -5.0)):
        run_script(guide_script(f"r{rho}", theta, rho), root)
    return root


def test_clean_runs_in_a_process_and_writes_outside_the_raw_folder(three_recordings) -> None:
    from rerun.chunk import RrdReader

    runner = CleanRunner(three_recordings, CleanOptions(epochs=2, write_rrd=False), processes=True)
    session_rrd = three_recordings.parent / "rr" / "tab.rrd"
    job = runner.start("wiping", rerun=CleanLogTarget("tab", session_rrd=session_rrd))
    with pytest.raises(ConfigError, match="running"):
        runner.start("wiping")
    progress = job.wait(240.0)
    runner.close()
    assert progress.state == "done", progress.message
    output = progress.output
    assert output is not None and output == cleaned_path(three_recordings, "wiping")
    cleaned = read_recording(output)
    assert len(cleaned.demos) == 3
    # The job's process logged the result into the tab's recording (the app never held it).
    (logged,) = session_rrd.parent.glob("tab_clean_wiping_*.rrd")
    paths = {str(c.entity_path) for c in RrdReader(logged).stream().to_chunks()}
    assert {"/wiping/plane/rollouts", "/wiping/summary"} <= paths
    assert {r.recording_id for r in RrdReader(logged).recordings()} == {"tab"}
    assert not hasattr(job, "result") and progress.notes == ()


def test_a_clean_whose_viewer_is_gone_is_done_with_a_note(three_recordings) -> None:
    runner = CleanRunner(three_recordings, CleanOptions(epochs=1, write_rrd=False), processes=True)
    with socket.socket() as probe:  # a port nothing listens on
        probe.bind(("127.0.0.1", 0))
        url = f"rerun+http://127.0.0.1:{probe.getsockname()[1]}/proxy"
    progress = runner.start("wiping", rerun=CleanLogTarget("tab", grpc_url=url)).wait(240.0)
    runner.close()
    assert progress.state == "done", progress.message
    assert progress.output is not None and len(read_recording(progress.output).demos) == 3
    assert progress.notes == ("the Rerun viewer did not get the result (RuntimeError)",)
    library = load_library(three_recordings, "wiping")
    assert len(library.raw) == 3 and len(library.cleaned) == 3  # cleaned file is not raw input
    assert {t.key.removeprefix("cleaned · ") for t in library.cleaned} == {
        t.key.removeprefix("raw · ") for t in library.raw
    }


def test_clean_button_then_replay_a_cleaned_demo(three_recordings, make_app, tabs) -> None:
    app = make_app(recordings=three_recordings, clean_in_subprocess=False, rerun="save")
    tabs(app)
    ui = only_session(app)
    ui.controls.clean_button.value = True
    wait_until(lambda: "Clean done" in [m[0] for m in ui.messages], 240.0, "clean")
    # The job logged the result beside the tab's .rrd, and the tab's layout grew its tab.
    assert len(list((three_recordings / "rerun").glob("*_clean_wiping_*.rrd"))) == 1
    wait_until(lambda: ui.logger.cleaned_tasks == ["wiping"], what="the layout to grow")
    # the Replay picker opens on the cleaned ★: the cleaned version of the best raw demo
    wait_until(lambda: ui.controls.replay_picker.key.startswith("cleaned · "), what="cleaned demos")
    library = ui.library
    assert library is not None and library.best is not None
    key = ui.controls.replay_picker.key
    assert library.find(key).source == library.best.key
    ui.controls.play_button.value = True
    assert ui.wait_idle()
    scene = ui.client.scene
    wait_until(lambda: scene.get_handle_by_name("/replay/cleaned") is not None, what="cleaned path")
    assert scene.get_handle_by_name("/replay/raw") is not None  # its source, to compare
    wait_until(lambda: ui.last_replay is not None, 30.0, "the replay to end")
    result = ui.last_replay.result  # type: ignore[union-attr]
    assert result is not None and result.rms_error_m < 0.01
    wait_until(lambda: any(t == "Replay done" for t, _ in ui.messages), what="the notice")
    frames = ui.frames
    wait_until(lambda: ui.frames > frames + 3, what="a few frames after the replay")
    assert "clamped" not in ui.controls.status_text.content  # nobody touched the target


def test_replay_tracks_a_raw_demo(three_recordings) -> None:
    library = load_library(three_recordings, "wiping")
    track = library.raw[0]
    session = Session("wiping", three_recordings / "unused")
    samples = TrackReader().read(track)  # the library lists it; Play reads it from its file
    result = replay_sync(session, samples)
    assert result.times_s[-1] == pytest.approx(track.duration_s)
    assert result.rms_error_m < 0.005
    session.close()


# -- scene drawing ------------------------------------------------------------------------------


def test_guide_lies_on_the_task_plane_and_follows_theta_and_rho() -> None:
    from bt_teleop.sim.scene import load_scene

    scene = load_scene("weaving")
    base = guide_loop_world(scene, 0.0, 1.0)
    turned = guide_loop_world(scene, 20.0, 1.5)
    for loop in (base, turned):
        assert np.allclose((loop - scene.plane.origin) @ scene.plane.normal, 0.0, atol=1e-12)
    uv, uv_turned = scene.plane.to_plane(base), scene.plane.to_plane(turned)
    assert np.ptp(np.linalg.norm(uv_turned, axis=1)) == pytest.approx(
        1.5 * np.ptp(np.linalg.norm(uv, axis=1))
    )
    angle = math.radians(20.0)
    rotation = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    assert np.allclose(uv_turned, 1.5 * uv @ rotation.T)


def test_trail_resends_only_its_newest_chunk() -> None:
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        trail = Trail(server.scene, "/trail", (255, 0, 0), chunk=10)
        points = np.random.default_rng(0).random((35, 3))
        trail.set(points[:5])
        first = server.scene.get_handle_by_name("/trail/chunk_0")
        trail.set(points[:25])
        assert trail.n_chunks == 3
        chunk_0 = server.scene.get_handle_by_name("/trail/chunk_0")
        assert chunk_0 is not None and chunk_0 is not first  # grew from 5 to 11 points: re-sent
        trail.set(points)
        assert trail.n_chunks == 4
        assert server.scene.get_handle_by_name("/trail/chunk_0") is chunk_0  # full: kept
        trail.set(points[:3])  # a new, shorter trail starts over
        assert trail.n_chunks == 1
        trail.clear()
        assert server.scene.get_handle_by_name("/trail/chunk_0") is None
    finally:
        server.stop()


# -- Rerun --------------------------------------------------------------------------------------


def test_rerun_save_mode_writes_a_session_rrd(make_app, tabs) -> None:
    from rerun.chunk import RrdReader

    app = make_app(rerun="save")
    tab = tabs(app)
    ui = only_session(app)
    record(ui, 0.5)
    wait_until(lambda: ui.frames > 10, what="frames")
    tab.close()
    wait_until(lambda: not app.sessions() and app.settled(), what="the session to end")
    (rrd,) = (app.options.recordings / "rerun").glob("*.rrd")
    paths = {chunk.entity_path for chunk in RrdReader(rrd).stream().to_chunks()}
    assert {"/ee/position", "/joints"} <= paths
    assert any(p.startswith("/demos/") for p in paths)


def test_rerun_serve_mode_serves_the_web_viewer(tmp_path: Path) -> None:
    hub = RerunHub("serve", tmp_path, grpc_port=0, web_port=0)
    try:
        assert hub.viewer_url is not None and hub.grpc_url is not None
        with urllib.request.urlopen(hub.viewer_url.replace("localhost", "127.0.0.1")) as reply:
            assert reply.status == 200 and b"<html" in reply.read().lower()
        logger = hub.session_logger("abc123")
        logger.log_state(0.0, np.zeros(3), np.zeros(7))
        logger.close()
        assert logger.dropped == 0
    finally:
        hub.close()


def test_session_logger_drops_instead_of_blocking() -> None:
    import rerun as rr

    rec = rr.RecordingStream("bt_test", recording_id="drop")
    rec.memory_recording()
    logger = SessionLogger(rec, queue_size=1)
    release = threading.Event()

    def block(_: object) -> None:
        release.wait(10.0)

    logger._submit(block)  # occupies the worker
    wait_until(lambda: logger._queue.empty(), what="the worker to take the job")
    for k in range(5):  # one fits in the queue; the rest are dropped, not waited for
        logger.log_demo(f"d{k}", np.zeros((4, 3)))
    release.set()
    logger.close()
    assert logger.dropped == 4


def test_the_objects_loaded_at_start_are_left_out_of_later_collections() -> None:
    """``serve`` freezes what the app loaded before serving: a later full collection walks only
    what was made since, not the ~190,000 objects of the imports (in a process of its own: a
    freeze in the test process would keep every earlier test's garbage)."""
    import subprocess
    import sys

    code = (
        "import gc, bt_teleop.app as app\n"
        "loaded = len(gc.get_objects())\n"
        "app.freeze_startup_objects()\n"
        "kept = [[k] for k in range(1000)]\n"
        "print(loaded, gc.get_freeze_count(), len(gc.get_objects()))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    loaded, frozen, tracked = map(int, out.stdout.split())
    assert loaded > 50_000
    assert frozen >= 0.9 * loaded
    assert 1000 <= tracked < 5_000  # the new lists, not the imports
