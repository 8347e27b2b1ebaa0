"""The test harness of the teleop app, shared by ``tests/`` and ``benchmarks/``.

::

    app_factory(recordings) -> make(**AppOptions overrides) -> TeleopApp   (all stopped on exit)
    tab_factory() -> open_tab(app) -> FakeTab      a raw viser websocket client (closed on exit)
    chromium_page() -> Playwright Page             Debian's headless Chromium, software WebGL
    open_tab(page, app) -> ClientUI                load the app in a page; the tab's session
    type_name(page, ui, name)                      type the demonstrator's name in the page
    record_in_page(page, ui, trace, seconds)       Record, move the target, Stop & save: the file
    wait_until(condition, timeout_s, what)         poll until truthy; TimeoutError otherwise
    circle_uv(t_s)                                 a reachable circle in task-plane coordinates
    reachable(root)                                every object a record holds (memory checks)
    synthetic_task_files(root, task, n)            n takes on disk as the library loader caches them

:class:`FakeTab` is a browser tab as the server sees it: it connects with viser's protocol
version, sends the first camera message (what makes viser call ``on_client_connect``), reads
(and, unless told not to, decodes) everything the server sends, and closes like a tab.
Playwright is imported only by :func:`chromium_page` (a dev dependency; never
``playwright install``: it drives Debian's ``/usr/bin/chromium``).
"""

from __future__ import annotations

import functools
import math
import threading
import time
import types
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec
import numpy as np
import viser
import zstandard
from websockets.sync.client import connect

from bt_pipeline.data.records import FloatArray
from bt_teleop.app import AppOptions, TeleopApp, start_app

if TYPE_CHECKING:
    from playwright.sync_api import Page, ViewportSize

    from bt_teleop.ui.tab import ClientUI

__all__ = [
    "CAMERA_MESSAGE",
    "CHROMIUM",
    "CHROMIUM_ARGS",
    "VIEWPORT",
    "FakeTab",
    "app_factory",
    "chromium_page",
    "circle_uv",
    "decode_frame",
    "guide_script",
    "guide_uv",
    "open_tab",
    "reachable",
    "record_in_page",
    "shared_dir",
    "synthetic_task_files",
    "tab_factory",
    "type_name",
    "wait_until",
]

CAMERA_MESSAGE: dict[str, Any] = {
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
"""The first message a viser page sends (its camera); the server then calls on_client_connect."""
CHROMIUM = Path("/usr/bin/chromium")
"""Debian's Chromium (``apt-get install -y chromium``, as ``.ci/run`` does)."""
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
"""Flags from integration-facts; Playwright adds a fresh temporary --user-data-dir itself."""
VIEWPORT: ViewportSize = {"width": 1000, "height": 700}
"""Page size [px] of :func:`chromium_page`."""


def decode_frame(frame: bytes, decompressor: zstandard.ZstdDecompressor) -> list[dict[str, Any]]:
    """The messages of one websocket frame viser sent (sizes, zstd, msgpack)."""
    size = int.from_bytes(frame[:8], "little")
    compressed = int.from_bytes(frame[8:16], "little")
    payload = decompressor.decompress(frame[16 : 16 + compressed], max_output_size=size)
    return msgspec.msgpack.decode(payload)["messages"]


class FakeTab:
    """A browser tab as the server sees it: a viser websocket client that reads everything."""

    def __init__(self, port: int, *, decode: bool = True) -> None:
        """Connect to the app on `port`; keep the decoded messages when `decode` (else only
        count the bytes, which costs the benchmarks no CPU)."""
        self.ws = connect(
            f"ws://127.0.0.1:{port}",
            subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]
            max_size=None,
        )
        self.decode = decode
        self.messages: list[dict[str, Any]] = []
        """Every message received (when decoding)."""
        self.bytes = 0
        """Bytes received so far."""
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()
        self.ws.send(msgspec.msgpack.encode(CAMERA_MESSAGE))

    def _read(self) -> None:
        decompressor = zstandard.ZstdDecompressor()
        try:
            for frame in self.ws:
                assert isinstance(frame, bytes)
                self.bytes += len(frame)
                if self.decode:
                    self.messages.extend(decode_frame(frame, decompressor))
        except Exception:  # closed
            return

    def text(self) -> str:
        """Every message received, as text (to look for strings)."""
        return " ".join(str(m) for m in list(self.messages))

    def close(self) -> None:
        """Close like a tab."""
        self.ws.close()
        self._thread.join(5.0)


@contextmanager
def tab_factory() -> Iterator[Callable[..., FakeTab]]:
    """``open_tab(app, decode=True)`` opens a :class:`FakeTab` on `app`; all closed on exit."""
    opened: list[FakeTab] = []

    def open_tab(app: TeleopApp, *, decode: bool = True) -> FakeTab:
        tab = FakeTab(app.port, decode=decode)
        opened.append(tab)
        return tab

    try:
        yield open_tab
    finally:
        for tab in opened:
            tab.close()


