"""Live Rerun latency of the teleop app with a viewer attached, with 1 and 4 sessions.

The app runs with ``--rerun serve`` (the proxy + web viewer child process, bound to 127.0.0.1)
and 1 or 4 simulated tabs (:class:`bt_teleop.testing.FakeTab`; each session's robot moves on a
circle). The viewer is a gRPC client of the proxy: the bundled ``rerun`` binary connected to
the proxy URL, saving what it receives (``rerun <proxy url> --save viewer.rrd``), which is what
a web viewer receives. Every 0.25 s the benchmark reads that growing file and compares, per
session recording, the newest ``sim_time`` received with the session's simulation time now
(the session runs in real time, so simulation seconds behind are wall seconds behind).

Two viewers per run:

* *attached from the start* (the baseline, same process, same run): the lag while streaming;
* *opened late*, after ``--warm-s`` seconds of streaming (the proxy then holds a backlog):
  the seconds from opening until the lag (high bound) is under 2 s (catch-up), and the lag
  afterwards.

Lags are given as low..high bounds: the sessions' clocks are read before and after reading
the file (which takes up to seconds on a loaded machine). Medians over runs. The issue's aim:
a viewer opened at any time shows the present within a few seconds.

    nice -n 10 .venv/bin/python benchmarks/bench_teleop_rerun.py --runs 3
"""

from __future__ import annotations

import statistics
import subprocess
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr
import tyro

from bt_teleop.rerun_proxy import free_port, rerun_binary
from bt_teleop.testing import app_factory, circle_uv, tab_factory
from bt_teleop.ui import ClientUI

CAUGHT_UP_S = 2.0
"""A viewer has caught up when its lag (high bound, reading time included) is below this [s]."""


@dataclass(frozen=True)
class Args:
    runs: int = 3
    """Repetitions; medians are reported."""
    warm_s: float = 20.0
    """Seconds of streaming before the late viewer opens."""
    watch_s: float = 20.0
    """Longest wait for the late viewer to catch up [s]; the lag is then watched 5 s more."""


def newest_sim_times(rrd: Path) -> dict[str, float]:
    """Newest ``sim_time`` [s] of ``/ee/position`` per recording id in a (growing) .rrd."""
    newest: dict[str, float] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # no footer yet: the file is still being written
        try:
            reader = rr.chunk.RrdReader(rrd)
            stores = reader.recordings()
            chunks = [(s, c) for s in stores for c in reader.stream(store=s).to_chunks()]
        except Exception:  # not written yet, or a chunk half written
            return newest
    for store, chunk in chunks:
        if str(chunk.entity_path) != "/ee/position":
            continue
        batch = chunk.to_record_batch()
        times = batch.column(batch.schema.names.index("sim_time")).to_numpy()
        if len(times):
            value = float(np.max(times.astype(np.int64))) * 1e-9
            newest[store.recording_id] = max(newest.get(store.recording_id, 0.0), value)
    return newest


