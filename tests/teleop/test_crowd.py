"""The app as a crowdsourcing tool, without a browser: take checks on Stop & save, flagged
takes never ranked or cleaned, moderation by owner or operator, the small things of the page,
and Rerun (loopback sockets, one recording per tab, a bounded stream rate, 2-D in 2-D views)."""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import psutil
import pytest

from bt_pipeline.data.moderation import is_excluded
from bt_pipeline.data.recording import read_recording
from bt_pipeline.data.tasks import TASKS
from bt_pipeline.exceptions import ConfigError, DemoError
from bt_teleop.app import TeleopApp
from bt_teleop.clean.runner import clean_task
from bt_teleop.library.listing import library_markdown, load_library
from bt_teleop.rerun.blueprint import session_blueprint
from bt_teleop.rerun.clean_log import log_clean_to
from bt_teleop.rerun.live import RerunHub, SessionLogger
from bt_teleop.session.script import run_script
from bt_teleop.testing.harness import FakeTab, guide_script, wait_until
from bt_teleop.ui.panels import NO_DEMOS
from bt_teleop.ui.tab import ClientUI

TOKEN = "operator-secret-1"


def still_script(name: str) -> dict:
    """A 3 s scripted take that never moves (junk)."""
    return {"task": "wiping", "demonstrator": name, "waypoints": [[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]]}


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def tab_ui(app: TeleopApp, tabs: Callable[..., FakeTab], n: int) -> ClientUI:
    before = set(app.sessions())
    tabs(app)
    uis = app.wait_for_sessions(n)
    (new,) = [ui for cid, ui in uis.items() if cid not in before]
    return new


def record(ui: ClientUI, seconds: float) -> Path:
    ui.controls.record_button.value = True
    assert ui.wait_idle()
    wait_until(lambda: ui.session.status().duration_s >= seconds, what="recording")
    ui.controls.save_button.value = True
    assert ui.wait_idle()
    return ui.saved[-1]


# -- take checks in the app ---------------------------------------------------------------------


def test_a_junk_take_is_saved_flagged_says_why_and_can_be_discarded(make_app, tabs) -> None:
    app = make_app()
    ui = tab_ui(app, tabs, 1)
    path = record(ui, 0.5)
    demo = read_recording(path).demos["demo_0"]
    assert {"too_short", "no_motion", "incomplete"} <= set(demo.flags)
    title, body = ui.messages[-1]
    assert title == "Saved but flagged" and path.name in body and "too short" in body
    assert ui.controls.take_text.visible and "too short" in ui.controls.take_text.content
    assert ui.controls.discard_take_button.visible
    before = sha(path)
    ui.controls.discard_take_button.value = True
    assert ui.wait_idle()
    assert is_excluded(path) and sha(path) == before  # kept, marked, untouched
    assert not ui.controls.discard_take_button.visible


def test_stop_and_save_pressed_right_after_record_saves_a_flagged_take(make_app, tabs) -> None:
    # What a hasty person (and tests/teleop/browser/test_browser_crowd.py) does: Stop & save
    # before the take has the 16 samples a file needs. It was refused ("at least 16 are
    # needed"), and the take lost; with a starved control loop even a take of seconds could be
    # that short.
    app = make_app()
    ui = tab_ui(app, tabs, 1)
    ui.controls.record_button.value = True
    ui.controls.save_button.value = True  # queued behind Record: runs as soon as it has
    assert ui.wait_idle(60.0)
    assert ui.saved, ui.messages[-1]
    demo = read_recording(ui.saved[-1]).demos["demo_0"]
    assert len(demo.timestamps) >= 16 and "too_short" in demo.flags
    assert ui.messages[-1][0] == "Saved but flagged"


def test_flagged_and_excluded_demos_are_never_best_nor_scored(tmp_path: Path) -> None:
    root = tmp_path / "rec"
    good = [run_script(guide_script(f"g{r}", t, r), root) for r, t in ((0.8, 0.0), (1.0, 5.0))]
    library = load_library(root, "wiping")
    alone = {t.file: t.utility for t in library.raw}
    junk = run_script(still_script("junk"), root)
    library = load_library(root, "wiping")
    by_file = {t.file: t for t in library.raw}
    assert by_file[junk].flags and by_file[junk].utility is None
    assert {f: by_file[f].utility for f in good} == alone  # junk does not shift their scores
    assert library.best is not None and library.best.file in good
    text = library_markdown(library)
    assert "3 demos of wiping, 2 usable" in text and "no motion" in text
    from bt_pipeline.data.moderation import exclude

    exclude(library.best.file, reason="test")
    library = load_library(root, "wiping")
    assert library.best is not None and library.best.file != exclude.__name__
    assert all(t.usable for t in library.raw if t is library.best)
    assert "⊘" in library_markdown(library)