@contextmanager
def app_factory(recordings: Path) -> Iterator[Callable[..., TeleopApp]]:
    """``make(**overrides)`` starts an app on a free port, recording under `recordings`, with
    Rerun off and 2 clean epochs unless overridden; every app is stopped on exit."""
    apps: list[TeleopApp] = []

    def make(**overrides: Any) -> TeleopApp:
        defaults: dict[str, Any] = {
            "port": 0,
            "recordings": recordings,
            "rerun": "off",
            "clean_epochs": 2,
        }
        app = start_app(AppOptions(**(defaults | overrides)))
        apps.append(app)
        return app

    try:
        yield make
    finally:
        for app in apps:
            app.stop()


@contextmanager
def chromium_page(
    viewport: ViewportSize = VIEWPORT, timeout_ms: float | None = None
) -> Iterator[Page]:
    """A page in headless Chromium (:data:`CHROMIUM` with :data:`CHROMIUM_ARGS`).

    Args:
        viewport: Page size [px].
        timeout_ms: Playwright's default timeout of the page [ms]; its own when None.

    Raises:
        FileNotFoundError: Chromium is not installed (the message says how to install it).
    """
    from playwright.sync_api import sync_playwright

    if not CHROMIUM.is_file():
        raise FileNotFoundError(
            f"{CHROMIUM} is missing: apt-get install -y chromium (as .ci/run does)"
        )
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(
            executable_path=str(CHROMIUM), args=CHROMIUM_ARGS, headless=True
        )
        try:
            page = browser.new_page(viewport=viewport)
            if timeout_ms is not None:
                page.set_default_timeout(timeout_ms)
            yield page
        finally:
            browser.close()


def open_tab(page: Page, app: TeleopApp, timeout_s: float = 90.0) -> ClientUI:
    """Load `app` in `page` until its Record button shows; the new tab's session."""
    from playwright.sync_api import expect

    before = set(app.sessions())
    page.goto(app.url, wait_until="commit")
    record = page.get_by_role("button", name="Record", exact=True)
    expect(record).to_be_visible(timeout=1e3 * timeout_s)
    uis = app.wait_for_sessions(len(before) + 1, 60.0)
    (ui,) = [ui for cid, ui in uis.items() if cid not in before]
    return ui


def type_name(page: Page, ui: ClientUI, name: str) -> None:
    """Type `name` as the demonstrator in `page` (tab `ui`) and wait until the app has it."""
    box = page.locator("xpath=//p[normalize-space(.)='Demonstrator']/following::input[1]")
    box.fill(name)
    box.press("Enter")
    wait_until(lambda: ui.controls.name_input.value == name, 30.0, "the name to arrive")


def record_in_page(
    page: Page, ui: ClientUI, trace: Callable[[float], FloatArray] | None, seconds: float = 5.0
) -> Path:
    """A take through the page's buttons: Record, then for `seconds` [s] of simulation the
    target follows `trace` (t [s] -> (u, v) [m] on the task plane, as a drag of the gizmo sets
    it; None: no motion), then Stop & save; the saved file.

    Raises:
        TimeoutError: The take did not start or was not saved (a refusal is in ``ui.messages``).
    """
    saved = len(ui.saved)
    page.get_by_role("button", name="Record", exact=True).click()
    wait_until(lambda: ui.session.recording, 30.0, "the recording to start")
    start_s = ui.session.status().sim_time_s
    plane = ui.session.scene.plane

    def moved() -> bool:
        t_s = ui.session.status().sim_time_s - start_s
        if trace is not None:
            ui.session.set_target(plane.to_world(trace(t_s)))
        return t_s >= seconds

    if trace is not None:
        wait_until(moved, 60.0 + 10.0 * seconds, "the take to be recorded", poll_s=0.01)
    page.get_by_role("button", name="Stop & save", exact=True).click()
    return wait_until(lambda: len(ui.saved) > saved and ui.saved[-1], 30.0, "the take's file")


def wait_until(
    condition: Callable[[], Any], timeout_s: float = 30.0, what: str = "", poll_s: float = 0.02
) -> Any:
    """Poll `condition` every `poll_s` [s] until it is truthy; its value.

    Raises:
        TimeoutError: Not truthy after `timeout_s` [s] (the message names `what`).
    """
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(poll_s)
    raise TimeoutError(f"timed out after {timeout_s} s waiting for {what or condition}")


def guide_script(
    name: str, theta_deg: float = 0.0, rho: float = 1.0, seconds: float = 3.0
) -> dict[str, Any]:
    """The scripted operator's JSON (:mod:`bt_teleop.session.script`) for a careful wiping take: one
    loop along the guide under (θ [deg], ρ) in `seconds` [s], by demonstrator `name`."""
    from bt_pipeline.data.shapes import canonical_loop, similarity_transform

    loop = similarity_transform(canonical_loop("wiping", 30), theta_deg, rho)
    times = np.linspace(0.0, seconds, 31)
    return {
        "task": "wiping",
        "demonstrator": name,
        "theta_deg": theta_deg,
        "rho": rho,
        "waypoints": np.column_stack([times, np.vstack([loop, loop[:1]])]).tolist(),
    }


