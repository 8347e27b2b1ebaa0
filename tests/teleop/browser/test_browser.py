"""End to end in a real browser: Debian's Chromium (headless, software WebGL) drives the teleop app.

Load the page, see the controls, type a name, record ~2 s and save through the buttons, find
the file on disk, and check in a screenshot that the FR3 is drawn: the pixels that change when
the robot is hidden server-side must be many and sit in the 3-D view. `.ci/run` installs
Chromium with apt-get when it is missing (never ``playwright install``). Every wait is on a
condition, with generous limits: software WebGL compiles shaders slowly on a busy machine.
"""

from __future__ import annotations

import io
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from playwright.sync_api import Page, expect

from bt_pipeline.data.recording import read_recording
from bt_teleop.app import TeleopApp
from bt_teleop.testing.harness import app_factory, wait_until
from bt_teleop.ui.tab import ClientUI
from tests.teleop.browser.conftest import PAGE_TIMEOUT_MS


@pytest.fixture
def app(tmp_path: Path) -> Iterator[TeleopApp]:
    with app_factory(tmp_path / "recordings") as make:
        yield make()


def screenshot(page: Page) -> np.ndarray:
    """The page as an RGB array, shape (H, W, 3)."""
    png = page.screenshot(animations="disabled")
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)


def robot_pixels(page: Page, ui: ClientUI) -> tuple[np.ndarray, np.ndarray]:
    """(mask of pixels that change when the robot is hidden and back when it is shown again
    (H, W), the shown screenshot). Pixels that change for another reason between the shots (a
    status line or notice redrawn: a loaded CI run saw 911 such) are not in the mask."""

    def differs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.abs(a - b).sum(axis=2) > 30

    def shot_until(done: Callable[[np.ndarray], bool]) -> np.ndarray:
        deadline = time.monotonic() + 60.0
        shot = screenshot(page)
        while not done(shot) and time.monotonic() < deadline:
            shot = screenshot(page)
        return shot

    shown = screenshot(page)
    ui.tab_scene.view.set_visible(False)
    try:  # the next frame drawn without the robot
        hidden = shot_until(lambda shot: bool(np.any(shot != shown)))
    finally:
        ui.tab_scene.view.set_visible(True)
    change = int(differs(shown, hidden).sum())
    again = shot_until(lambda shot: int(differs(shot, shown).sum()) < change // 2)  # drawn back
    return differs(shown, hidden) & differs(again, hidden) & ~differs(shown, again), shown


def test_record_in_the_browser_and_see_the_robot(app: TeleopApp, page: Page) -> None:
    page.goto(app.url, wait_until="commit")
    record = page.get_by_role("button", name="Record", exact=True)
    expect(record).to_be_visible(timeout=PAGE_TIMEOUT_MS)
    for name in ("Stop & save", "Discard", "Clean", "Play"):
        expect(page.get_by_role("button", name=name, exact=True)).to_be_visible()
    expect(page.get_by_role("checkbox", name="Stay on task plane")).to_be_visible()
    expect(page.get_by_role("combobox", name="Task")).to_have_value("wiping")
    (ui,) = app.wait_for_sessions(1).values()

    name = page.locator("xpath=//p[normalize-space(.)='Demonstrator']/following::input[1]")
    name.fill("Ada Lovelace")
    name.press("Enter")
    wait_until(lambda: ui.controls.name_input.value == "Ada Lovelace", 30.0, "the name to arrive")

    record.click()
    wait_until(lambda: ui.session.recording, 30.0, "the recording to start")
    expect(page.get_by_text("Recording", exact=False).first).to_be_visible(timeout=PAGE_TIMEOUT_MS)
    wait_until(lambda: ui.session.status().duration_s >= 2.0, 30.0, "2 s of recording")
    page.get_by_role("button", name="Stop & save", exact=True).click()
    path = wait_until(lambda: ui.saved and ui.saved[-1], 30.0, "the file to be saved")

    assert path.is_file() and path.parent == app.options.recordings / "wiping"
    assert path.name.startswith("Ada-Lovelace_")
    recording = read_recording(path)
    demo = recording.demos["demo_0"]
    assert recording.task == "wiping" and demo.demonstrator == "Ada Lovelace"
    assert demo.num_samples >= 100 and demo.timestamps[-1] >= 2.0  # 50 Hz for ≥ 2 s
    listed = page.get_by_text("Ada Lovelace").first  # in the recordings list
    expect(listed).to_be_visible(timeout=PAGE_TIMEOUT_MS)

    notice = page.get_by_text("Saved", exact=True)
    expect(notice).to_be_hidden(timeout=PAGE_TIMEOUT_MS)  # it closes itself: not in the diff
    changed, shown = robot_pixels(page, ui)
    canvas = page.locator("canvas").first.bounding_box()
    assert canvas is not None
    panel = page.get_by_role("button", name="Record", exact=True).bounding_box()
    assert panel is not None
    view = np.zeros_like(changed)  # the 3-D view left of the control panel
    view[int(canvas["y"]) : int(canvas["y"] + canvas["height"]), : int(panel["x"]) - 20] = True
    n_robot = int(changed[view].sum())
    assert n_robot > 0.02 * view.sum(), f"only {n_robot} robot pixels"
    assert int(changed[~view].sum()) < 0.05 * n_robot  # the change is the robot, in the view
    robot_rgb = shown[changed]
    assert robot_rgb.std(axis=0).mean() > 20  # shaded links, not a flat blob
