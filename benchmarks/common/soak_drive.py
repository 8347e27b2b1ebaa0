"""A tab's driver in the soak: what a person does in a tab, through the app's own handles."""

from __future__ import annotations

import threading
import time

import numpy as np

from bt_teleop.testing.harness import circle_uv, guide_uv
from bt_teleop.ui.tab import ClientUI


def drive(
    ui: ClientUI,
    stop: threading.Event,
    seed: int,
    counts: dict[str, int],
    take_s: float,
    discard: bool = False,
    path: str = "guide",
) -> None:
    """Record takes of `take_s`-2 `take_s` seconds (wall time) until `stop`; save each (or, with
    `discard`, press Discard instead). The target follows the guide (`path` "guide": the takes
    pass the take checks, so the library scores each and Clean cleans them, as a careful
    person's) or a circle ("circle": every take flagged incomplete, the soak before 2026-12-03).
    """
    trace = guide_uv if path == "guide" else circle_uv
    rng = np.random.default_rng(seed)
    plane = ui.session.scene.plane
    t0 = time.perf_counter()
    while not stop.is_set():
        ui.controls.record_button.value = True
        ui.wait_idle()
        end = time.perf_counter() + float(rng.uniform(take_s, 2.0 * take_s))
        while time.perf_counter() < end and not stop.is_set():
            ui.session.set_target(plane.to_world(trace(time.perf_counter() - t0)))
            time.sleep(1.0 / 30.0)
        if stop.is_set():
            break
        counts["intended"] += 0 if discard else 1
        (ui.controls.discard_button if discard else ui.controls.save_button).value = True
        ui.wait_idle(30.0)
        time.sleep(float(rng.uniform(0.2, 1.0)))
