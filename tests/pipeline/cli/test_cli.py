"""The ``bt`` command line: score, synth, clean (JSON schemas, errors, exit codes)."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

from bt_pipeline.cli import main
from bt_pipeline.data.recording import read_recording
from tests.conftest import run


@pytest.fixture(scope="module")
def wiping_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("synth") / "wiping.hdf5"
    main(["synth", "--task", "wiping", "--demos", "4", "--seed", "1", "--out", str(path)])
    return path


def test_synth_writes_a_valid_file_and_prints_its_path(capsys, tmp_path) -> None:
    out_file = tmp_path / "w.hdf5"
    code, out, _ = run(capsys, "synth", "--task", "weaving", "--demos", "5", "--out", str(out_file))
    assert code == 0
    assert out.strip() == str(out_file)
    recording = read_recording(out_file)
    assert recording.task == "weaving"
    assert len(recording.demos) == 5


def test_synth_refuses_to_overwrite(capsys, wiping_file) -> None:
    code, _, err = run(capsys, "synth", "--out", str(wiping_file))
    assert code == 2
    assert str(wiping_file) in err


def test_score_json_schema(capsys, wiping_file) -> None:
    code, out, _ = run(capsys, "score", str(wiping_file), "--json")
    assert code == 0
    document = json.loads(out)
    (task,) = document["tasks"]
    assert task["task"] == "wiping"
    assert set(task["best"]) == {"file", "demo"}
    assert len(task["demos"]) == 4
    keys = {"file", "demo", "demonstrator", "mutual_information", "symmetry", "closure"}
    keys |= {"smoothness", "utility", "rank"}
    for demo in task["demos"]:
        assert keys <= set(demo)
    ranks = sorted(d["rank"] for d in task["demos"])
    assert ranks == [1, 2, 3, 4]
    best = next(d for d in task["demos"] if d["rank"] == 1)
    assert task["best"] == {"file": best["file"], "demo": best["demo"]}
    for demo in task["demos"]:  # the single-loop style: θ/ρ given, about one loop each
        assert demo["preference_estimated"] is False
        assert 0.5 < demo["cycles"] < 1.5
        assert demo["loop_start_s"] < demo["loop_end_s"]


def test_score_reads_the_periodic_part_and_picks_the_demo_clean_picks(capsys, tmp_path) -> None:
    """Human-style weaving, seed 1 (θ/ρ hidden): scored over the whole recordings (rest,
    approach and retreat included; Eqs. 3-8 as written) demo_3 ranks first; on their periodic
    parts, with the cleaner's shape gate, the expert-like demo_2 does, as in ``bt clean``."""
    path = tmp_path / "weaving.hdf5"
    main(["synth", "--style", "human", "--task", "weaving", "--seed", "1", "--out", str(path)])
    capsys.readouterr()
    recording = read_recording(path)
    expert = next(k for k, d in recording.demos.items() if d.ep_meta["synthetic"]["is_expert"])
    code, out, _ = run(capsys, "score", str(path), "--json")
    assert code == 0
    (task,) = json.loads(out)["tasks"]
    assert task["best"]["demo"] == expert == "demo_2"
    for demo in task["demos"]:
        times = recording.demos[demo["demo"]].timestamps
        assert times[0] <= demo["loop_start_s"] < demo["loop_end_s"] <= times[-1]
        assert demo["loop_end_s"] - demo["loop_start_s"] < times[-1] - times[0]  # trimmed
        assert demo["cycles"] >= 1.0 and demo["preference_estimated"] is True
    code, out, _ = run(capsys, "score", str(path), "--json", "--whole-demos")
    assert code == 0
    (whole,) = json.loads(out)["tasks"]
    assert whole["best"]["demo"] == "demo_3"
    assert all(d["cycles"] is None for d in whole["demos"])
    code, out, _ = run(capsys, "clean", str(path), "--out", str(tmp_path / "out"), "--no-rrd",
                       "--epochs", "2", "--json")  # fmt: skip
    assert code == 0
    (cleaned,) = json.loads(out)["tasks"]
    assert cleaned["best"]["demo"] == expert