def test_clean_skips_flagged_and_excluded_demos(tmp_path: Path) -> None:
    root = tmp_path / "rec"
    good = [
        run_script(guide_script(name, t, r), root)
        for name, r, t in (("<script>x</script> |", 0.8, 0.0), ("g1", 1.0, 5.0), ("g2", 0.9, -5.0))
    ]
    junk = run_script(still_script("junk"), root)
    from bt_pipeline.clean.pipeline import CleanOptions
    from bt_pipeline.data.moderation import exclude

    exclude(good[2], reason="test")
    output, result = clean_task(
        root, "wiping", CleanOptions(epochs=1, write_rrd=False, progress=False)
    )
    sources = [str(d.attrs.get("cleaned_from", "")) for d in read_recording(output).demos.values()]
    assert len(result.demos) == 2
    assert all(str(junk) not in s and str(good[2]) not in s for s in sources)

    # The live viewer gets the result with the names escaped, and the DMP rollouts.
    import rerun as rr

    # (The job's process logs it, to a file of its own beside the session's in save mode.)
    hub = RerunHub("save", tmp_path / "rr")
    logger = hub.session_logger("clean")
    target = logger.clean_target()
    assert target is not None
    written = log_clean_to(target, result, seed=0)
    logger.show_cleaned("wiping")
    logger.close()
    clean_rrd = tmp_path / "rr" / "rerun" / written
    (rrd,) = set((tmp_path / "rr" / "rerun").glob("*.rrd")) - {clean_rrd}
    assert clean_rrd.stem.startswith(rrd.stem + "_clean_wiping_")
    summary, rollouts, ids = "", 0, set()
    for chunk in rr.chunk.RrdReader(clean_rrd).stream().to_chunks():
        batch = chunk.to_record_batch()
        if str(chunk.entity_path) == "/wiping/summary":
            summary += " ".join(str(v) for v in batch.column(batch.num_columns - 1).to_pylist())
        if str(chunk.entity_path) == "/wiping/plane/rollouts":
            rollouts += chunk.num_rows
    assert "&#60;script&#62;" in summary and "<script>" not in summary
    assert rollouts >= 1
    for path in (rrd, clean_rrd):  # one recording, in two files
        ids |= {s.recording_id for s in rr.chunk.RrdReader(path).recordings()}
    assert ids == {"clean"}
    assert logger.cleaned_tasks == ["wiping"]  # the layout grew the task's tab
    assert len(rr.chunk.RrdReader(rrd).blueprints()) == 2  # the robot's, then with wiping


def test_clean_without_recordings_names_no_server_path(tmp_path: Path) -> None:
    with pytest.raises(DemoError) as error:
        clean_task(tmp_path / "nowhere", "wiping")
    assert str(tmp_path) not in str(error.value) and "record some demos" in str(error.value)


# -- moderation ---------------------------------------------------------------------------------


def test_a_tab_moderates_its_own_demos_and_an_operator_anyones(make_app, tabs, tmp_path) -> None:
    root = tmp_path / "recordings"
    theirs = run_script(guide_script("someone"), root)  # another session's demo
    app = make_app(operator_token=TOKEN)
    ui = tab_ui(app, tabs, 1)
    mine = record(ui, 0.5)
    wait_until(lambda: ui.library is not None and len(ui.library.raw) == 2, what="library")
    key_of = {t.file: t.key for t in ui.library.raw}  # type: ignore[union-attr]
    before = sha(theirs)

    ui.moderate("exclude", key_of[theirs])
    assert ui.wait_idle()
    assert not is_excluded(theirs) and "operator" in ui.messages[-1][1]
    ui.moderate("exclude", key_of[mine])
    assert ui.wait_idle()
    assert is_excluded(mine)
    ui.moderate("restore", key_of[mine])
    assert ui.wait_idle()
    assert not is_excluded(mine)

    ui.controls.token_input.value = "wrong-token"
    assert ui.wait_idle()
    ui.moderate("exclude", key_of[theirs])
    assert ui.wait_idle()
    assert not is_excluded(theirs)
    ui.controls.token_input.value = TOKEN
    assert ui.wait_idle()
    ui.moderate("exclude", key_of[theirs])
    assert ui.wait_idle()
    assert is_excluded(theirs) and sha(theirs) == before
    wait_until(lambda: ui.library is not None and ui.library.raw[0].excluded is not None, what="")
    wait_until(
        lambda: any(t.excluded for t in ui.library.raw),  # type: ignore[union-attr]
        what="the exclusion in the list",
    )
    ui.controls.choose_demo(key_of[theirs])
    assert ui.wait_idle()
    # The panel's pickers refresh from the library a moment after the tab's library does (a CI
    # run chose the demo in between, against the list before the exclusion): Restore is offered
    # once that refresh lands.
    wait_until(
        lambda: ui.controls.exclude_button.disabled and not ui.controls.restore_button.disabled,
        what="Restore offered for the excluded demo",
    )


def test_a_short_operator_token_is_refused() -> None:
    from bt_teleop.app import AppOptions

    with pytest.raises(ConfigError, match="operator-token"):
        AppOptions(operator_token="short")


# -- the small things ---------------------------------------------------------------------------


