"""``bt teleop``: the viser web app, one session per browser tab.

::

    serve(options)            blocks until Ctrl-C, then stops the app
    start_app(options) -> TeleopApp (.port, .url, .stop()): the same, non-blocking (tests)

    TeleopApp
      viser server (binds options.host, 127.0.0.1 by default)
        on_client_connect  -> slot free? ClientUI(client) : "full, try later" message, then
                              the socket is closed (REFUSED_CLOSE_S later; at once when more
                              than max_sessions refused sockets are still open)
        ConnectionWatch    -> a tab that sends nothing for idle_timeout_s (and is not recording)
                              is told, then closed (bt_teleop/ui/connections.py)
        on_client_disconnect -> ClientUI.close(): a recording in progress is saved flagged
                                incomplete (or discarded: save_incomplete=False)
      shared by the tabs: CleanRunner (one clean job at a time, in a process),
                          RerunHub (live viewer / .rrd files / off),
                          a one-thread executor for loading a task's library, whose files
                          are read and scored in a reader child
                          (bt_teleop/library/reader_process.py)

Stopping closes every tab the same way a closed tab is closed, then stops viser, the clean job,
Rerun's gRPC server, the executor and the reader child.
"""

from __future__ import annotations

import concurrent.futures
import gc
import ipaddress
import logging
import secrets
import signal
import sys
import threading
import time
import warnings

import viser

from bt_pipeline.clean.pipeline import CleanOptions
from bt_teleop.app_options import AppOptions
from bt_teleop.clean.runner import CleanRunner
from bt_teleop.library.loader import LibraryLoader
from bt_teleop.library.reader_process import ReaderProcess
from bt_teleop.library.reading import read_file_tracks
from bt_teleop.proc.native_memory import HeapTrimmer
from bt_teleop.proc.priority import lower_thread_priority
from bt_teleop.rerun.live import RerunHub
from bt_teleop.session.process import start_forkserver
from bt_teleop.ui.connections import ConnectionWatch, loop_safe_wakeups
from bt_teleop.ui.context import TaskVersions, UiContext
from bt_teleop.ui.tab import ClientUI

LOGGER = logging.getLogger("bt.teleop")
CAMERA_POSITION = (1.1, -0.85, 0.7)
"""Where a new tab's camera starts [m]: the FR3 and its table fill the view."""
CAMERA_LOOK_AT = (0.42, 0.0, 0.2)
"""What a new tab's camera looks at [m]."""
REFUSED_CLOSE_S = 2.0
"""How long a refused tab's socket stays open to deliver the "full" message [s]."""
EXPOSED_WARNING = (
    "bt teleop: WARNING: --host {host} exposes the app to every machine that can reach this "
    "one: anyone can record, clean and watch sessions. Use 127.0.0.1 (the default) with an SSH "
    "tunnel, or a reverse proxy with a login in front (docs/security.md)."
)
IDLE_TITLE = "Closed: no activity"
IDLE_BODY = (
    "Nothing happened in this tab for {minutes:g} min, so its robot was closed to free a "
    "place. Reload the page (or click it) to start again."
)
FULL_MESSAGE = (
    "## This teleop server is full\n\n"
    "{n} people are recording right now, the most this server allows. "
    "Please try again later (reload this page)."
)


