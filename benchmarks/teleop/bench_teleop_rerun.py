"""Live Rerun latency of the teleop app in Rerun's web viewer, with 1 and 4 sessions.

The app runs with ``--rerun serve`` (a web viewer and one gRPC proxy per tab, child processes
bound to 127.0.0.1) and 1 or 4 simulated tabs (:class:`bt_teleop.testing.harness.FakeTab`; each
session's robot moves on a circle). The viewer is what a user opens: the last tab's link, in
Debian's headless Chromium (software WebGL), read through the viewer's own state API
(:class:`bt_teleop.testing.viewer_probe.ViewerProbe`: which recording it shows and the newest
``sim_time`` it holds). Every 0.5 s the benchmark compares that newest time with the session's
simulation time now (the session runs in real time, so simulation seconds behind are wall
seconds behind).

One late viewer per run: opened after ``--warm-s`` seconds of streaming, so the tab's proxy
holds that backlog. Reported: seconds from opening the page until the viewer holds any of the
tab's states ("first data": the web viewer's own start in software WebGL, the same with or
without a backlog) and until it holds them within 2 s of the present ("to the present"); the
lag afterwards (median over 5 s); whether the active recording was the tab's own. "First
data" is the baseline of the same run: what the viewer needs before any backlog. With
``--newest-first``, every case also runs (interleaved, same process) with the proxy's
``--newest-first`` order. Medians over runs; the load average (1 min) is printed with each run.

    nice -n 10 .venv/bin/python benchmarks/teleop/bench_teleop_rerun.py --runs 3
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tyro

from bt_teleop.testing.harness import app_factory, chromium_page, circle_uv, tab_factory
from bt_teleop.testing.viewer_probe import ViewerProbe
from bt_teleop.ui.tab import ClientUI

CAUGHT_UP_S = 2.0
"""A viewer shows the present when it holds the session's states up to this close [s]."""


@dataclass(frozen=True)
class Args:
    runs: int = 3
    """Repetitions; medians are reported."""
    warm_s: float = 30.0
    """Seconds of streaming before the late viewer opens."""
    watch_s: float = 90.0
    """Longest wait for a viewer to reach the present [s]; the lag is then watched 5 s more."""
    newest_first: bool = False
    """Also run every case with the proxy's ``--newest-first`` order (interleaved)."""


@dataclass(frozen=True)
class ViewerRun:
    first_data_s: float
    """Seconds from opening the page until the viewer holds any of the tab's states."""
    to_present_s: float
    """Seconds from opening the page until the viewer holds the present (inf: not in time)."""
    lag_after_s: float
    """Median lag over the 5 s after that [s]."""
    own_recording: bool
    """Whether the viewer's active recording was the tab's own."""
    backlog_s: float
    """Seconds of the session already streamed when the page opened."""


def move(uis: list[ClientUI], t0: float) -> None:
    for k, ui in enumerate(uis):
        plane = ui.session.scene.plane
        ui.session.set_target(plane.to_world(circle_uv(time.perf_counter() - t0 + k)))


def watch(url: str, ui: ClientUI, uis: list[ClientUI], t0: float, args: Args) -> ViewerRun:
    """Open `url` in a fresh Chromium and follow the viewer until it shows the present."""
    store = f"Recording:bt_teleop:{ui.session_id}"
    with chromium_page({"width": 1400, "height": 900}, timeout_ms=args.watch_s * 1000) as page:
        opened = time.perf_counter()
        backlog = ui.session.status().sim_time_s
        page.goto(url, wait_until="load")
        probe = ViewerProbe(page)
        first, to_present, lags, own = float("inf"), float("inf"), [], False
        while time.perf_counter() - opened < args.watch_s:
            move(uis, t0)
            time.sleep(0.5)
            if not probe.started():
                continue
            state = probe.state()
            newest = state.newest_s.get(store, {}).get("sim_time", -np.inf)
            lag = ui.session.status().sim_time_s - newest
            if first == float("inf") and np.isfinite(newest):
                first = time.perf_counter() - opened
            if to_present == float("inf") and lag < CAUGHT_UP_S:
                to_present = time.perf_counter() - opened
                own = state.active_store_id == store
            elif to_present < float("inf"):
                lags.append(lag)
                if time.perf_counter() - opened > to_present + 5.0:
                    break
    lag_after = statistics.median(lags) if lags else float("inf")
    return ViewerRun(first, to_present, lag_after, own, backlog)


def run_once(n_tabs: int, newest_first: bool, args: Args) -> ViewerRun:
    """The late viewer of one app run."""
    with (
        tempfile.TemporaryDirectory() as tmp,
        tab_factory() as open_tab,
        app_factory(Path(tmp) / "recordings") as make,
    ):
        app = make(
            rerun="serve", rerun_grpc_port=0, rerun_web_port=0, rerun_newest_first=newest_first
        )
        for _ in range(n_tabs):
            open_tab(app, decode=False)
        uis = list(app.wait_for_sessions(n_tabs, 120.0).values())
        ui = uis[-1]
        url = app.rerun.session_url(ui.session_id)
        assert url is not None
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < args.warm_s:
            move(uis, t0)
            time.sleep(0.25)
        return watch(url, ui, uis, t0, args)


def _row(n_tabs: int, order: str, runs: list[ViewerRun], watch_s: float) -> str:
    def median(values: list[float]) -> str:
        value = statistics.median(values)
        return f"{value:.1f} s" if np.isfinite(value) else f"not within {watch_s:.0f} s"

    own = sum(r.own_recording for r in runs)
    return (
        f"| {n_tabs} | {order} | {statistics.median(r.backlog_s for r in runs):.0f} s "
        f"| {median([r.first_data_s for r in runs])} | {median([r.to_present_s for r in runs])} "
        f"| {median([r.lag_after_s for r in runs])} | {own}/{len(runs)} |"
    )


def main(args: Args) -> None:
    print(f"live Rerun latency in the web viewer, medians of {args.runs} runs")
    rows = []
    for n_tabs in (1, 4):
        orders = ("in order", "newest first") if args.newest_first else ("in order",)
        by_order: dict[str, list[ViewerRun]] = {order: [] for order in orders}
        for run in range(args.runs):
            for order, runs in by_order.items():  # interleaved: both see the same load
                result = run_once(n_tabs, order == "newest first", args)
                load = os.getloadavg()[0]
                line = f"  {n_tabs} tabs, {order}, run {run + 1}: {result}; load {load:.1f}"
                print(line, flush=True)
                runs.append(result)
        rows.extend(_row(n_tabs, order, runs, args.watch_s) for order, runs in by_order.items())
    print("| tabs | proxy order | streamed | first data | to the present | lag after | own |")
    print("|---|---|---|---|---|---|---|")
    print("\n".join(rows))


if __name__ == "__main__":
    main(tyro.cli(Args))
