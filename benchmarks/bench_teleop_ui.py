"""Teleop web app speed: scene updates per second sent to a browser and target-to-page delay.

Server side, with 1 and 4 simulated tabs (raw viser websocket clients that read everything):

* scene updates per second per tab: the tab worker's published frames (robot link poses,
  target marker, trail, status text; one ``client.atomic()`` group each) over wall time, with
  the target moving on a circle; and the bytes per second a tab receives;
* delay from a target update (``Session.set_target``, what the gizmo callback does) to the
  first published frame whose end-effector position has moved: control tick + publish period.

In a real browser (Debian's Chromium, headless, software WebGL; one tab):

* websocket frames per second the page receives, and status-text updates per second rendered
  into the page (the status line shows the end-effector position in mm, updated with each
  scene update);
* delay from ``set_target`` (wall clock) to the moment the page's DOM shows the moved end
  effector (a MutationObserver stamps ``Date.now()``; same machine, same clock).

Every number is the median over runs (the machine may be shared). The aim (issue 4): ≥ 30
scene updates per second.

    .venv/bin/python benchmarks/bench_teleop_ui.py --runs 5
"""

from __future__ import annotations

import math
import statistics
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import tyro
import viser
import zstandard
from websockets.sync.client import connect

from bt_teleop.app import AppOptions, TeleopApp, start_app
from bt_teleop.ui import ClientUI

CAMERA = {
    "type": "ViewerCameraMessage",
    "wxyz": [1.0, 0.0, 0.0, 0.0],
    "position": [1.0, -1.0, 1.0],
    "fov": 1.0,
    "near": 0.01,
    "far": 100.0,
    "image_height": 600,
    "image_width": 800,
    "look_at": [0.4, 0.0, 0.2],
    "up_direction": [0.0, 0.0, 1.0],
}
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--enable-unsafe-swiftshader",
    "--use-angle=swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
WATCH_STATUS_JS = """() => {
  window.__bt = [];
  let last = null;
  const read = () => {
    const p = [...document.querySelectorAll('p')].find(e => e.textContent.includes('End effector'));
    const text = p ? p.textContent : null;
    if (text !== null && text !== last) { last = text; window.__bt.push([Date.now(), text]); }
  };
  new MutationObserver(read).observe(document.body,
    {subtree: true, childList: true, characterData: true});
  read();
}"""


@dataclass(frozen=True)
class Args:
    """Benchmark settings."""

    runs: int = 5
    """Repetitions; medians are reported."""
    seconds: float = 4.0
    """Wall seconds of each rate measurement."""
    steps: int = 8
    """Target steps per delay measurement."""
    browser: bool = True
    """Also measure in headless Chromium (/usr/bin/chromium)."""


class DrainingTab:
    """A simulated tab: connects like a browser and reads (and counts) everything sent."""

    def __init__(self, port: int) -> None:
        self.ws = connect(
            f"ws://127.0.0.1:{port}",
            subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]
            max_size=None,
        )
        self.bytes = 0
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()
        self.ws.send(msgspec.msgpack.encode(CAMERA))

    def _read(self) -> None:
        try:
            for frame in self.ws:
                self.bytes += len(frame)
        except Exception:  # closed
            return

    def close(self) -> None:
        self.ws.close()
        self._thread.join(5.0)


def circle(ui: ClientUI, t_s: float) -> None:
    """Move the tab's target on a 6 cm circle in the task plane (4 s a lap)."""
    phase = 2.0 * math.pi * t_s / 4.0
    uv = 0.06 * np.array([math.sin(phase), 1.0 - math.cos(phase)])
    ui.session.set_target(ui.session.scene.plane.to_world(uv))


def drive_circles(uis: list[ClientUI], seconds: float) -> None:
    start = time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        for ui in uis:
            circle(ui, elapsed)
        time.sleep(0.01)


def server_rates(app: TeleopApp, n_tabs: int, seconds: float) -> tuple[float, float]:
    """(scene updates per second per tab, kB per second per tab), medians over tabs."""
    tabs = [DrainingTab(app.port) for _ in range(n_tabs)]
    try:
        uis = list(app.wait_for_sessions(n_tabs).values())
        drive_circles(uis, 1.0)  # warm up
        frames0 = [ui.frames for ui in uis]
        bytes0 = [tab.bytes for tab in tabs]
        start = time.perf_counter()
        drive_circles(uis, seconds)
        wall = time.perf_counter() - start
        rates = [(ui.frames - f0) / wall for ui, f0 in zip(uis, frames0, strict=True)]
        kbps = [(tab.bytes - b0) / wall / 1e3 for tab, b0 in zip(tabs, bytes0, strict=True)]
        return statistics.median(rates), statistics.median(kbps)
    finally:
        for tab in tabs:
            tab.close()
        wait_for(lambda: not app.sessions() and app.settled(), 10.0)


def step_targets(ui: ClientUI, k: int) -> np.ndarray:
    """The k-th step target: ±3 cm along the task plane's u axis."""
    return ui.session.scene.plane.to_world(np.array([0.03 if k % 2 == 0 else -0.03, 0.0]))


