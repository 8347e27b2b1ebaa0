"""Rerun's gRPC proxy and web viewer as child processes bound to the app's ``--host``.

Rerun 0.41's Python ``serve_grpc`` / ``serve_web_viewer`` listen on every interface and have
no host setting; the bundled ``rerun`` binary does (``--bind``). So ``bt teleop --rerun serve``
starts, each in a process group of its own (stopping the app stops them and nothing else)::

    rerun --serve-web --bind <host> --port <grpc> --web-viewer-port <web>    the web viewer page
    rerun --serve-grpc --bind <host> --port <free> --server-memory-limit <limit>   one per tab

and waits until each of its ports answers. On Linux each child also dies with the app, even when
the app is killed with SIGKILL and cannot stop it: it is started with ``PR_SET_PDEATHSIG``
(SIGTERM when its parent thread ends), from one long-lived spawner thread, since the signal
fires when the *thread* that started the child ends, and tabs open on short-lived threads.
Every tab streams to its *own* proxy
(``rerun+http://<host>:<port>/proxy``), and its link opens the web viewer on that proxy alone:
a proxy sends every recording it holds to every viewer, and the web viewer makes the last
recording that arrives the active one, so one shared proxy opened another tab's recording and
made each viewer replay every tab's backlog (docs/teleop.md, "Live Rerun latency").
"""

from __future__ import annotations

import concurrent.futures
import importlib.util
import logging
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from typing import IO

from bt_pipeline.exceptions import ConfigError
from bt_teleop.proc.child import die_with_parent_hook

__all__ = ["RerunProxy", "free_port", "rerun_binary"]

LOGGER = logging.getLogger("bt.teleop")
START_TIMEOUT_S = 30.0
"""Longest wait for the proxy's gRPC port to answer [s]."""
_SPAWNER = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="bt-rerun-spawner")
"""Starts every child: its one thread lives as long as the app (module doc)."""


def _spawn(command: list[str], log: IO[bytes]) -> subprocess.Popen[bytes]:
    """Popen `command` from the spawner thread (stdout and stderr to `log`)."""

    def start() -> subprocess.Popen[bytes]:
        return subprocess.Popen(  # preexec_fn only calls prctl (above)
            command,
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # its own process group: close() stops it and its children
            preexec_fn=die_with_parent_hook(),
        )

    return _SPAWNER.submit(start).result()


def rerun_binary() -> Path:
    """The ``rerun`` executable bundled with rerun-sdk (package ``rerun_cli``), else on PATH.

    The bundled binary is preferred over ``bin/rerun``, a Python wrapper that would leave the
    real server running when it is stopped.

    Raises:
        ConfigError: No rerun binary found.
    """
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin is not None:
        bundled = Path(spec.origin).parent / "rerun"
        if bundled.is_file() and os.access(bundled, os.X_OK):
            return bundled
    found = shutil.which("rerun")
    if found is None:
        raise ConfigError("no rerun executable found: pip install rerun-sdk, or use --rerun save")
    return Path(found)


def free_port(preferred: int, host: str) -> int:
    """`preferred` if it can be bound on `host`, else a free port there.

    Raises:
        ConfigError: No free port.
    """
    for candidate in (preferred, 0):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
            try:
                probe.bind((host, candidate))
            except OSError:
                continue
            return int(probe.getsockname()[1])
    raise ConfigError(f"no free port for Rerun on {host}")


def url_host(host: str) -> str:
    """The host to put in URLs for a server bound to `host` (loopback for "every interface")."""
    return "127.0.0.1" if host in ("0.0.0.0", "::", "") else host


class RerunProxy:
    """A running ``rerun --serve-web`` (web viewer and proxy) or ``rerun --serve-grpc`` (proxy
    only) child process; :meth:`close` stops it."""

    def __init__(
        self,
        host: str,
        grpc_port: int,
        web_port: int | None,
        memory_limit: str = "256MiB",
        *,
        newest_first: bool = False,
    ) -> None:
        """Start the proxy, and the web viewer unless `web_port` is None, on `host` (preferred
        ports; free ones when busy); `newest_first`: a viewer that connects late gets the
        newest data first.

        Raises:
            ConfigError: No rerun binary, or it did not start within :data:`START_TIMEOUT_S`.
        """
        self.host = host
        self.grpc_port = free_port(grpc_port, host)
        self.web_port: int | None = None
        serve = ["--serve-grpc"]
        if web_port is not None:
            self.web_port = free_port(web_port, host)
            if self.web_port == self.grpc_port:
                self.web_port = free_port(0, host)
            serve = ["--serve-web", "--web-viewer-port", str(self.web_port)]
        self._log = tempfile.TemporaryFile()  # noqa: SIM115  # closed in close()
        command = [
            str(rerun_binary()),
            *serve,
            "--bind",
            host,
            "--port",
            str(self.grpc_port),
            "--server-memory-limit",
            memory_limit,
            *(["--newest-first"] if newest_first else []),
        ]
        self.process = _spawn(command, self._log)
        try:
            self._wait_ready()
        except ConfigError:
            self.close()
            raise

    @property
    def grpc_url(self) -> str:
        """Where sessions stream: ``rerun+http://<host>:<port>/proxy``."""
        return f"rerun+http://{url_host(self.host)}:{self.grpc_port}/proxy"

    @property
    def web_url(self) -> str:
        """The web viewer's page (without a recording).

        Raises:
            ConfigError: This proxy serves no web viewer.
        """
        if self.web_port is None:
            raise ConfigError("this Rerun proxy serves no web viewer (started without web_port)")
        return f"http://{url_host(self.host)}:{self.web_port}/"

    def close(self, timeout_s: float = 5.0) -> None:
        """Stop the child process (SIGTERM, then SIGKILL after `timeout_s` [s])."""
        if self.process.poll() is None:
            try:
                os.killpg(self.process.pid, signal.SIGTERM)
                self.process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait(timeout_s)
            except ProcessLookupError:
                pass
        self._log.close()

    def _wait_ready(self) -> None:
        """Until the gRPC port and, when served, the web viewer's port answer: the rerun binary
        opens the web viewer's port after the proxy's, and a link handed out in between was
        refused (seen under load)."""
        deadline = time.monotonic() + START_TIMEOUT_S
        waiting = [p for p in (self.grpc_port, self.web_port) if p is not None]
        while waiting and time.monotonic() < deadline:
            if self.process.poll() is not None:
                break
            try:
                with socket.create_connection((url_host(self.host), waiting[0]), timeout=0.5):
                    waiting.pop(0)
            except OSError:
                time.sleep(0.1)
        if not waiting:
            return
        self._log.seek(0)
        tail = self._log.read()[-400:].decode("utf-8", "replace").strip()
        raise ConfigError(f"Rerun's proxy did not start on {self.host}:{waiting[0]}: {tail}")