class TeleopApp:
    """A running teleop server; create it with :func:`start_app`."""

    def __init__(self, options: AppOptions) -> None:
        """Start the server, Rerun (per options) and the shared services."""
        self.options = options
        options.recordings.mkdir(parents=True, exist_ok=True)
        # A tab's worker may publish once more between its socket closing and its close():
        # viser warns about every such message; they are expected and harmless.
        warnings.filterwarnings(
            "ignore", message=r"Queued a \w+ on a closed connection", category=UserWarning
        )
        self._lock = threading.Lock()
        self._uis: dict[int, ClientUI] = {}
        self._pending: set[int] = set()  # tabs being set up (they hold a slot)
        self._departed: set[int] = set()  # tabs that left while being set up
        self._closing: set[ClientUI] = set()  # tabs being closed after a disconnect
        self._refused: set[int] = set()  # refused tabs whose socket is not closed yet
        self._stopping = False
        if options.session_processes:
            start_forkserver()  # it imports MuJoCo and mink while the first tab connects
        self.rerun = RerunHub(
            options.rerun,
            options.recordings,
            host=options.host,
            grpc_port=options.rerun_grpc_port,
            web_port=options.rerun_web_port,
            newest_first=options.rerun_newest_first,
        )
        self.versions = TaskVersions()
        self.cleaner = CleanRunner(
            options.recordings,
            CleanOptions(epochs=options.clean_epochs, write_rrd=options.rerun != "off"),
            processes=options.clean_in_subprocess,
            on_finish=lambda job: self.versions.bump(job.task),
        )
        # Library loads list every take of a task on this thread. With the sessions in processes
        # of their own it runs at nice +10, below their control loops (docs/security.md, "Library
        # loads below the control loops"); with them in this process it must not hold their GIL
        # while waiting for a CPU, so it stays at the app's priority.
        self._background = concurrent.futures.ThreadPoolExecutor(
            1,
            thread_name_prefix="bt-read",
            initializer=lower_thread_priority if options.session_processes else None,
        )
        # Files are read and scored in a child when the sessions are
        # (bt_teleop/library/reader_process.py)
        self.reader = ReaderProcess() if options.session_processes else None
        if self.reader is not None:  # its imports run while the first tab connects
            self._background.submit(self.reader.start)
        self.server = viser.ViserServer(
            host=options.host, port=options.port, label="bt teleop", verbose=False
        )
        self.context = UiContext(
            recordings_dir=options.recordings,
            robot=options.robot,
            cleaner=self.cleaner,
            rerun=self.rerun,
            background=self._background,
            libraries=LibraryLoader(
                options.recordings,
                self._background,
                read_file=self.reader.read if self.reader is not None else read_file_tracks,
            ),
            versions=self.versions,
            session_config=options.session,
            session_processes=options.session_processes,
            publish_hz=options.publish_hz,
            save_incomplete=options.save_incomplete,
            initial_task=options.initial_task,
            listed_demos=options.listed_demos,
            operator_token=options.operator_token,
            fancy_lighting=options.fancy_lighting,
            event_loop=self.server.get_event_loop(),
        )
        self.server.initial_camera.position = CAMERA_POSITION
        self.server.initial_camera.look_at = CAMERA_LOOK_AT
        self.connections = ConnectionWatch(
            self.server, options.idle_timeout_s, busy=self._busy, notify=self._notify_idle
        )
        loop_safe_wakeups(self.server._websock_server.get_message_buffer())  # see ui/connections.py
        self.server.on_client_connect(self._on_connect)
        self.server.on_client_disconnect(self._on_disconnect)
        self.heap_trimmer = HeapTrimmer(options.trim_heap_every_s)

    @property
    def port(self) -> int:
        """The port actually bound."""
        return self.server.get_port()

    @property
    def url(self) -> str:
        """The address to open in a browser."""
        host = self.options.host
        shown = "localhost" if host in ("0.0.0.0", "::", "") else host
        return f"http://{shown}:{self.port}/"

    def sessions(self) -> dict[int, ClientUI]:
        """The tabs with a session, by viser client id."""
        with self._lock:
            return dict(self._uis)

    def settled(self) -> bool:
        """Whether no tab is being set up or closed (its files are final)."""
        with self._lock:
            return not self._pending and not self._closing

    def wait_for_sessions(self, n: int, timeout_s: float = 30.0) -> dict[int, ClientUI]:
        """Wait until `n` tabs have a session (tests); the tabs.

        Raises:
            TimeoutError: Fewer than `n` after `timeout_s` [s].
        """
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            uis = self.sessions()
            if len(uis) >= n:
                return uis
            time.sleep(0.02)
        raise TimeoutError(f"{len(self.sessions())} sessions after {timeout_s} s; expected {n}")

    def stop(self) -> None:
        """Close every tab (incomplete-recording policy), then stop the server and services."""
        with self._lock:
            if self._stopping:
                return
            self._stopping = True
            uis = [*self._uis.values(), *self._closing]
            self._uis.clear()
        self.connections.stop()
        self.heap_trimmer.stop()
        for ui in uis:
            path = ui.close()
            if path is not None:
                LOGGER.info("saved the incomplete recording %s", path)
        self.server.stop()
        self.cleaner.close()
        self.context.libraries.close()  # a load waiting its turn runs now, not later
        self._background.shutdown(wait=True)
        if self.reader is not None:
            self.reader.close()
        self.rerun.close()

    def _on_connect(self, client: viser.ClientHandle) -> None:
        loop_safe_wakeups(client._websock_connection.get_message_buffer())  # before our threads
        self.connections.touch(client.client_id)
        with self._lock:
            full = len(self._uis) + len(self._pending) >= self.options.max_sessions
            if self._stopping or full:
                refused = True
            else:
                refused = False
                self._pending.add(client.client_id)
        if refused:
            self._refuse(client)
            return
        ui: ClientUI | None = None
        try:
            ui = ClientUI(client, self.context, session_id=secrets.token_hex(4))
        except Exception as exc:  # tell the person, keep serving the others
            LOGGER.exception("tab %d: could not start a session", client.client_id)
            client.gui.add_markdown(f"## Could not start a session\n\n{exc}")
        finally:
            with self._lock:
                self._pending.discard(client.client_id)
                gone = client.client_id in self._departed or self._stopping
                self._departed.discard(client.client_id)
                if ui is not None and not gone:
                    self._uis[client.client_id] = ui
        if ui is not None and gone:
            ui.close()
        elif ui is not None:
            LOGGER.info("tab %d: session %s", client.client_id, ui.session_id)

    def refused_open(self) -> int:
        """Refused tabs whose socket is still open (at most ``max_sessions``)."""
        with self._lock:
            return len(self._refused)

    def _refuse(self, client: viser.ClientHandle) -> None:
        """Tell a tab the server is full, then close its socket (bounded: no pile of sockets)."""
        with self._lock:
            crowded = len(self._refused) >= self.options.max_sessions
            self._refused.add(client.client_id)
        LOGGER.info("tab %d refused: %d sessions", client.client_id, self.options.max_sessions)
        if not crowded:
            client.gui.add_markdown(FULL_MESSAGE.format(n=self.options.max_sessions))
        delay = 0.0 if crowded else REFUSED_CLOSE_S
        timer = threading.Timer(delay, self._close_socket, args=(client.client_id,))
        timer.daemon = True
        timer.start()

    def _close_socket(self, client_id: int) -> None:
        """Close a refused client's websocket."""
        if not self.connections.close(client_id, 1013, "server full"):
            with self._lock:
                self._refused.discard(client_id)

    def _busy(self, client_id: int) -> bool:
        """Whether a tab must stay open however long it is silent: being set up, or recording."""
        with self._lock:
            ui = self._uis.get(client_id)
            pending = client_id in self._pending
        return pending or (ui is not None and ui.session.recording)

    def _notify_idle(self, client_id: int) -> None:
        client = self.server.get_clients().get(client_id)
        if client is not None:
            body = IDLE_BODY.format(minutes=round(self.options.idle_timeout_s / 60.0, 1))
            client.add_notification(IDLE_TITLE, body, color="yellow", with_close_button=False)

    def _on_disconnect(self, client: viser.ClientHandle) -> None:
        self.connections.forget(client.client_id)
        with self._lock:
            self._refused.discard(client.client_id)
            ui = self._uis.pop(client.client_id, None)
            if ui is None and client.client_id in self._pending:
                self._departed.add(client.client_id)
            if ui is not None:
                self._closing.add(ui)
        if ui is not None:
            try:
                path = ui.close()
            finally:
                with self._lock:
                    self._closing.discard(ui)
            LOGGER.info(
                "tab %d closed%s",
                client.client_id,
                "" if path is None else f"; saved the incomplete recording {path}",
            )