def server_delays(app: TeleopApp, n_tabs: int, steps: int) -> float:
    """Median delay [ms] from set_target to the first published frame that moved."""
    tabs = [DrainingTab(app.port) for _ in range(n_tabs)]
    try:
        uis = list(app.wait_for_sessions(n_tabs).values())
        ui = uis[0]
        delays = []
        for k in range(steps):
            goal = step_targets(ui, k)
            ui.session.set_target(goal)
            wait_for(lambda g=goal: np.linalg.norm(ui.session.status().ee_pos - g) < 2e-3, 5.0)
            time.sleep(0.2)
            before = ui.session.status().ee_pos
            t0 = time.perf_counter()
            ui.session.set_target(step_targets(ui, k + 1))
            frame = wait_for(
                lambda t=t0, b=before: (
                    (f := ui.last_frame) is not None
                    and f.wall_time_s > t
                    and np.linalg.norm(f.ee_pos - b) > 1e-4
                    and f
                ),
                5.0,
            )
            delays.append(1e3 * (frame.wall_time_s - t0))
        return statistics.median(delays)
    finally:
        for tab in tabs:
            tab.close()
        wait_for(lambda: not app.sessions() and app.settled(), 10.0)


class PageSocket:
    """The page's websocket as Playwright reports it: tool poses decoded from each frame."""

    def __init__(self, node: str) -> None:
        self.node = node
        self.frames = 0
        """Websocket frames received so far."""
        self.poses: list[tuple[int, np.ndarray]] = []
        """(frame index, tool position) of every tool pose update."""
        self._zstd = zstandard.ZstdDecompressor()

    def on_frame(self, payload: bytes | str) -> None:
        index = self.frames
        self.frames += 1
        if not isinstance(payload, bytes):
            return
        size = int.from_bytes(payload[:8], "little")
        compressed = int.from_bytes(payload[8:16], "little")
        inner = self._zstd.decompress(payload[16 : 16 + compressed], max_output_size=size)
        for message in msgspec.msgpack.decode(inner)["messages"]:
            if message.get("type") == "SetPositionMessage" and message.get("name") == self.node:
                self.poses.append((index, np.array(message["position"])))


def browser_numbers(app: TeleopApp, seconds: float, steps: int) -> dict[str, float]:
    """Rates and delays seen by headless Chromium (one tab)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(
            executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS, headless=True
        )
        try:
            page = browser.new_page(viewport={"width": 1000, "height": 700})
            sockets: list[PageSocket] = []

            def watch(ws: Any) -> None:
                sockets.append(PageSocket(""))
                ws.on("framereceived", sockets[-1].on_frame)

            page.on("websocket", watch)
            page.goto(app.url, wait_until="commit")
            page.get_by_text("End effector").first.wait_for(timeout=120_000)
            (ui,) = app.wait_for_sessions(1).values()
            socket = sockets[-1]
            socket.node = f"/robot/body_{ui.view.moving_bodies[-1]}"  # the tool
            page.evaluate(WATCH_STATUS_JS)
            drive_circles([ui], 2.0)  # warm up (shader compilation)
            page.evaluate("0")  # let Playwright deliver the frames received so far
            n0, dom0 = len(socket.poses), len(page.evaluate("window.__bt"))
            start = time.perf_counter()
            drive_circles([ui], seconds)
            wall = time.perf_counter() - start
            page.evaluate("0")
            received = (len(socket.poses) - n0) / wall
            rendered = (len(page.evaluate("window.__bt")) - dom0) / wall
            page_delays = []
            for k in range(steps):
                goal = step_targets(ui, k)
                ui.session.set_target(goal)
                wait_for(lambda g=goal: np.linalg.norm(ui.session.status().ee_pos - g) < 1e-3, 5)
                time.sleep(0.5)
                dom_seen = len(page.evaluate("window.__bt"))
                t0_ms = time.time() * 1e3
                ui.session.set_target(step_targets(ui, k + 1))
                time.sleep(1.0)
                shown = [t for t, _ in page.evaluate("window.__bt")[dom_seen:] if t >= t0_ms]
                if shown:
                    page_delays.append(shown[0] - t0_ms)
            return {
                "tool pose updates/s reaching the page (Chromium)": received,
                "status-text updates/s rendered in the page (Chromium)": rendered,
                "set_target → pose shown in the page DOM [ms] (Chromium)": _median(page_delays),
            }
        finally:
            browser.close()


def _median(values: list[float]) -> float:
    return statistics.median(values) if values else math.nan


def wait_for(condition: Callable[[], Any], timeout_s: float) -> Any:
    """Poll `condition` until truthy; its value (TimeoutError after `timeout_s` [s])."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.002)
    raise TimeoutError(f"condition not met in {timeout_s} s")


def main(args: Args) -> None:
    rows: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        app = start_app(AppOptions(port=0, recordings=Path(tmp), rerun="off", max_sessions=8))
        try:
            for _ in range(args.runs):
                for n in (1, 4):
                    rate, kbps = server_rates(app, n, args.seconds)
                    rows.setdefault(f"scene updates/s per tab, {n} tab(s) (server)", []).append(
                        rate
                    )
                    rows.setdefault(f"kB/s per tab, {n} tab(s)", []).append(kbps)
                    delay = server_delays(app, n, args.steps)
                    rows.setdefault(
                        f"set_target → published pose [ms], {n} tab(s) (server)", []
                    ).append(delay)
                if args.browser:
                    for name, value in browser_numbers(app, args.seconds, args.steps).items():
                        rows.setdefault(name, []).append(value)
                    wait_for(lambda: not app.sessions() and app.settled(), 10.0)
        finally:
            app.stop()
    print(f"\n| measurement | median of {args.runs} runs | runs |")
    print("|---|---|---|")
    for name, values in rows.items():
        runs = ", ".join(f"{v:.1f}" for v in values)
        print(f"| {name} | {statistics.median(values):.1f} | {runs} |")


if __name__ == "__main__":
    main(tyro.cli(Args))