def shared_dir() -> Path:
    """``../shared`` beside the clone (CI), or ``$BT_SHARED_DIR`` when set (a worktree)."""
    import os

    override = os.environ.get("BT_SHARED_DIR")
    return Path(override) if override else Path(__file__).resolve().parents[3] / "shared"


def guide_uv(t_s: float, task: str = "wiping", period_s: float = 4.0) -> FloatArray:
    """The task's guide (its canonical loop at θ = 0, ρ = 1, centred on the plane origin, as
    the page draws it) traced at uniform phase, one loop every `period_s`, at time `t_s` [s]:
    (u, v), shape (2,) [m]. Takes that follow it pass the take checks, as a careful person's."""
    loop = _guide_loop(task)
    position = (t_s / period_s % 1.0) * len(loop)
    k = int(position) % len(loop)
    w = position - int(position)
    return (1.0 - w) * loop[k] + w * loop[(k + 1) % len(loop)]


@functools.cache
def _guide_loop(task: str) -> FloatArray:
    from bt_pipeline.data.shapes import canonical_loop
    from bt_pipeline.data.tasks import parse_guided_task

    return canonical_loop(parse_guided_task(task), 360)


def circle_uv(t_s: float, radius_m: float = 0.06, period_s: float = 4.0) -> FloatArray:
    """A circle from the task plane's origin upwards in v (inside every workspace) at time
    `t_s` [s]: (u, v), shape (2,) [m]."""
    phase = 2.0 * math.pi * t_s / period_s
    return radius_m * np.array([math.sin(phase), 1.0 - math.cos(phase)])


def reachable(root: object) -> Iterator[object]:
    """Every object reachable from `root` through containers and records, each once.

    Follows dict keys and values, list / tuple / set items, and the ``__slots__`` and
    ``__dict__`` attributes of other objects; never classes, modules or functions (they would
    reach the whole program). For checks of what a record holds (e.g. no numpy arrays) and of
    its size (``sys.getsizeof`` summed).
    """
    seen: set[int] = set()
    stack = [root]
    while stack:
        item = stack.pop()
        if id(item) in seen or isinstance(item, type | types.ModuleType | types.FunctionType):
            continue
        seen.add(id(item))
        yield item
        if isinstance(item, dict):
            stack += [*item.keys(), *item.values()]
        elif isinstance(item, list | tuple | set | frozenset):
            stack += list(item)
        elif not isinstance(item, str | bytes | int | float | np.ndarray):
            names = [n for cls in type(item).__mro__ for n in getattr(cls, "__slots__", ())]
            stack += [getattr(item, n) for n in names if hasattr(item, n)]
            stack += list(getattr(item, "__dict__", {}).values())


def synthetic_task_files(root: Path, task: str, n: int, seed: int = 0) -> dict[Path, Any]:
    """`n` takes of `task` under `root`, as the library loader's cache holds them.

    The files are empty (no HDF5 is written: thousands of takes in a second); each has one
    demo, saved a second after the one before (its mtime), by one of 8 demonstrators, with
    random ranking inputs. Returns file -> :class:`~bt_teleop.library.tracks.FileTracks`, to serve
    as ``load_library(root, task, read=lambda path, kind: files[path])``.
    """
    import os

    from bt_pipeline.clean.selection import TakeScore
    from bt_pipeline.score.utility import RawMetrics
    from bt_teleop.library.tracks import FileTracks, ReplayTrack, file_stamp
    from bt_teleop.takes.naming import demo_path

    rng = np.random.default_rng(seed)
    start = 1_795_000_000  # 2026-11-18, seconds since the epoch
    files: dict[Path, Any] = {}
    for i in range(n):
        who = f"tab {i % 8}"
        when = time.gmtime(start + i)
        path = demo_path(root, task, who, _utc(when), suffix=f"{i:06x}")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.touch()
        os.utime(path, ns=((start + i) * 10**9, (start + i) * 10**9))
        stamp = file_stamp(path)
        track = ReplayTrack(
            key=f"raw · {path.stem}",
            kind="raw",
            file=path,
            demo="demo_0",
            stamp=stamp,
            num_samples=300,
            duration_s=3.0,
            demonstrator=who,
            theta_deg=0.0,
            rho=1.0,
        )
        metrics = TakeScore(
            RawMetrics(*(float(v) for v in rng.uniform(0.1, 1.0, 4))), float(rng.uniform(0, 0.01))
        )
        files[path] = FileTracks(path, stamp, task, (track,), (metrics,))  # type: ignore[arg-type]
    return files


def _utc(when: time.struct_time) -> Any:
    from datetime import UTC, datetime

    return datetime(*when[:6], tzinfo=UTC)
