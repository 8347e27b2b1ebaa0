"""bt view: demos on a time timeline in an .rrd; --serve binds 127.0.0.1 only; CLI polish."""

from __future__ import annotations

import contextlib
import dataclasses
import socket
import time
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

from bt_pipeline.cli import commands, main
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.viz import view as view_module
from bt_pipeline.viz.demo_style import display_name
from bt_pipeline.viz.view import (
    BIND,
    SERVE_GRPC_PORT,
    SERVE_WEB_PORT,
    save_view_rrd,
    serve_view,
    split_rrd,
    start_server,
    stop_server,
)

REPO = Path(__file__).resolve().parents[3]
TAKES = REPO.parent / "shared/data/browser-takes"


def _entities(path: Path) -> dict[str, list]:
    out: dict[str, list] = {}
    for chunk in RrdReader(path).store().stream().to_chunks():
        out.setdefault(chunk.entity_path, []).append(chunk)
    return out


def test_one_entity_per_demo_on_the_time_timeline(tmp_path, write_example_file) -> None:
    src = write_example_file(tmp_path, n_demos=3, n_samples=40)
    rrd = save_view_rrd([src], tmp_path / "view.rrd")
    chunks = _entities(rrd)
    for k in range(3):
        group = "person_0" if k % 2 == 0 else "person_1"
        name = display_name(group, None, str(src), f"demo_{k}")  # no created attr: file, demo
        assert name == f"{group}_example_demo_{k}"
        for kind in ("world", "plane"):
            ee = chunks[f"/wiping/{kind}/{group}/{name}/ee"]
            temporal = [c for c in ee if not c.is_static]
            assert temporal, "the end effector must move on a timeline"
            batch = temporal[0].to_record_batch()
            assert "time" in batch.schema.names
            times = np.asarray(batch.column("time").cast("int64").to_pylist())  # [ns]
            assert len(times) == 40 and times[0] == 0 and np.all(np.diff(times) > 0)
        assert f"/wiping/world/{group}/{name}/path" in chunks
    assert "/wiping/world/task_plane" in chunks and "/wiping/scores/utility" in chunks


@pytest.mark.skipif(not TAKES.is_dir(), reason="../shared/data/browser-takes not beside the repo")
def test_real_takes_with_hostile_names_are_escaped(tmp_path) -> None:
    rrd = save_view_rrd([TAKES / "wiping"], tmp_path / "takes.rrd")
    chunks = _entities(rrd)
    assert all("<" not in e and ">" not in e for e in chunks)
    [table] = chunks["/wiping/scores/table"]
    text = str(table.to_record_batch().to_pylist())
    assert "<script" not in text.lower() and "&lt;script" in text.lower()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind((BIND, 0))
        return int(s.getsockname()[1])


