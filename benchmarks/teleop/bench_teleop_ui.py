"""Teleop web app speed: scene updates per second sent to a browser and target-to-page delay.

Server side, with 1 and 4 simulated tabs (:class:`bt_teleop.testing.harness.FakeTab`: raw viser
websocket clients that read and count everything):

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

    .venv/bin/python benchmarks/teleop/bench_teleop_ui.py --runs 5
"""

from __future__ import annotations

import math
import statistics
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tyro
import zstandard

from bt_teleop.app import TeleopApp
from bt_teleop.testing.harness import (
    FakeTab,
    app_factory,
    chromium_page,
    circle_uv,
    decode_frame,
    tab_factory,
    wait_until,
)
from bt_teleop.ui.tab import ClientUI

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


def circle(ui: ClientUI, t_s: float) -> None:
    """Move the tab's target on a 6 cm circle in the task plane (4 s a lap)."""
    ui.session.set_target(ui.session.scene.plane.to_world(circle_uv(t_s)))


def drive_circles(uis: list[ClientUI], seconds: float) -> None:
    start = time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        for ui in uis:
            circle(ui, elapsed)
        time.sleep(0.01)


@contextmanager
def draining_tabs(app: TeleopApp, n_tabs: int) -> Iterator[tuple[list[FakeTab], list[ClientUI]]]:
    """`n_tabs` simulated tabs that only count what they receive, and their sessions; on exit
    the tabs close and their sessions end."""
    try:
        with tab_factory() as open_tab:
            tabs = [open_tab(app, decode=False) for _ in range(n_tabs)]
            yield tabs, list(app.wait_for_sessions(n_tabs).values())
    finally:
        wait_for(lambda: not app.sessions() and app.settled(), 10.0)


def server_rates(app: TeleopApp, n_tabs: int, seconds: float) -> tuple[float, float]:
    """(scene updates per second per tab, kB per second per tab), medians over tabs."""
    with draining_tabs(app, n_tabs) as (tabs, uis):
        drive_circles(uis, 1.0)  # warm up
        frames0 = [ui.frames for ui in uis]
        bytes0 = [tab.bytes for tab in tabs]
        start = time.perf_counter()
        drive_circles(uis, seconds)
        wall = time.perf_counter() - start
        rates = [(ui.frames - f0) / wall for ui, f0 in zip(uis, frames0, strict=True)]
        kbps = [(tab.bytes - b0) / wall / 1e3 for tab, b0 in zip(tabs, bytes0, strict=True)]
        return statistics.median(rates), statistics.median(kbps)


def step_targets(ui: ClientUI, k: int) -> np.ndarray:
    """The k-th step target: ±3 cm along the task plane's u axis."""
    return ui.session.scene.plane.to_world(np.array([0.03 if k % 2 == 0 else -0.03, 0.0]))


def settle_at(ui: ClientUI, goal: np.ndarray, tolerance_m: float, pause_s: float) -> None:
    """Send the target to `goal` (3,) [m], wait until the end effector is within `tolerance_m`
    [m] of it (at most 5 s), then `pause_s` [s] more."""
    ui.session.set_target(goal)
    wait_for(lambda: np.linalg.norm(ui.session.status().ee_pos - goal) < tolerance_m, 5.0)
    time.sleep(pause_s)


def server_delays(app: TeleopApp, n_tabs: int, steps: int) -> float:
    """Median delay [ms] from set_target to the first published frame that moved."""
    with draining_tabs(app, n_tabs) as (_, uis):
        ui = uis[0]
        delays = []
        for k in range(steps):
            settle_at(ui, step_targets(ui, k), tolerance_m=2e-3, pause_s=0.2)
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
        for message in decode_frame(payload, self._zstd):
            if message.get("type") == "SetPositionMessage" and message.get("name") == self.node:
                self.poses.append((index, np.array(message["position"])))


def browser_numbers(app: TeleopApp, seconds: float, steps: int) -> dict[str, float]:
    """Rates and delays seen by headless Chromium (one tab)."""
    with chromium_page() as page:
        sockets: list[PageSocket] = []

        def watch(ws: Any) -> None:
            sockets.append(PageSocket(""))
            ws.on("framereceived", sockets[-1].on_frame)

        page.on("websocket", watch)
        page.goto(app.url, wait_until="commit")
        page.get_by_text("End effector").first.wait_for(timeout=120_000)
        (ui,) = app.wait_for_sessions(1).values()
        socket = sockets[-1]
        socket.node = f"/robot/body_{ui.tab_scene.view.moving_bodies[-1]}"  # the tool
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
            settle_at(ui, step_targets(ui, k), tolerance_m=1e-3, pause_s=0.5)
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


def _median(values: list[float]) -> float:
    return statistics.median(values) if values else math.nan


def wait_for(condition: Callable[[], Any], timeout_s: float) -> Any:
    """Poll `condition` every 2 ms (delays are measured with it) until truthy; its value."""
    return wait_until(condition, timeout_s, poll_s=0.002)


def main(args: Args) -> None:
    rows: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp, app_factory(Path(tmp)) as make_app:
        app = make_app(max_sessions=8)
        for _ in range(args.runs):
            for n in (1, 4):
                rate, kbps = server_rates(app, n, args.seconds)
                rows.setdefault(f"scene updates/s per tab, {n} tab(s) (server)", []).append(rate)
                rows.setdefault(f"kB/s per tab, {n} tab(s)", []).append(kbps)
                delay = server_delays(app, n, args.steps)
                rows.setdefault(
                    f"set_target → published pose [ms], {n} tab(s) (server)", []
                ).append(delay)
            if args.browser:
                for name, value in browser_numbers(app, args.seconds, args.steps).items():
                    rows.setdefault(name, []).append(value)
                wait_for(lambda: not app.sessions() and app.settled(), 10.0)
    print(f"\n| measurement | median of {args.runs} runs | runs |")
    print("|---|---|---|")
    for name, values in rows.items():
        runs = ", ".join(f"{v:.1f}" for v in values)
        print(f"| {name} | {statistics.median(values):.1f} | {runs} |")


if __name__ == "__main__":
    main(tyro.cli(Args))
