"""The live Rerun view in a real browser: Rerun's own web viewer, in Debian's headless Chromium
(as tests/teleop/browser/test_browser.py), read through its viewer-control API
(:class:`bt_teleop.testing.viewer_probe.ViewerProbe`), not through pixels.

* A tab's link opens the viewer on that tab's own recording, holding its robot states and its
  saved take, while another session streams too.
* Every view of the session blueprint, shown with everything a session logs (robot states, a
  saved demo, a replay, a Clean's result with references, best demo, value map and DMP
  rollouts), reports no warning or error. A control view that puts 2-D plane content in a 3-D
  view must report "2D visualizers require a pinhole ancestor", so the check can fail.

Timeouts are generous (the web viewer needs tens of seconds to start in software WebGL on a
loaded machine); nothing asserts on wall-clock time.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import rerun.blueprint as rrb
from playwright.sync_api import Page, expect

from bt_pipeline.clean.pipeline import CleanOptions
from bt_pipeline.data.tasks import TASKS
from bt_pipeline.viz.demo_style import name_from_stem
from bt_teleop.clean.task import clean_task
from bt_teleop.rerun.blueprint import session_blueprint
from bt_teleop.rerun.clean_log import log_clean_to
from bt_teleop.rerun.live import RerunHub
from bt_teleop.session.script import run_script
from bt_teleop.testing.harness import (
    app_factory,
    chromium_page,
    guide_script,
    tab_factory,
    wait_until,
)
from bt_teleop.testing.viewer_probe import ViewerProbe, ViewerState
from tests.teleop.browser.conftest import PAGE_TIMEOUT_MS

VIEWER_TIMEOUT_S = 240.0
"""Longest wait for the web viewer to start and receive a session [s] (loaded 2-core CI)."""
BENIGN_LOG = ("Unhandled egui viewport command", "Failed to load examples")
"""Viewer log lines of a headless page with no internet (no window, no examples manifest)."""
expect.set_options(timeout=PAGE_TIMEOUT_MS)


@pytest.fixture
def page() -> Iterator[Page]:
    with chromium_page(viewport={"width": 1400, "height": 900}, timeout_ms=PAGE_TIMEOUT_MS) as tab:
        yield tab


def open_viewer(viewer: Page, url: str) -> ViewerProbe:
    """`viewer` on `url`, once the Rerun viewer in it has started."""
    viewer.goto(url, wait_until="load")
    probe = ViewerProbe(viewer)
    wait_until(probe.started, VIEWER_TIMEOUT_S, "the Rerun web viewer to start")
    return probe


def errors_in_log(probe: ViewerProbe) -> list[str]:
    return [
        f"{level}: {text}"
        for level, text in probe.logs()
        if level in ("WARN", "ERROR") and not any(b in text for b in BENIGN_LOG)
    ]


def test_the_rerun_link_opens_the_tabs_own_recording(tmp_path: Path, page: Page) -> None:
    with app_factory(tmp_path / "recordings") as make, tab_factory() as open_tab:
        app = make(rerun="serve", rerun_grpc_port=0, rerun_web_port=0)
        open_tab(app, decode=False)  # another session streams at the same time
        (other,) = app.wait_for_sessions(1, 60.0).values()
        page.goto(app.url, wait_until="commit")
        expect(page.get_by_role("button", name="Record", exact=True)).to_be_visible()
        uis = app.wait_for_sessions(2, 60.0)
        (ui,) = [u for u in uis.values() if u is not other]

        # A short take through the page's buttons: its path reaches the recording.
        page.get_by_role("button", name="Record", exact=True).click()
        wait_until(lambda: ui.session.recording and ui.session.status().n_samples > 60, 60.0, "")
        page.get_by_role("button", name="Stop & save", exact=True).click()
        take = wait_until(lambda: ui.saved and ui.saved[-1], 30.0, "the take to be saved")
        take_end_s = ui.session.status().sim_time_s

        link = page.get_by_role("link", name="Open the live Rerun viewer")
        href = link.get_attribute("href")
        assert href is not None and href == app.rerun.session_url(ui.session_id)
        # Freeze the app's page (its software WebGL would take the CPU the viewer needs); its
        # websocket, and so the session, stays open.
        page.context.new_cdp_session(page).send("Page.setWebLifecycleState", {"state": "frozen"})
        browser = page.context.browser
        assert browser is not None
        probe = open_viewer(browser.new_page(viewport={"width": 1400, "height": 900}), href)
        mine = f"Recording:bt_teleop:{ui.session_id}"

        def shows_the_take() -> ViewerState | None:
            state = probe.state()
            newest = state.newest_s.get(mine, {}).get("sim_time", -1.0)
            return state if newest >= take_end_s else None

        state = wait_until(shows_the_take, VIEWER_TIMEOUT_S, "the viewer to hold the take")
        assert state.active_store_id == mine  # the tab's own recording is the one shown
        assert list(state.newest_s) == [mine]  # and no other session's
        assert state.route.endswith(f"recording_id={ui.session_id}")
        paths = probe.entity_paths(mine)
        # The take is named as the page names it: who and when.
        assert {"/ee/position", "/joints", f"/demos/{name_from_stem(take.stem)}"} <= set(paths)
        assert "/legend" in paths
        assert any(v.kind == "3D" and v.visible for v in state.views)
        assert all(not v.reports for v in state.views if v.visible)
        assert errors_in_log(probe) == []
        probe.page.screenshot(path=str(tmp_path / "rerun-viewer.png"))


def all_views(blueprint: rrb.Blueprint) -> list[rrb.View]:
    views: list[rrb.View] = []

    def walk(item: object) -> None:
        for child in getattr(item, "contents", None) or []:
            if isinstance(child, rrb.View):
                views.append(child)
            walk(child)

    walk(blueprint.root_container)
    return views


def test_no_view_of_the_session_blueprint_reports_an_error(tmp_path: Path, page: Page) -> None:
    root = tmp_path / "recordings"
    for k, (rho, theta) in enumerate(((0.8, 0.0), (1.0, 5.0), (0.9, -5.0))):
        run_script(guide_script(f"careful{k}", theta, rho), root)
    _, result = clean_task(root, "wiping", CleanOptions(epochs=1, write_rrd=False, progress=False))
    hub = RerunHub("serve", tmp_path, grpc_port=0, web_port=0)
    try:
        logger = hub.session_logger("views")
        path = np.column_stack([np.linspace(0.3, 0.5, 50), np.zeros(50), np.full(50, 0.3)])
        for k in range(90):  # 3 s of robot states
            logger.log_state(k / 30.0, path[k % 50], np.zeros(7))
        logger.log_demo("demo_file", path)
        logger.log_replay("raw: demo_file", path, "raw")
        # As a Clean job's process does: a second stream into the tab's recording.
        target = logger.clean_target()
        assert target is not None
        assert log_clean_to(target, result, seed=0) == "the live viewer"
        logger.show_cleaned("wiping")
        wait_until(lambda: logger.cleaned_tasks == ["wiping"], 60.0, "the layout to grow")
        # Show every view of every task's layout at once (reports come from shown views),
        # beside a control view that wrongly puts 2-D plane content in a 3-D view.
        views = all_views(session_blueprint(TASKS))
        control = rrb.Spatial3DView(name="control", origin="/", contents=["/wiping/plane/raw/**"])
        grid = rrb.Blueprint(rrb.Grid(*views, control), rrb.SelectionPanel(state="collapsed"))
        assert logger.rec is not None
        logger.rec.send_blueprint(grid, make_active=True)
        url = hub.session_url("views")
        assert url is not None
        probe = open_viewer(page, url)

        def rollouts_arrived() -> ViewerState | None:
            state = probe.state()
            if state.active_store_id is None or len(state.views) != len(views) + 1:
                return None
            entities = probe.entity_paths(state.active_store_id)
            reported = any(v.reports for v in state.views if v.name == "control")
            return state if "/wiping/plane/rollouts" in entities and reported else None

        state = wait_until(rollouts_arrived, VIEWER_TIMEOUT_S, "the Clean and the reports")
        probe.page.screenshot(path=str(tmp_path / "rerun-views.png"))
        shown = {v.name: v for v in state.views}
        assert all(v.visible for v in shown.values())
        summaries = [r.summary for r in shown["control"].reports]
        assert any("pinhole" in s for s in summaries), summaries  # the check can fail
        errors = {v.name: v.reports for v in state.views if v.name != "control" and v.reports}
        assert errors == {}
        assert {"2D", "3D", "BarChart", "TextDocument"} <= {v.kind for v in shown.values()}
        assert errors_in_log(probe) == []
        logger.close()
    finally:
        hub.close()
