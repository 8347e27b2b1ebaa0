"""bt view: demos on a time timeline in an .rrd; --serve binds 127.0.0.1 only; CLI polish."""

from __future__ import annotations

import socket
import time
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

from bt_pipeline.cli import COMMANDS, main
from bt_pipeline.viz.rerun_timeline import entity_name
from bt_pipeline.viz.view import BIND, save_view_rrd, start_server, stop_server

REPO = Path(__file__).resolve().parents[1]
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
    stem = entity_name(src.stem)
    for k in range(3):
        group = "person_0" if k % 2 == 0 else "person_1"
        for kind in ("world", "plane"):
            ee = chunks[f"/wiping/{kind}/{group}/{stem}_demo_{k}/ee"]
            temporal = [c for c in ee if not c.is_static]
            assert temporal, "the end effector must move on a timeline"
            batch = temporal[0].to_record_batch()
            assert "time" in batch.schema.names
            times = np.asarray(batch.column("time").cast("int64").to_pylist())  # [ns]
            assert len(times) == 40 and times[0] == 0 and np.all(np.diff(times) > 0)
        assert f"/wiping/world/{group}/{stem}_demo_{k}/path" in chunks
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


@pytest.mark.parametrize("command", sorted(COMMANDS))
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
    from tests.test_cli import run
    from tests.test_tasks import write_stirring_file

    src = write_stirring_file(tmp_path, n_demos=3, n_samples=40)
    rrd = tmp_path / "x.rrd"
    code, out, err = run(capsys, "view", str(src), "--out", str(rrd))
    assert code == 0, err
    assert out.strip() == str(rrd)
    chunks = _entities(rrd)
    stem = entity_name(src.stem)
    for k in range(3):
        group = "person_0" if k % 2 == 0 else "person_1"
        assert f"/stirring/world/{group}/{stem}_demo_{k}/ee" in chunks
        assert f"/stirring/plane/{group}/{stem}_demo_{k}/ee" in chunks
    assert "/stirring/world/task_plane" in chunks and "/stirring/scores/utility" in chunks
