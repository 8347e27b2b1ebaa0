"""Regenerate the screenshots in docs/teleop.md: the page after Clean, and the tab's live Rerun
view, in Debian's headless Chromium (software WebGL; never ``playwright install``).

python examples/make_screenshots.py                 # docs/images/teleop-*.png
python examples/make_screenshots.py --out /tmp/shots

The session is the one tests/teleop/browser/test_browser_session.py checks: the task folder starts
with four real browser takes (``../shared/data/browser-takes``, or ``$BT_SHARED_DIR``), the page
records a circle of its own (the target follows it as a drag of the gizmo moves it) and a junk
take, then Clean runs with the cleaner's default epochs and the cleaned ★ is replayed. The tab's
Rerun link is then opened in a second page (the app's page frozen meanwhile: software WebGL would
take the CPU the viewer needs) and shot once the viewer holds the Clean: its robot tab, then its
wiping tab (clicked in the viewer's tab bar; checked through the viewer's state, not its pixels).
Images are reduced to a palette of 256 colours so each stays under 300 kB. Takes a few minutes on a
loaded 2-core machine.
"""

from __future__ import annotations

import io
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import tyro
from PIL import Image
from playwright.sync_api import Page, ViewportSize, expect

from bt_teleop.testing.harness import (
    app_factory,
    chromium_page,
    circle_uv,
    open_tab,
    record_in_page,
    shared_dir,
    type_name,
    wait_until,
)
from bt_teleop.testing.viewer_probe import ViewerProbe, ViewerState

PLACED = ("alice_", "bob_", "carol_", "dave_")
"""The real browser takes the task folder starts with
(tests/teleop/browser/test_browser_session.py)."""
PAGE_TIMEOUT_MS = 120_000
VIEWER_TIMEOUT_S = 300.0
"""Longest wait for Rerun's web viewer to start and hold the Clean [s] (software WebGL)."""


@dataclass
class Args:
    out: Path = Path(__file__).resolve().parents[1] / "docs" / "images"
    """Folder of the PNG files (teleop-after-clean.png, teleop-rerun*.png)."""
    width: int = 1280
    """Page width [px]."""
    height: int = 1300
    """Height [px] of the app's page (its panel whole after Clean)."""
    viewer_height: int = 800
    """Height [px] of the Rerun viewer's page."""


def save_png(png: bytes, path: Path, max_width: int = 1100) -> None:
    """`png` at most `max_width` px wide, with a 256-colour palette, to `path`."""
    image = Image.open(io.BytesIO(png)).convert("RGB")
    if image.width > max_width:
        height = round(image.height * max_width / image.width)
        image = image.resize((max_width, height), Image.Resampling.LANCZOS)
    image.quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)
    print(f"{path}: {image.width} x {image.height} px, {path.stat().st_size / 1024:.0f} kB")


def close_notifications(page: Page) -> None:
    """Close the page's notifications (they cover the 3-D view)."""
    close = "document.querySelectorAll('.mantine-Notification-closeButton').forEach(b => b.click())"
    for _ in range(10):  # they slide out; a new one may arrive meanwhile
        page.evaluate(close)
        time.sleep(0.5)
        if page.locator(".mantine-Notification-closeButton").count() == 0:
            return


def main(args: Args) -> None:
    args.out.mkdir(parents=True, exist_ok=True)
    expect.set_options(timeout=PAGE_TIMEOUT_MS)
    viewport: ViewportSize = {"width": args.width, "height": args.height}
    with tempfile.TemporaryDirectory(prefix="bt-shots-") as tmp:
        root = Path(tmp) / "recordings"
        folder = root / "wiping"
        folder.mkdir(parents=True)
        for path in sorted((shared_dir() / "data/browser-takes/wiping").glob("*.hdf5")):
            if path.name.startswith(PLACED):
                shutil.copy2(path, folder / path.name)
        with (
            app_factory(root) as make,
            chromium_page(viewport=viewport, timeout_ms=PAGE_TIMEOUT_MS) as page,
        ):
            app = make(rerun="serve", rerun_grpc_port=0, rerun_web_port=0, clean_epochs=None)
            ui = open_tab(page, app)
            type_name(page, ui, "Ada Lovelace")
            record_in_page(page, ui, circle_uv, seconds=5.0)
            record_in_page(page, ui, None)  # a junk take: flagged, skipped by Clean
            page.get_by_role("button", name="Clean", exact=True).click()
            cleaned = page.get_by_text("Cleaned: 5 demos", exact=False)
            expect(cleaned).to_be_visible(timeout=900_000)
            for folder_title in ("Demonstration", "Record"):  # the table and pickers in view
                page.get_by_text(folder_title, exact=True).first.click()
            close_notifications(page)
            time.sleep(2.0)  # a few frames of software WebGL
            save_png(page.screenshot(), args.out / "teleop-after-clean.png")
            page.get_by_role("button", name="Play", exact=True).click()  # the cleaned ★
            done = page.get_by_text("tracked within", exact=False)
            expect(done).to_be_visible(timeout=300_000)

            href = page.get_by_role("link", name="Open the live Rerun viewer").get_attribute("href")
            assert href is not None
            page.context.new_cdp_session(page).send(
                "Page.setWebLifecycleState", {"state": "frozen"}
            )
            browser = page.context.browser
            assert browser is not None
            viewer_size: ViewportSize = {"width": args.width, "height": args.viewer_height}
            viewer = browser.new_page(viewport=viewer_size)
            viewer.goto(href, wait_until="load")
            probe = ViewerProbe(viewer)
            wait_until(probe.started, VIEWER_TIMEOUT_S, "the Rerun web viewer to start")
            mine = f"Recording:bt_teleop:{ui.session_id}"

            def holds_the_clean() -> ViewerState | None:
                state = probe.state()
                if state.active_store_id != mine:
                    return None
                paths = probe.entity_paths(mine)
                ready = "/wiping/plane/rollouts" in paths and len(state.views) > 2
                return state if ready else None

            wait_until(holds_the_clean, VIEWER_TIMEOUT_S, "the viewer to hold the Clean", 1.0)
            time.sleep(5.0)  # the views draw what they hold
            save_png(viewer.screenshot(), args.out / "teleop-rerun.png")
            show_tab(probe, "wiping", args.width)
            time.sleep(5.0)
            save_png(viewer.screenshot(), args.out / "teleop-rerun-clean.png")


def show_tab(probe: ViewerProbe, task: str, width: int) -> None:
    """Click `task`'s tab in the viewer's tab bar (egui draws it: no DOM to click) until the
    viewer reports its views visible."""

    def shown() -> bool:
        views = [v for v in probe.state().views if v.name.startswith(f"{task}: ")]
        return bool(views) and all(v.visible for v in views)

    for x_share in (0.238, 0.245, 0.23, 0.255):  # the tab's title, right of the robot tab's
        probe.page.mouse.click(round(x_share * width), 50)
        try:
            wait_until(shown, 10.0, f"the {task} tab", 0.5)
        except TimeoutError:
            continue
        return
    raise TimeoutError(f"the viewer did not show the {task} tab")


if __name__ == "__main__":
    main(tyro.cli(Args))