def _outside_address() -> str | None:
    """This machine's address on a non-loopback interface, if it has one."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("10.255.255.255", 1))  # UDP: picks a route, sends nothing
            address = s.getsockname()[0]
        except OSError:
            return None
    return None if address.startswith("127.") else address


def _accepts(address: str, port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(2.0)
        return s.connect_ex((address, port)) == 0


@pytest.mark.skipif(_outside_address() is None, reason="no non-loopback interface to test from")
def test_serve_binds_loopback_only(tmp_path, write_example_file) -> None:
    rrd = save_view_rrd([write_example_file(tmp_path, n_demos=2)], tmp_path / "v.rrd")
    port, web_port = _free_port(), _free_port()
    outside = _outside_address()
    assert outside is not None
    process = start_server(rrd, port, web_port)
    try:
        for _ in range(300):  # wait until both servers are up (a wait, not a timing assertion)
            if _accepts(BIND, port) and _accepts(BIND, web_port):
                break
            assert process.poll() is None, "rerun exited early"
            time.sleep(0.1)
        assert _accepts(BIND, port) and _accepts(BIND, web_port)
        assert not _accepts(outside, port) and not _accepts(outside, web_port)
    finally:
        stop_server(process)
    assert not _accepts(BIND, port)  # stopped: nothing left listening


def test_version_flag(capsys) -> None:
    main(["--version"])
    assert capsys.readouterr().out.startswith("bt ")


@pytest.mark.parametrize("command", sorted(commands()))
def test_help_never_shows_an_empty_default(command: str, capsys, monkeypatch) -> None:
    monkeypatch.setenv("COLUMNS", "200")
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = capsys.readouterr().out
    assert "--help" in text and "(default: )" not in text


def test_missing_paths_is_one_clear_error(capsys) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["view"])
    assert exit_info.value.code == 2
    assert "give at least one PATH" in capsys.readouterr().err


def test_a_task_without_a_guide_is_viewed(capsys, tmp_path) -> None:
    from tests.conftest import run
    from tests.pipeline.conftest import write_stirring_file

    src = write_stirring_file(tmp_path, n_demos=3, n_samples=40)
    rrd = tmp_path / "x.rrd"
    code, out, err = run(capsys, "view", str(src), "--out", str(rrd))
    assert code == 0, err
    assert out.strip() == str(rrd)
    chunks = _entities(rrd)
    for k in range(3):
        group = "person_0" if k % 2 == 0 else "person_1"
        name = display_name(group, None, str(src), f"demo_{k}")
        assert f"/stirring/world/{group}/{name}/ee" in chunks
        assert f"/stirring/plane/{group}/{name}/ee" in chunks
    assert "/stirring/world/task_plane" in chunks and "/stirring/scores/utility" in chunks


def _column(chunks: list, column: str) -> list:
    values = []
    for chunk in chunks:
        batch = chunk.to_record_batch()
        if column in batch.schema.names:
            values.extend(batch.column(column).to_pylist())
    return values


def test_a_cleaned_demo_is_named_and_coloured_as_its_raw_demo_and_drawn_wider(
    tmp_path, make_recording
) -> None:
    """Raw and cleaned files viewed together: each demo named who and when (created attrs),
    one colour per demo shared by its raw and cleaned paths, the cleaned path wider and in the
    full colour, and a legend naming each."""
    from bt_pipeline.data.recording import write_recording

    raw = make_recording(n_demos=2, n_samples=40, optional=True)
    src = write_recording(tmp_path / "takes.hdf5", raw)
    cleaned_demos = {
        name: dataclasses.replace(d, attrs={"cleaned_from": f"{src}:{name}"})
        for name, d in raw.demos.items()
    }
    out = write_recording(
        tmp_path / "wiping.cleaned.hdf5", dataclasses.replace(raw, demos=cleaned_demos)
    )
    chunks = _entities(save_view_rrd([src, out], tmp_path / "view.rrd"))
    colours: dict[str, tuple[int, ...]] = {}
    for k in range(2):
        group, base = f"person_{k % 2}", f"person_{k % 2}_01-0{k + 1}_100000"
        paths = {
            kind: chunks[f"/wiping/plane/{group}/{base}{suffix}/path"]
            for kind, suffix in (("raw", ""), ("cleaned", "_cleaned"))
        }
        rgba = {
            kind: _column(c, "LineStrips2D:colors")[0][0].to_bytes(4, "big")
            for kind, c in paths.items()
        }
        radius = {kind: abs(_column(c, "LineStrips2D:radii")[0][0]) for kind, c in paths.items()}
        assert radius["cleaned"] > radius["raw"]
        assert rgba["cleaned"][3] == 255 and sum(rgba["raw"][:3]) > sum(rgba["cleaned"][:3])
        colours[base] = tuple(rgba["cleaned"][:3])
    assert len(set(colours.values())) == 2  # one colour per demo
    [legend] = _column(chunks["/wiping/legend"], "TextDocument:text")
    assert all(f"`{base}`" in legend[0] and f"`{base}_cleaned`" in legend[0] for base in colours)


def test_rrd_paths_are_split_from_recordings(tmp_path) -> None:
    rrd = tmp_path / "wiping.rrd"
    rrd.write_bytes(b"")
    assert split_rrd([str(rrd), "recordings"]) == ([rrd], ["recordings"])
    with pytest.raises(ConfigError, match="no Rerun file"):
        split_rrd([str(tmp_path / "missing.rrd")])


def test_view_out_refuses_an_rrd_input(capsys, tmp_path) -> None:
    from tests.conftest import run

    rrd = tmp_path / "wiping.rrd"
    rrd.write_bytes(b"")
    code, _, err = run(capsys, "view", str(rrd), "--out", str(tmp_path / "x.rrd"))
    assert code == 2 and "is a Rerun file" in err


def test_serve_avoids_reruns_default_ports_and_busy_ones(
    tmp_path, write_example_file, monkeypatch, capsys
) -> None:
    """``bt view --serve`` never takes 9876 (where ``rerun FILE`` looks for a viewer) by
    default, moves off a busy port, and serves an .rrd path as it is beside the timeline."""
    assert {SERVE_GRPC_PORT, SERVE_WEB_PORT}.isdisjoint({9876, 9090, 9877, 9091})
    started: list[list[str]] = []

    class Exited:
        pid = -1

        def poll(self) -> int:
            return 0

    def fake_start(files, port, web_port):
        started.append([*(str(f) for f in files), str(port), str(web_port)])
        return Exited()

    monkeypatch.setattr(view_module, "start_server", fake_start)
    src = write_example_file(tmp_path, n_demos=2)
    rrd = save_view_rrd([src], tmp_path / "given.rrd")
    with socket.socket() as busy:
        with contextlib.suppress(OSError):  # something else holds it: busy all the same
            busy.bind((BIND, SERVE_GRPC_PORT))
        busy.listen()
        serve_view([str(rrd), str(src)])
    [command] = started
    assert command[0] == str(rrd) and command[1].endswith("view.rrd")
    port, web_port = int(command[2]), int(command[3])
    assert port != SERVE_GRPC_PORT and port not in (9876, 9090) and web_port != port
    url = capsys.readouterr().out.strip()
    assert url == f"http://{BIND}:{web_port}/?url=rerun%2Bhttp://{BIND}:{port}/proxy"


def test_sigterm_of_bt_view_serve_stops_its_server(tmp_path, write_example_file) -> None:
    """The server runs in a process group of its own: a SIGTERM to ``bt view --serve`` must
    still stop it (it was left running, holding its ports)."""
    import signal
    import subprocess
    import sys

    src = write_example_file(tmp_path, n_demos=2)
    command = [sys.executable, "-m", "bt_pipeline", "view", "--serve", str(src)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, text=True)
    try:
        assert process.stdout is not None
        url = process.stdout.readline().strip()
        web_port = int(url.split(":")[2].split("/")[0])
        port = int(url.rsplit(":", 1)[1].split("/")[0])
        for _ in range(300):  # wait until both servers are up (a wait, not a timing assertion)
            if _accepts(BIND, port) and _accepts(BIND, web_port):
                break
            time.sleep(0.1)
        assert _accepts(BIND, port) and _accepts(BIND, web_port)
        process.send_signal(signal.SIGTERM)
        process.wait(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
    assert not _accepts(BIND, port) and not _accepts(BIND, web_port)