class Viewer:
    """A gRPC client of the proxy that saves what it receives (as a viewer would see it)."""

    def __init__(self, grpc_url: str, folder: Path, name: str) -> None:
        self.path = folder / f"{name}.rrd"
        self.newest: dict[str, float] = {}
        port = free_port(0, "127.0.0.1")
        self.process = subprocess.Popen(
            [
                str(rerun_binary()),
                grpc_url,
                "--save",
                str(self.path),
                "--bind",
                "127.0.0.1",
                "--port",
                str(port),
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )

    def lag(self, uis: list[ClientUI]) -> tuple[float, float]:
        """Bounds (low, high) [s] on how far behind the most lagging session the viewer is.

        Reading the file takes time (seconds on a loaded machine): the sessions' clocks are
        read before it (low bound) and after it (high bound). inf: nothing of a session yet. A
        read that fails (a chunk half written) keeps the last answer."""
        before = [ui.session.status().sim_time_s for ui in uis]
        for recording, value in newest_sim_times(self.path).items():
            self.newest[recording] = max(self.newest.get(recording, -np.inf), value)
        after = [ui.session.status().sim_time_s for ui in uis]
        newest = [self.newest.get(ui.session_id, -np.inf) for ui in uis]
        low = max(t - n for t, n in zip(before, newest, strict=True))
        high = max(t - n for t, n in zip(after, newest, strict=True))
        return low, high

    def close(self) -> None:
        self.process.terminate()
        self.process.wait(10.0)


def move(uis: list[ClientUI], t0: float) -> None:
    for k, ui in enumerate(uis):
        plane = ui.session.scene.plane
        ui.session.set_target(plane.to_world(circle_uv(time.perf_counter() - t0 + k)))


def run_once(
    n_tabs: int, args: Args, newest_first: bool = True
) -> tuple[float, float, float, float, float]:
    """Medians [s]: baseline lag (low, high), late viewer's catch-up time, its lag afterwards
    (low, high)."""
    with tempfile.TemporaryDirectory() as tmp, tab_factory() as open_tab:
        folder = Path(tmp)
        with app_factory(folder / "recordings") as make:
            app = make(
                rerun="serve",
                rerun_grpc_port=0,
                rerun_web_port=0,
                rerun_newest_first=newest_first,
            )
            assert app.rerun.grpc_url is not None
            early = Viewer(app.rerun.grpc_url, folder, "early")
            for _ in range(n_tabs):
                open_tab(app, decode=False)
            uis = list(app.wait_for_sessions(n_tabs, 120.0).values())
            t0 = time.perf_counter()
            baseline: list[tuple[float, float]] = []
            while time.perf_counter() - t0 < args.warm_s:
                move(uis, t0)
                time.sleep(0.25)
                if time.perf_counter() - t0 > args.warm_s / 2:
                    baseline.append(early.lag(uis))
            late = Viewer(app.rerun.grpc_url, folder, "late")
            opened = time.perf_counter()
            catch_up = float("inf")
            after: list[tuple[float, float]] = []
            while time.perf_counter() - opened < args.watch_s + 5.0:
                move(uis, t0)
                time.sleep(0.25)
                lag = late.lag(uis)
                if catch_up == float("inf") and lag[1] < CAUGHT_UP_S:
                    catch_up = time.perf_counter() - opened
                elif catch_up < float("inf"):
                    after.append(lag)
                    if time.perf_counter() - opened > catch_up + 5.0:
                        break
                if catch_up == float("inf") and time.perf_counter() - opened > args.watch_s:
                    break
            early.close()
            late.close()
    return (*_medians(baseline), catch_up, *_medians(after))


def _medians(pairs: list[tuple[float, float]]) -> tuple[float, float]:
    finite = [p for p in pairs if np.isfinite(p[1])]
    if not finite:
        return float("inf"), float("inf")
    return statistics.median(p[0] for p in finite), statistics.median(p[1] for p in finite)


def main(args: Args) -> None:
    print(f"live Rerun latency, medians of {args.runs} runs (late viewer after {args.warm_s} s)")
    print("| sessions | proxy | lag, viewer from the start | late viewer: catch-up | lag after |")
    print("|---|---|---|---|---|")
    for n_tabs in (1, 4):
        for newest_first in (True, False):  # the app's setting, and the proxy's default order
            results = [run_once(n_tabs, args, newest_first) for _ in range(args.runs)]
            m = [statistics.median(r[i] for r in results) for i in range(5)]
            order = "newest first" if newest_first else "in order"
            print(
                f"| {n_tabs} | {order} | {m[0]:.2f}..{m[1]:.2f} s | {m[2]:.2f} s "
                f"| {m[3]:.2f}..{m[4]:.2f} s |",
                flush=True,
            )


if __name__ == "__main__":
    main(tyro.cli(Args))