def test_score_table_marks_the_best_and_groups_by_task(capsys, tmp_path, wiping_file) -> None:
    other = tmp_path / "pnp.hdf5"
    main(["synth", "--task", "pick_and_place", "--out", str(other)])
    capsys.readouterr()
    code, out, _ = run(capsys, "score", str(wiping_file), str(tmp_path / "*.hdf5"))
    assert code == 0
    assert "wiping: 4 demos" in out
    assert "pick_and_place: 4 demos" in out
    assert out.count("│ ★ │") == 2  # one best row per task


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["score", "does/not/exist.hdf5"], "no recordings found"),
        (["synth", "--task", "sweeping", "--out", "x.hdf5"], "task 'sweeping' has no built-in"),
    ],
)
def test_errors_print_one_line_and_exit_2(capsys, args, message) -> None:
    code, out, err = run(capsys, *args)
    assert code == 2
    assert out == ""
    assert message in err
    assert len(err.strip().splitlines()) == 1


def test_score_of_a_corrupt_file_names_it(capsys, tmp_path) -> None:
    bad = tmp_path / "bad.hdf5"
    bad.write_bytes(b"not an hdf5 file at all")
    code, _, err = run(capsys, "score", str(bad))
    assert code == 2
    assert "bad.hdf5" in err


def test_clean_json_writes_outputs_and_leaves_inputs_alone(capsys, tmp_path, wiping_file) -> None:
    digest = hashlib.sha256(wiping_file.read_bytes()).hexdigest()
    out_dir = tmp_path / "out"
    code, out, _ = run(
        capsys, "clean", str(wiping_file), "--out", str(out_dir), "--epochs", "3", "--no-rrd",
        "--json",
    )  # fmt: skip
    assert code == 0
    document = json.loads(out)
    (task,) = document["tasks"]
    assert task["task"] == "wiping"
    assert {"best", "demos", "seconds", "output"} <= set(task)
    assert len(task["demos"]) == 4
    for demo in task["demos"]:
        assert {"file", "demo", "utility_raw", "utility_cleaned", "beta_final"} <= set(demo)
    cleaned = read_recording(out_dir / "wiping.cleaned.hdf5")
    assert list(cleaned.demos) == ["demo_0", "demo_1", "demo_2", "demo_3"]
    assert cleaned.attrs["best_demo"] == task["best"]["demo"]
    assert not (out_dir / "wiping.rrd").exists()
    assert hashlib.sha256(wiping_file.read_bytes()).hexdigest() == digest


def test_clean_with_no_demos_found_writes_nothing(capsys, tmp_path) -> None:
    out_dir = tmp_path / "out"
    code, _, err = run(capsys, "clean", str(tmp_path / "none*.hdf5"), "--out", str(out_dir))
    assert code == 2
    assert "no recordings found" in err
    assert not out_dir.exists()


def test_python_dash_m_runs_the_same_cli() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "bt_pipeline", "--help"], capture_output=True, text=True, check=True
    )
    for command in ("score", "synth", "clean"):
        assert command in result.stdout