def start_app(options: AppOptions | None = None) -> TeleopApp:
    """Start the app in background threads and return it (stop it with ``.stop()``).

    A host other than a loopback address prints :data:`EXPOSED_WARNING` on stderr.
    """
    options = options or AppOptions()
    if not is_loopback(options.host):
        print(EXPOSED_WARNING.format(host=options.host), file=sys.stderr, flush=True)
    return TeleopApp(options)


def is_loopback(host: str) -> bool:
    """Whether `host` names this machine only (127.0.0.0/8, ::1, localhost)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def serve(options: AppOptions | None = None) -> None:
    """Run the app until Ctrl-C, printing its address; then close every session cleanly."""
    if threading.current_thread() is threading.main_thread():
        # Ctrl-C and `kill` both stop the app cleanly (a background job may start with SIGINT
        # ignored; SIGTERM would otherwise end the process without settling recordings).
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, _interrupt)
    app = start_app(options)
    freeze_startup_objects()
    print(f"bt teleop: open {app.url}", flush=True)
    if app.rerun.viewer_url is not None:
        print(
            f"bt teleop: Rerun web viewer at {app.rerun.viewer_url} (each tab links to its own "
            "live recording)",
            flush=True,
        )
    print("bt teleop: press Ctrl-C to stop", flush=True)
    try:
        while True:
            time.sleep(3600.0)
    except KeyboardInterrupt:
        print("bt teleop: stopping; recordings in progress are settled", flush=True)
    finally:
        app.stop()


def freeze_startup_objects() -> None:
    """Leave what the app has loaded so far (modules, the scene, the server: ~190,000 objects)
    out of every later garbage collection (``gc.freeze``). A full collection of the app's
    process walked them all: 107-131 ms on the idle machine
    (``benchmarks/teleop/bench_app_gc.py``), a 544 ms pause in a soak, during which the web
    server answered no tab. Objects made later
    (takes, libraries) are collected as before; the frozen ones live as long as the app."""
    gc.collect()
    gc.freeze()


def _interrupt(signum: int, _frame: object) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


__all__ = ["AppOptions", "TeleopApp", "freeze_startup_objects", "serve", "start_app"]
