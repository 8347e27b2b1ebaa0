"""kill -9 at chosen moments during bt clean, bt synth --overwrite, bt evaluate (four outputs),
bt export (both formats) and an app take being saved (bt_teleop.testing.faults): every output
complete or absent, an overwritten file old or new, a set from one run, no temp file left after
the next run's recovery. The big suite (≥ 100 trials at random moments) is
benchmarks/faults/bench_faults.py."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bt_pipeline.data.output_set import STAGING_PREFIX
from bt_teleop.testing.faults import check, prepare, run_trial, snapshot

REPO = Path(__file__).resolve().parents[2]
DELAYS = np.random.default_rng(10).uniform(0.3, 6.0, size=8)
"""Seeded kill moments [s]: from the imports to the outputs of these small runs."""


@pytest.mark.parametrize(
    ("scenario", "delay_s"),
    [
        ("synth", DELAYS[0]),
        ("synth", DELAYS[1]),
        ("take", DELAYS[2]),
        ("take", DELAYS[3]),
        ("clean", DELAYS[4]),
        ("evaluate", DELAYS[5]),
        ("export_lerobot", DELAYS[6]),
        ("export_robomimic", DELAYS[7]),
    ],
)
def test_a_killed_writer_leaves_complete_or_absent_outputs(tmp_path, scenario, delay_s) -> None:
    previous = scenario != "evaluate"  # a previous evaluate run costs a minute: fresh folder
    trial = run_trial(scenario, tmp_path / scenario, float(delay_s), REPO, previous=previous)
    assert trial.problems == (), trial


def test_the_check_finds_a_torn_output_and_leftovers(tmp_path) -> None:
    folder = tmp_path / "synth"
    prepare("synth", folder)
    (folder / ".s.hdf5.tmp-999999999-abcd").write_bytes(b"x" * 100)  # a stale temp: removed
    (folder / "s.hdf5").write_bytes((folder / "s.hdf5").read_bytes()[:3000])  # torn in place
    problems = check("synth", folder, old=None)
    assert any("incomplete output" in p for p in problems)
    assert not any("left behind" in p for p in problems)
    (folder / f"{STAGING_PREFIX}x").mkdir()  # not a staging folder recovery knows: reported
    assert any("left behind" in p for p in check("synth", folder, old=None))


def test_a_writer_that_finishes_passes_the_check(tmp_path) -> None:
    """The check accepts the new content of a finished `bt synth --overwrite` (not only the old)."""
    import os
    import subprocess

    folder = tmp_path / "synth"
    command = prepare("synth", folder)
    old = snapshot(folder / "s.hdf5")
    subprocess.run(command, check=True, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert snapshot(folder / "s.hdf5") is not None
    assert check("synth", folder, old) == ()


def test_the_check_finds_an_evaluate_set_mixing_two_runs_or_missing_a_file(tmp_path) -> None:
    from bt_pipeline.data.output_set import OutputSet
    from bt_teleop.testing.faults import EVALUATE_OUTPUTS

    folder = tmp_path / "evaluate"
    prepare("synth", tmp_path / "valid")  # a valid recording for the .hdf5 outputs
    recording = (tmp_path / "valid" / "s.hdf5").read_bytes()

    def publish(names: tuple[str, ...]) -> None:
        with OutputSet(folder / "rollouts") as outputs:
            for name in names:
                path = folder / name
                body = recording if name.endswith(".hdf5") else name.encode()
                outputs.path(path.name, path.parent).write_bytes(body)
            outputs.commit()

    publish(EVALUATE_OUTPUTS)
    assert check("evaluate", folder) == ()
    publish(("plots/rewards.png",))  # a later run replaced one file only
    assert any("mixes runs" in p for p in check("evaluate", folder))
    publish(EVALUATE_OUTPUTS)
    (folder / "table.json").unlink()
    assert any("only part of the set" in p for p in check("evaluate", folder))


def test_the_check_finds_a_lost_or_torn_lerobot_dataset(tmp_path) -> None:
    import shutil

    folder = tmp_path / "export_lerobot"
    prepare("export_lerobot", folder)
    assert check("export_lerobot", folder, previous_dataset=True) == ()
    (folder / "ds" / "meta" / "stats.json").unlink()
    assert any("meta/stats.json" in p for p in check("export_lerobot", folder))
    shutil.rmtree(folder / "ds")
    assert any("is gone" in p for p in check("export_lerobot", folder, previous_dataset=True))