def test_small_things_of_the_page(make_app, tabs, tmp_path) -> None:
    app = make_app()
    ui = tab_ui(app, tabs, 1)
    c = ui.controls
    wait_until(lambda: ui.library is not None, what="library")
    assert c.play_button.disabled and c.replay_input.value == NO_DEMOS  # nothing to play
    c.theta_input.value = 12
    assert ui.wait_idle()
    c.theta_input._impl.value = math.nan  # what a box holding "abc" may send
    assert c.theta_deg == 12.0  # the last valid value, not NaN and not a blank box
    c.theta_input._impl.value = ""
    assert c.theta_deg == 12.0
    run_script(guide_script("solo"), tmp_path / "recordings")
    app.versions.bump("wiping")
    wait_until(lambda: ui.library is not None and len(ui.library.raw) == 1, what="library")
    assert "1 demo of wiping" in c.library_text.content and "1 demos" not in c.library_text.content
    assert not c.play_button.disabled
    from bt_teleop.clean.runner import CleanProgress

    starting = CleanProgress("wiping", "running", 0, 10, "reading")

    def shown() -> bool:
        # The tab's own poll (no real job here) may hide the bar between the two lines.
        c.show_clean_progress(starting)
        return c.clean_progress.visible and c.clean_progress.value > 0.0  # never an empty bar

    wait_until(shown, what="a non-empty clean progress bar")
    c.show_clean_progress(CleanProgress("wiping", "running", 5, 10, "epoch 5"))
    assert c.clean_progress.value == pytest.approx(50.0)


# -- Rerun --------------------------------------------------------------------------------------


def test_rerun_serve_binds_loopback_and_links_each_tab_to_its_own_proxy(tmp_path: Path) -> None:
    hub = RerunHub("serve", tmp_path, host="127.0.0.1", grpc_port=0, web_port=0)
    loggers: dict[str, SessionLogger] = {}
    try:
        assert hub.proxy is not None
        loggers.update({n: hub.session_logger(n) for n in ("abc123", "def456")})  # two tabs
        proxies = {name: hub.session_proxy(name) for name in loggers}
        children = [psutil.Process(hub.proxy.process.pid)]
        for name, proxy in proxies.items():
            assert proxy is not None
            children.append(psutil.Process(proxy.process.pid))
            url = hub.session_url(name)
            assert url is not None and f"recording_id%3D{name}" in url
            assert f"127.0.0.1%3A{proxy.grpc_port}%2Fproxy" in url  # its own proxy
        assert len({p.grpc_port for p in proxies.values() if p is not None}) == 2
        for child in children:
            listening = [c.laddr for c in child.net_connections("inet") if c.status == "LISTEN"]
            assert listening and all(a.ip == "127.0.0.1" for a in listening), listening
        loggers["abc123"].close()  # a closed tab's proxy stops with it
        assert hub.session_url("abc123") is None and hub.session_proxy("abc123") is None
        assert not _alive(children[1])
    finally:
        for logger in loggers.values():
            logger.close()
        hub.close()
    assert not any(_alive(child) for child in children)


def _alive(process: psutil.Process) -> bool:
    return process.is_running() and process.status() != psutil.STATUS_ZOMBIE


def test_the_blueprint_keeps_2d_plane_content_out_of_3d_views() -> None:
    # A session starts with the robot view and the legend of its saved demos.
    kinds = [type(view).__name__ for view in _views(session_blueprint())]
    assert kinds == ["Spatial3DView", "TextDocumentView"]
    views = _views(session_blueprint(TASKS))
    kinds = {type(view).__name__ for view in views}
    assert "Spatial3DView" in kinds and "Spatial2DView" in kinds
    for view in views:
        contents = " ".join(str(q) for q in (view.contents or []))
        if type(view).__name__ == "Spatial3DView":
            assert "/plane" not in contents
        if "/plane/" in contents:
            assert type(view).__name__ == "Spatial2DView"
    assert any("rollouts" in " ".join(str(q) for q in (v.contents or [])) for v in views)


def _views(blueprint) -> list:
    views = []

    def walk(item) -> None:
        for child in getattr(item, "contents", None) or []:
            if hasattr(child, "class_identifier"):
                views.append(child)
            walk(child)

    walk(blueprint.root_container)
    return views


def test_the_state_stream_is_bounded_to_30_hz(tmp_path: Path) -> None:
    import rerun as rr

    hub = RerunHub("save", tmp_path)
    logger = hub.session_logger("rate")
    for k in range(200):  # 2 s of simulation time at 100 Hz
        logger.log_state(0.01 * k, np.zeros(3), np.zeros(7))
        time.sleep(0.005)  # the worker drains between calls: batching is the logger's doing
    logger.close()
    (rrd,) = (tmp_path / "rerun").glob("*.rrd")
    rows, messages = 0, 0
    for chunk in rr.chunk.RrdReader(rrd).stream().to_chunks():
        if str(chunk.entity_path) == "/ee/position":
            rows += chunk.num_rows
            messages += 1
    assert 55 <= rows <= 61  # 2 s at most 30 Hz
    assert messages <= 3  # batched: one message per STATE_BATCH_S (1 s), plus the last part