def test_clean_reads_hidden_theta_rho_within_the_given_range(capsys, tmp_path) -> None:
    """--theta-max/--rho-min/--rho-max bound what is read from files that lack θ/ρ (NaN)."""
    import math

    path = tmp_path / "human.hdf5"
    # Seed 0's wiping set hides θ/ρ; its demonstrators' truth: θ 7.7, -18.2, 5.9, -9.9 deg,
    # ρ 1.24, 1.19, 1.09, 1.21.
    main(["synth", "--style", "human", "--seed", "0", "--out", str(path)])
    raw = read_recording(path)
    assert all(math.isnan(d.theta_deg) for d in raw.demos.values())
    truth = {name: d.attrs["truth_theta_deg"] for name, d in raw.demos.items()}
    assert min(truth.values()) < -10.0  # the range below must bind
    code, _, _ = run(
        capsys, "clean", str(path), "--out", str(tmp_path / "out"), "--epochs", "2", "--no-rrd",
        "--theta-max", "10", "--rho-min", "0.9", "--rho-max", "1.15", "--executor", "local",
    )  # fmt: skip
    assert code == 0
    cleaned = read_recording(tmp_path / "out" / "wiping.cleaned.hdf5")
    for name, demo in cleaned.demos.items():
        assert demo.attrs["preference_estimated"]
        assert -10.0 - 1e-9 <= demo.theta_deg <= 10.0 + 1e-9, name
        assert 0.9 - 1e-9 <= demo.rho <= 1.15 + 1e-9, name
    (low,) = [name for name, theta in truth.items() if theta < -10.0]
    assert cleaned.demos[low].theta_deg == pytest.approx(-10.0)  # held at the bound


def test_clean_refuses_an_empty_preference_range(capsys, wiping_file, tmp_path) -> None:
    code, out, err = run(
        capsys, "clean", str(wiping_file), "--out", str(tmp_path / "out"),
        "--rho-min", "1.5", "--rho-max", "1.2",
    )  # fmt: skip
    assert code == 2
    assert out == ""
    assert "rho range" in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_teleop_realtime_priority_reaches_every_session(capsys, monkeypatch) -> None:
    import bt_teleop.app

    seen = []
    monkeypatch.setattr(bt_teleop.app, "serve", seen.append)
    assert run(capsys, "teleop", "--realtime-priority", "12")[0] == 0
    assert run(capsys, "teleop")[0] == 0
    assert run(capsys, "teleop", "--realtime-priority", "0")[0] == 0
    # tried by default (left off, logged, where not permitted); 0 turns it off
    assert [options.session.realtime_priority for options in seen] == [12, 10, 0]
    code, _, err = run(capsys, "teleop", "--realtime-priority", "100")
    assert code == 2 and "realtime_priority" in err and "Traceback" not in err


def test_teleop_joins_bt_through_its_entry_point_not_an_import() -> None:
    """``bt teleop`` is bt_teleop's plugin (pyproject's ``bt.commands`` group): the installed
    metadata names it, and loading it is what brings bt_teleop in."""
    from importlib.metadata import entry_points

    import bt_pipeline.cli as cli

    (point,) = [p for p in entry_points(group=cli.PLUGIN_GROUP) if p.name == "teleop"]
    assert point.value == "bt_teleop.cli:teleop"
    found = cli.commands()
    assert next(iter(found)) == "teleop" and found["teleop"].__module__ == "bt_teleop.cli"
    assert set(cli.BUILT_IN) < set(found) and "teleop" not in cli.BUILT_IN


def test_a_broken_or_clashing_plugin_is_left_out_with_a_warning(monkeypatch, caplog) -> None:
    from importlib.metadata import EntryPoint

    import bt_pipeline.cli as cli

    points = [
        EntryPoint("broken", "no_such_module_xyz:run", cli.PLUGIN_GROUP),
        EntryPoint("score", "json:dumps", cli.PLUGIN_GROUP),  # a built-in's name
        EntryPoint("dumps", "json:dumps", cli.PLUGIN_GROUP),
    ]
    monkeypatch.setattr(
        cli, "entry_points", lambda group: points if group == cli.PLUGIN_GROUP else []
    )
    with caplog.at_level("WARNING", logger="bt"):
        found = cli.commands()
    assert "broken" not in found and found["score"] is cli.BUILT_IN["score"]
    assert found["dumps"] is json.dumps
    text = caplog.text
    assert "'broken'" in text and "failed to load" in text
    assert "'score'" in text and "bt has a command of that name" in text
