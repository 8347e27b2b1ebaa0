"""``bt view``: recordings on Rerun's ``time`` timeline, saved, opened or served on localhost.

    PATH... ──read, group by task, score Ũ──▶ TimelineDemo per demo ──log_timeline──▶ .rrd
        --out FILE.rrd : write it (atomically)
        --serve        : ``rerun --serve-web --bind 127.0.0.1 FILE.rrd`` as a child process
        (neither)      : ``rerun FILE.rrd``, the bundled native viewer (needs a display)

A PATH ending in ``.rrd`` (such as ``bt clean``'s ``<task>.rrd``) is opened or served as it is,
beside the timeline of the other PATHs: ``bt view --serve out/wiping.rrd`` shows a cleaning run
on a machine without a display.

Rerun 0.41's Python ``serve_grpc`` / ``serve_web_viewer`` have no bind address, so serving goes
through the bundled ``rerun`` CLI, whose ``--bind`` keeps it on 127.0.0.1. Its ports are
:data:`SERVE_GRPC_PORT` and :data:`SERVE_WEB_PORT` (free ones when busy), not Rerun's defaults
(9876, 9090): a user's ``rerun FILE`` looks for a viewer on 9876 and would stream into ours.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import signal
import socket
import subprocess
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import rerun as rr
import rerun.blueprint as rrb

from bt_pipeline.data.demo import DEFAULT_SAMPLES, Demo, demos_from_recording
from bt_pipeline.data.moderation import is_excluded
from bt_pipeline.data.paths import expand_paths
from bt_pipeline.data.recording import read_recordings
from bt_pipeline.data.records import INFO_FLAGS, Recording
from bt_pipeline.data.tasks import Task
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.viz.demo_style import (
    demo_color,
    display_name,
    legend_markdown,
    palette_index,
    unique_names,
)
from bt_pipeline.viz.rerun_timeline import TimelineDemo, log_timeline, timeline_views
from bt_pipeline.viz.rrd import save_rrd

APP_ID = "bt_view"
BIND = "127.0.0.1"
"""The only interface ``bt view --serve`` listens on."""
SERVE_GRPC_PORT = 9878
"""Preferred gRPC port of ``bt view --serve`` (not Rerun's 9876, nor the app's 9877)."""
SERVE_WEB_PORT = 9092
"""Preferred web viewer port of ``bt view --serve`` (not Rerun's 9090, nor the app's 9091)."""
RRD_SUFFIX = ".rrd"


def view_demos(
    paths: Sequence[str | Path], n_samples: int = DEFAULT_SAMPLES
) -> dict[Task, tuple[Recording, list[TimelineDemo]]]:
    """Every demo under `paths` as timeline demos, grouped by task and scored (Ũ, Eq. 8).

    Demos are named as the web app's page names them (who and when); a cleaned demo (attr
    ``cleaned_from``) is named as its raw demo plus ``_cleaned`` and shares its colour.

    Raises:
        RecordingError: A path matches nothing or a file breaks format v1 (named).
    """
    by_task: dict[Task, tuple[Recording, list[TimelineDemo]]] = {}
    pending: dict[Task, list[tuple[Recording, str]]] = {}
    for recording in read_recordings(expand_paths(paths), strict=True):
        for name in recording.demos:
            pending.setdefault(recording.task, []).append((recording, name))
    for task, items in pending.items():
        views = [
            next(
                d
                for d in demos_from_recording(rec, n_samples, file=str(rec.path or ""))
                if d.name == name
            )
            for rec, name in items
        ]
        utilities, best, reason = view_utilities(items, views)
        bases = [_base_name(rec, name) for rec, name in items]
        cleaned = [_is_cleaned(rec, name) for rec, name in items]
        hue = {base: k for k, base in enumerate(dict.fromkeys(bases))}  # raw and cleaned share it
        suffixed = zip(bases, ["_cleaned" if c else "" for c in cleaned], strict=True)
        names = unique_names(base + suffix for base, suffix in suffixed)
        demos = []
        for k, ((rec, name), utility) in enumerate(zip(items, utilities, strict=True)):
            record = rec.demos[name]
            demos.append(
                TimelineDemo(
                    name=names[k],
                    group=record.demonstrator,
                    ee_pos=record.ee_pos,
                    timestamps=record.timestamps,
                    color=demo_color(hue[bases[k]]),
                    utility=utility,
                    cleaned=cleaned[k],
                    best=k == best,
                    best_reason=reason if k == best else "",
                )
            )
        by_task[task] = (items[0][0], demos)
    return by_task


def view_utilities(
    items: Sequence[tuple[Recording, str]], views: Sequence[Demo]
) -> tuple[list[float | None], int | None, str]:
    """Each demo's Ũ as ``bt score`` and ``bt clean`` show it, the best demo and why it is.

    The raw demos that ``bt score`` ranks (neither flagged nor in an excluded file) are scored
    together by :func:`~bt_pipeline.clean.skipping.select_skipping`, the function ``bt score``
    calls; a cleaned demo shows the Ũ ``bt clean`` gave it (attr ``utility_cleaned``: against
    its raw set's scale); flagged, excluded and unscorable demos have none.

    Args:
        items: (recording, demo name) of each demo of one task.
        views: The same demos as pipeline demos (N samples), in the same order.

    Returns:
        Ũ per demo (None: not scored), the index of the best demo (None: none), and the line
        saying why it is the best when it is not the highest Ũ (empty otherwise).
    """
    from bt_pipeline.clean.skipping import select_skipping  # the cleaner: only when viewing

    utilities: list[float | None] = [None] * len(items)
    raw: list[int] = []
    for k, (rec, name) in enumerate(items):
        record = rec.demos[name]
        if "cleaned_from" in record.attrs:
            value = record.attrs.get("utility_cleaned")
            utilities[k] = None if value is None else float(value)
        elif not (set(record.flags) - set(INFO_FLAGS)) and not (
            rec.path is not None and is_excluded(rec.path)
        ):
            raw.append(k)
    if not raw:
        return utilities, None, ""
    selection, _ = select_skipping([views[k] for k in raw])
    if selection is None:
        return utilities, None, ""
    by_label = {views[k].label: k for k in raw}
    for score in selection.scores.scores:
        utilities[by_label[score.demo.label]] = score.utility
    best = by_label[selection.scores.best.demo.label]
    return utilities, best, selection.best_reason


def _is_cleaned(recording: Recording, name: str) -> bool:
    return "cleaned_from" in recording.demos[name].attrs


def _base_name(recording: Recording, name: str) -> str:
    """The demo's display name; a cleaned demo's is its raw demo's (``cleaned_from``)."""
    record = recording.demos[name]
    file, demo = str(recording.path or ""), name
    source = record.attrs.get("cleaned_from")
    if isinstance(source, str) and ":" in source:
        file, demo = source.rsplit(":", 1)
    return display_name(record.demonstrator, record.created, file, demo)


def view_legend(demos: Sequence[TimelineDemo]) -> str:
    """The legend of one task's timeline: each demo's colour and name."""
    return legend_markdown(
        [d.name for d in demos],
        cleaned=any(d.cleaned for d in demos),
        color_indices=[palette_index(d.color) for d in demos],
    )


def save_view_rrd(
    paths: Sequence[str | Path], out: str | Path, n_samples: int = DEFAULT_SAMPLES
) -> Path:
    """Write the timeline of every demo under `paths` to `out` (.rrd), atomically.

    Raises:
        ConfigError: `out` does not end in .rrd.
    """
    out = Path(out)
    if out.suffix != ".rrd":
        raise ConfigError(f"--out must end in .rrd; got {out}")
    tasks = view_demos(paths, n_samples)
    key = "|".join(f"{t}:{len(d)}" for t, (_, d) in tasks.items())

    def log(rec: rr.RecordingStream) -> None:
        for task, (recording, demos) in tasks.items():
            log_timeline(rec, f"/{task}", recording.plane, demos, view_legend(demos))

    return save_rrd(
        out,
        app_id=APP_ID,
        recording_id=hashlib.sha256(key.encode()).hexdigest()[:16],
        name="bt view",
        blueprint=rrb.Blueprint(
            rrb.Tabs(*(timeline_views(f"/{task}", task) for task in tasks)),
            rrb.TimePanel(timeline="time", expanded=True),
            collapse_panels=False,
        ),
        log=log,
        disabled_hint="write with RERUN unset",
    )


def rerun_binary() -> str:
    """The ``rerun`` executable bundled with rerun-sdk (package ``rerun_cli``).

    The real binary, not the ``bin/rerun`` Python wrapper: stopping the wrapper would leave its
    child, the server, running.
    """
    import rerun_cli

    candidate = Path(rerun_cli.__file__).with_name("rerun")
    return str(candidate) if candidate.exists() else "rerun"


def split_rrd(paths: Sequence[str | Path]) -> tuple[list[Path], list[str | Path]]:
    """`paths` split into Rerun files (ending in .rrd, shown as they are) and recordings.

    Raises:
        ConfigError: An .rrd file does not exist.
    """
    rrds = [Path(p) for p in paths if str(p).endswith(RRD_SUFFIX)]
    for rrd in rrds:
        if not rrd.is_file():
            raise ConfigError(f"no Rerun file at {str(rrd)!r}")
    return rrds, [p for p in paths if not str(p).endswith(RRD_SUFFIX)]


def free_port(preferred: int) -> int:
    """`preferred` if it can be bound on 127.0.0.1, else a free port there."""
    for candidate in (preferred, 0):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
            try:
                probe.bind((BIND, candidate))
            except OSError:
                continue
            return int(probe.getsockname()[1])
    raise ConfigError(f"no free port on {BIND} for bt view --serve")


def start_server(rrd: Path | Sequence[Path], port: int, web_port: int) -> subprocess.Popen[bytes]:
    """Serve `rrd` (one file or several) with Rerun's web viewer on 127.0.0.1 only; the caller
    stops the process."""
    files = [rrd] if isinstance(rrd, Path) else list(rrd)
    command = [
        rerun_binary(),
        "--serve-web",
        "--bind",
        BIND,
        "--port",
        str(port),
        "--web-viewer-port",
        str(web_port),
        *(str(f) for f in files),
    ]
    # Own process group: stop_server ends the server and anything it started, nothing else.
    return subprocess.Popen(command, stdin=subprocess.DEVNULL, start_new_session=True)


def stop_server(process: subprocess.Popen[bytes]) -> None:
    """Stop a server from :func:`start_server` (its whole process group) and reap it."""
    if process.poll() is None:
        with contextlib.suppress(ProcessLookupError):  # ended on its own meanwhile
            os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


def _view_files(paths: Sequence[str | Path], tmp: str, n_samples: int) -> list[Path]:
    """The .rrd files among `paths`, then the timeline of the other paths (if any) in `tmp`."""
    rrds, recordings = split_rrd(paths)
    if recordings:
        rrds.append(save_view_rrd(recordings, Path(tmp) / "view.rrd", n_samples))
    return rrds


def serve_view(
    paths: Sequence[str | Path],
    port: int = SERVE_GRPC_PORT,
    web_port: int = SERVE_WEB_PORT,
    n_samples: int = DEFAULT_SAMPLES,
) -> None:
    """Serve the timeline (and any .rrd among `paths`) on http://127.0.0.1:<web_port> until
    Ctrl-C or SIGTERM (either stops the server too); busy ports are replaced by free ones (the
    printed URL has the real ones)."""
    with tempfile.TemporaryDirectory(prefix="bt-view-") as tmp:
        files = _view_files(paths, tmp, n_samples)
        port = free_port(port)
        web_port = free_port(web_port)
        if web_port == port:
            web_port = free_port(0)
        process = start_server(files, port, web_port)
        url = f"http://{BIND}:{web_port}/?url=rerun%2Bhttp://{BIND}:{port}/proxy"
        print(url, flush=True)
        # SIGTERM's default would end this process without the `finally`, leaving the server
        # (its own process group) running: raise instead, so it is stopped.
        previous = None
        if threading.current_thread() is threading.main_thread():
            previous = signal.signal(signal.SIGTERM, _exit_on_signal)
        try:
            while process.poll() is None:
                time.sleep(0.5)
        finally:
            stop_server(process)
            if previous is not None:
                signal.signal(signal.SIGTERM, previous)


def _exit_on_signal(signum: int, frame: object) -> None:
    raise SystemExit(128 + signum)


def open_viewer(paths: Sequence[str | Path], n_samples: int = DEFAULT_SAMPLES) -> None:
    """Open the timeline (and any .rrd among `paths`) in the bundled native Rerun viewer
    (returns when it is closed; needs a display: use :func:`serve_view` without one)."""
    with tempfile.TemporaryDirectory(prefix="bt-view-") as tmp:
        files = [str(f) for f in _view_files(paths, tmp, n_samples)]
        subprocess.run([rerun_binary(), *files], check=False, stdin=subprocess.DEVNULL)
