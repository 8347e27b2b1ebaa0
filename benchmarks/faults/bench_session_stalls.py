"""Stalled and killed session children while tabs record (bt_teleop/session/process.py).

N tabs (:class:`bt_teleop.testing.harness.FakeTab`) record takes of 2-4 s back to back through the
app's own handles (:func:`benchmarks.common.soak_drive.drive`). Meanwhile, every ``--stall-every``
seconds one child, in turn, is stopped (SIGSTOP) for ``--stall-s`` seconds, longer than a quick
call's 5 s timeout (a starved child on a loaded machine), and every ``--kill-every`` seconds one is
killed (SIGKILL). Reported: takes intended, saved and reported lost (a take is intended when its
driver presses Stop & save; one whose child was killed under it cannot be saved and must be reported
in the tab's notice, never dropped silently), children replaced, the stalls that made a session lost
(aim: 0), and the tabs' "Not done" notices.

Run::

    nice -n 10 .venv/bin/python benchmarks/faults/bench_session_stalls.py --minutes 3 --sessions 4
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repo root: benchmarks.common

from benchmarks.common.soak_drive import drive
from bt_teleop.session.process import SessionProcess
from bt_teleop.testing.harness import app_factory, tab_factory
from bt_teleop.ui.tab import ClientUI


class Notices:
    """Every notice of a tab (its own list keeps only the last 100)."""

    def __init__(self, ui: ClientUI) -> None:
        self.titles: list[str] = []
        notify = ui._notify

        def counted(title: str, body: str, color: Any = None) -> None:
            self.titles.append(title)
            notify(title, body, color)

        ui._notify = counted  # type: ignore[method-assign]
        ui.takes.notify = counted  # it holds its own reference (saves, a restarted simulation)


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("--minutes", type=float, default=3.0)
    parser.add_argument("--sessions", type=int, default=4)
    parser.add_argument("--stall-every", type=float, default=15.0, help="[s]")
    parser.add_argument("--stall-s", type=float, default=8.0, help="each SIGSTOP [s]")
    parser.add_argument("--kill-every", type=float, default=60.0, help="[s]; 0: never")
    parser.add_argument("--take-s", type=float, default=2.0)
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.1f}")
    with (
        tempfile.TemporaryDirectory() as tmp,
        app_factory(Path(tmp) / "rec") as make_app,
        tab_factory() as open_tab,
    ):
        app = make_app(clean_epochs=1, idle_timeout_s=float("inf"))
        for _ in range(args.sessions):
            open_tab(app, decode=False)
        uis = list(app.wait_for_sessions(args.sessions, 120.0).values())
        notices = [Notices(ui) for ui in uis]
        stop = threading.Event()
        counts = [{"intended": 0} for _ in uis]
        drivers = [
            threading.Thread(target=drive, args=(ui, stop, k, counts[k], args.take_s), daemon=True)
            for k, ui in enumerate(uis)
        ]
        for thread in drivers:
            thread.start()
        start = time.monotonic()
        end = start + 60.0 * args.minutes
        next_stall, next_kill = start + args.stall_every, start + (args.kill_every or 1e12)
        stalls = kills = 0
        loads: list[float] = []
        while time.monotonic() < end:
            time.sleep(0.5)
            loads.append(os.getloadavg()[0])
            now = time.monotonic()
            if now >= next_stall:
                session = uis[stalls % len(uis)].session
                assert isinstance(session, SessionProcess) and session.pid is not None
                os.kill(session.pid, signal.SIGSTOP)
                time.sleep(args.stall_s)
                os.kill(session.pid, signal.SIGCONT)
                stalls += 1
                next_stall = time.monotonic() + args.stall_every
            if now >= next_kill:
                session = uis[(kills + 1) % len(uis)].session
                assert isinstance(session, SessionProcess) and session.pid is not None
                os.kill(session.pid, signal.SIGKILL)
                kills += 1
                next_kill += args.kill_every
        stop.set()
        for thread in drivers:
            thread.join(120.0)
        for ui in uis:
            ui.wait_idle(120.0)
        sessions = [ui.session for ui in uis if isinstance(ui.session, SessionProcess)]
        recoveries = [r for s in sessions for r in s.recoveries]
        intended = sum(c["intended"] for c in counts)
        saved = sum(ui.takes.saved_count for ui in uis)
        files = len(list((Path(tmp) / "rec" / "wiping").glob("*.hdf5")))
        titles = [t for n in notices for t in n.titles]
    print(
        f"{args.sessions} tabs, {args.minutes:g} min; load average (1 min) during the run: "
        f"min {min(loads):.1f}, mean {sum(loads) / len(loads):.1f}, max {max(loads):.1f}"
    )
    print(f"stalls: {stalls} of {args.stall_s:g} s; kills: {kills}")
    print(f"children replaced: {len(recoveries)} (" + "; ".join(r.reason for r in recoveries) + ")")
    print(
        f"takes: {intended} intended, {saved} saved by the tabs, {files} files on disk; "
        f"reported lost: {sum(r.take_lost for r in recoveries)}; saved by a lost child: "
        f"{sum(len(r.saved) for r in recoveries)}"
    )
    print("notices: " + ", ".join(f"{t} {titles.count(t)}" for t in sorted(set(titles))))


if __name__ == "__main__":
    main()
