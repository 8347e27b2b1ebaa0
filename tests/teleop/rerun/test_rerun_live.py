"""bt_teleop.rerun.live: saved demos named and coloured as the page shows them, with a legend;
the app's Rerun servers off the ports a user's ``rerun FILE`` looks at."""

from __future__ import annotations

import socket
from pathlib import Path

import numpy as np
import psutil
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from bt_teleop.app_options import AppOptions
from bt_teleop.rerun.live import RerunHub, SessionLogger

RERUN_DEFAULT_PORTS = {9876, 9090}
"""Where ``rerun FILE`` looks for a running viewer (gRPC) and ``--web-viewer`` serves."""


def _static(path: Path) -> dict[str, dict[str, list]]:
    """Each entity's static columns, read back from an .rrd."""
    out: dict[str, dict[str, list]] = {}
    for chunk in RrdReader(path).store().stream().to_chunks():
        batch = chunk.to_record_batch()
        columns = out.setdefault(chunk.entity_path, {})
        for name in batch.schema.names:
            columns.setdefault(name, []).extend(batch.column(name).to_pylist())
    return out


def test_saved_demos_are_named_who_and_when_each_in_its_colour_with_a_legend(
    tmp_path: Path,
) -> None:
    rrd = tmp_path / "session.rrd"
    rec = rr.RecordingStream("bt_test", recording_id="names", send_properties=False)
    rec.set_log_time_enabled(False)
    rec.save(rrd)
    logger = SessionLogger(rec)
    path = np.column_stack([np.linspace(0.3, 0.5, 20), np.zeros(20), np.full(20, 0.3)])
    stems = (
        "alice_20261206T120301Z_3fa2c1",
        "alice_20261206T120301Z_0b1c2d",  # the same second: named apart
        "bob_20261206T121000Z_00ff00",
        "..-x-",  # not an app file name: reduced to a safe part
    )
    for stem in stems:
        logger.log_demo(stem, path)
    logger.log_demo(stems[0], path)  # logged again: the same name
    logger.log_replay("raw · alice", path, "raw")
    logger.log_replay("cleaned · alice", path, "cleaned")
    logger.close()
    names = ["alice_12-06_120301", "alice_12-06_120301_2", "bob_12-06_121000", "x"]
    assert list(logger.demo_names.values()) == names
    entities = _static(rrd)
    demos = sorted(e for e in entities if e.startswith("/demos/"))
    assert demos == sorted(f"/demos/{n}" for n in names)
    colours = [entities[f"/demos/{n}"]["LineStrips3D:colors"][0][0] for n in names]
    assert len(set(colours)) == len(names)  # one colour per demo
    legends = [text[0] for text in entities["/legend"]["TextDocument:text"]]
    assert any(all(f"`{n}`" in text for n in names) for text in legends)
    radii = {
        kind: abs(entities[f"/replay/{kind}"]["LineStrips3D:radii"][0][0])
        for kind in ("raw", "cleaned")
    }
    assert radii["cleaned"] > radii["raw"]  # the cleaned replay wider than its raw one


def _listening(pid: int) -> set[int]:
    process = psutil.Process(pid)
    return {c.laddr.port for c in process.net_connections("inet") if c.status == "LISTEN"}


def _free(port: int) -> bool:
    with socket.socket() as probe:
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def test_the_apps_rerun_servers_stay_off_reruns_default_ports(tmp_path: Path) -> None:
    """With the app's defaults, nothing of the app listens on 9876 or 9090: a user's
    ``rerun out/wiping.rrd`` finds no viewer there and opens its own instead of streaming the
    file into the app's (an empty tab of the app's viewer, before)."""
    options = AppOptions()
    assert {options.rerun_grpc_port, options.rerun_web_port}.isdisjoint(RERUN_DEFAULT_PORTS)
    if not all(_free(p) for p in RERUN_DEFAULT_PORTS):
        pytest.skip("something else holds Rerun's default ports here")
    hub = RerunHub(
        "serve", tmp_path, grpc_port=options.rerun_grpc_port, web_port=options.rerun_web_port
    )
    try:
        assert hub.proxy is not None
        logger = hub.session_logger("ports")
        session = hub.session_proxy("ports")
        assert session is not None
        ports = _listening(hub.proxy.process.pid) | _listening(session.process.pid)
        assert ports and ports.isdisjoint(RERUN_DEFAULT_PORTS), ports
        assert all(_free(p) for p in RERUN_DEFAULT_PORTS)
        logger.close()
    finally:
        hub.close()
