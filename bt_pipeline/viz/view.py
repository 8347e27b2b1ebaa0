"""``bt view``: recordings on Rerun's ``time`` timeline, saved, opened or served on localhost.

    PATH... ──read, group by task, score Ũ──▶ TimelineDemo per demo ──log_timeline──▶ .rrd
        --out FILE.rrd : write it (atomically)
        --serve        : ``rerun --serve-web --bind 127.0.0.1 FILE.rrd`` as a child process
        (neither)      : ``rerun FILE.rrd``, the bundled native viewer

Rerun 0.41's Python ``serve_grpc`` / ``serve_web_viewer`` have no bind address, so serving goes
through the bundled ``rerun`` CLI, whose ``--bind`` keeps it on 127.0.0.1.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import signal
import subprocess
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import rerun as rr
import rerun.blueprint as rrb

from bt_pipeline.data.demo import DEFAULT_SAMPLES, demos_from_recording
from bt_pipeline.data.paths import expand_paths
from bt_pipeline.data.recording import read_recordings
from bt_pipeline.data.records import Recording
from bt_pipeline.data.tasks import Task
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.score.utility import score_demos
from bt_pipeline.viz.rerun_timeline import TimelineDemo, log_timeline, timeline_views
from bt_pipeline.viz.rrd import demo_colors, save_rrd

APP_ID = "bt_view"
BIND = "127.0.0.1"
"""The only interface ``bt view --serve`` listens on."""


def view_demos(
    paths: Sequence[str | Path], n_samples: int = DEFAULT_SAMPLES
) -> dict[Task, tuple[Recording, list[TimelineDemo]]]:
    """Every demo under `paths` as timeline demos, grouped by task and scored (Ũ, Eq. 8).

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
        utilities = [s.utility for s in score_demos(views).scores]
        colors = demo_colors(len(items))
        demos = []
        for k, ((rec, name), utility) in enumerate(zip(items, utilities, strict=True)):
            record = rec.demos[name]
            stem = Path(str(rec.path)).stem if rec.path else "memory"
            demos.append(
                TimelineDemo(
                    name=f"{stem}_{name}",
                    group=record.demonstrator,
                    ee_pos=record.ee_pos,
                    timestamps=record.timestamps,
                    color=(int(colors[k][0]), int(colors[k][1]), int(colors[k][2])),
                    utility=utility,
                )
            )
        by_task[task] = (items[0][0], demos)
    return by_task


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
            log_timeline(rec, f"/{task}", recording.plane, demos)

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


def start_server(rrd: Path, port: int, web_port: int) -> subprocess.Popen[bytes]:
    """Serve `rrd` with Rerun's web viewer on 127.0.0.1 only; the caller stops the process."""
    command = [
        rerun_binary(),
        "--serve-web",
        "--bind",
        BIND,
        "--port",
        str(port),
        "--web-viewer-port",
        str(web_port),
        str(rrd),
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


def serve_view(
    paths: Sequence[str | Path], port: int, web_port: int, n_samples: int = DEFAULT_SAMPLES
) -> None:
    """Serve the timeline on http://127.0.0.1:<web_port> until Ctrl-C."""
    with tempfile.TemporaryDirectory(prefix="bt-view-") as tmp:
        rrd = save_view_rrd(paths, Path(tmp) / "view.rrd", n_samples)
        process = start_server(rrd, port, web_port)
        url = f"http://{BIND}:{web_port}/?url=rerun%2Bhttp://{BIND}:{port}/proxy"
        print(url, flush=True)
        try:
            while process.poll() is None:
                time.sleep(0.5)
        finally:
            stop_server(process)


def open_viewer(paths: Sequence[str | Path], n_samples: int = DEFAULT_SAMPLES) -> None:
    """Open the timeline in the bundled native Rerun viewer (returns when it is closed)."""
    with tempfile.TemporaryDirectory(prefix="bt-view-") as tmp:
        rrd = save_view_rrd(paths, Path(tmp) / "view.rrd", n_samples)
        subprocess.run([rerun_binary(), str(rrd)], check=False, stdin=subprocess.DEVNULL)
