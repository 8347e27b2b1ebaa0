"""Soak: 8 scripted browser-like sessions on one teleop app for a long time (10 min by default).

Each of the 8 tabs is a real viser websocket client (:class:`bt_teleop.testing.FakeTab`) that
reads everything the server sends; a driver thread per tab does what a person does, through the
app's own handles: drags the target along a circle (``Session.set_target``, what the gizmo
callback calls) at 30 Hz, presses Record, records a take of a few seconds, presses Stop & save,
and again; every ``--clean-every`` seconds one tab presses Clean (the cleaner then competes for
the CPU, as in real use).

Reported:

* the largest control-loop stall over all sessions: the longest wall time between two control
  ticks minus the tick period (each session's ``_tick`` is wrapped with a timestamp), and the
  99th percentile of those gaps;
* resident memory of the process after the sessions are up and at the end (psutil);
* takes saved vs intended (Stop & save presses; files counted on disk at the end).

Aims (issue 10): no stall > 50 ms, memory flat, 0 lost takes.

    nice -n 10 .venv/bin/python benchmarks/bench_soak.py --minutes 10
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import psutil

from bt_teleop.app import TeleopApp
from bt_teleop.testing import app_factory, circle_uv, tab_factory, wait_until
from bt_teleop.ui import ClientUI

REFUSALS = ("Not done", "Error")
"""Titles of the notices a tab shows when an action fails."""


class TickClock:
    """Wraps a session's ``_tick`` to keep the largest gaps between ticks."""

    def __init__(self, ui: ClientUI) -> None:
        self.gaps: list[float] = []
        self._last: float | None = None
        session = ui.session
        tick = session._tick

        def timed() -> None:
            now = time.perf_counter()
            if self._last is not None:
                self.gaps.append(now - self._last)
            self._last = now
            tick()

        session._tick = timed  # type: ignore[method-assign]


def drive(ui: ClientUI, stop: threading.Event, seed: int, counts: dict[str, int]) -> None:
    """Record takes of 2-4 s with the target on a circle until `stop`."""
    rng = np.random.default_rng(seed)
    plane = ui.session.scene.plane
    t0 = time.perf_counter()
    while not stop.is_set():
        ui.controls.record_button.value = True
        ui.wait_idle()
        end = time.perf_counter() + float(rng.uniform(2.0, 4.0))
        while time.perf_counter() < end and not stop.is_set():
            ui.session.set_target(plane.to_world(circle_uv(time.perf_counter() - t0)))
            time.sleep(1.0 / 30.0)
        if stop.is_set():
            break
        counts["intended"] += 1
        ui.controls.save_button.value = True
        ui.wait_idle(30.0)
        time.sleep(float(rng.uniform(0.2, 1.0)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--sessions", type=int, default=8)
    parser.add_argument("--clean-every", type=float, default=120.0, help="[s]; 0: never")
    args = parser.parse_args()
    process = psutil.Process()
    tmp = tempfile.mkdtemp(prefix="bt-soak-")
    with app_factory(Path(tmp) / "rec") as make, tab_factory() as open_tab:
        app: TeleopApp = make(max_sessions=args.sessions, clean_epochs=5)
        tabs = [open_tab(app, decode=False) for _ in range(args.sessions)]
        uis = list(app.wait_for_sessions(args.sessions, 120.0).values())
        clocks = [TickClock(ui) for ui in uis]
        time.sleep(2.0)
        rss_start = process.memory_info().rss
        stop = threading.Event()
        counts = [{"intended": 0} for _ in uis]
        drivers = [
            threading.Thread(target=drive, args=(ui, stop, k, counts[k]), daemon=True)
            for k, ui in enumerate(uis)
        ]
        for thread in drivers:
            thread.start()
        end = time.monotonic() + 60.0 * args.minutes
        next_clean = time.monotonic() + args.clean_every if args.clean_every else None
        cleans = 0
        while time.monotonic() < end:
            time.sleep(1.0)
            if next_clean is not None and time.monotonic() >= next_clean:
                uis[cleans % len(uis)].controls.clean_button.value = True
                cleans += 1
                next_clean += args.clean_every
        stop.set()
        for thread in drivers:
            thread.join(60.0)
        wait_until(app.settled, 60.0, "tabs to settle")
        for ui in uis:
            ui.wait_idle(120.0)  # the last Stop & save may still be queued
        refused = [body for ui in uis for title, body in ui.messages if title in REFUSALS]
        rss_end = process.memory_info().rss
        received = sum(tab.bytes for tab in tabs)
        saved_ui = sum(len(ui.saved) for ui in uis)
        files = len(list((Path(tmp) / "rec" / "wiping").glob("*.hdf5")))
    gaps = np.concatenate([np.asarray(c.gaps) for c in clocks])
    period = 1.0 / uis[0].session.config.control_hz
    intended = sum(c["intended"] for c in counts)
    print(f"{args.sessions} sessions for {args.minutes:g} min, {cleans} Clean presses")
    print(f"control ticks: {gaps.size}, period {1e3 * period:.1f} ms")
    print(f"largest stall: {1e3 * (gaps.max() - period):.1f} ms beyond the period")
    p99, p999 = (1e3 * np.percentile(gaps, q) for q in (99, 99.9))
    print(f"gap p99: {p99:.1f} ms, p99.9: {p999:.1f} ms")
    print(f"stalls > 50 ms: {int(np.sum(gaps - period > 0.05))}")
    print(f"memory (RSS): {rss_start / 2**20:.0f} MiB at start, {rss_end / 2**20:.0f} MiB at end")
    print(f"takes: {intended} intended, {saved_ui} saved by the tabs, {files} files on disk")
    print(f"refused actions: {len(refused)}" + "".join(f"\n  {body}" for body in refused[:10]))
    print(f"bytes sent to the tabs: {received / 2**20:.0f} MiB")
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
