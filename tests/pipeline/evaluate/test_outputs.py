"""``bt evaluate``'s outputs are one set across their folders (evaluate/driver.py write_outputs):
all of them appear, or none; a failure mid-write leaves every folder as it was."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bt_pipeline.data.output_set import MANIFEST, STAGING_PREFIX, verify
from bt_pipeline.data.recording import write_recording
from bt_pipeline.data.synth import make_demo_set
from bt_pipeline.evaluate import driver
from bt_pipeline.evaluate.driver import evaluate_paths, write_outputs
from bt_pipeline.evaluate.protocol import EvalConfig, TaskEvaluation


@pytest.fixture(scope="module")
def evaluations(tmp_path_factory) -> list[TaskEvaluation]:
    source = tmp_path_factory.mktemp("in") / "in.hdf5"
    write_recording(source, make_demo_set("wiping", n_demos=3, seed=0).recording)
    config = EvalConfig(learners=("bc",), rollouts=2, quick=True, seed=0, steps=5)
    return evaluate_paths([source], [source], config, n_samples=120, progress=False)


def _targets(root: Path) -> dict[str, Path]:
    return {
        "plots": root / "plots",
        "rrd": root / "viz" / "eval.rrd",
        "rollouts_out": root / "rollouts",
        "json_out": root / "table.json",
    }


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in root.rglob("*") if p.is_file()}


def _runs(folder: Path) -> set[str]:
    return {e["run"] for e in json.loads((folder / MANIFEST).read_text())["files"].values()}


def test_every_output_is_published_with_one_run_in_every_manifest(evaluations, tmp_path) -> None:
    targets = _targets(tmp_path)
    written = write_outputs(evaluations, **targets, seed=0)  # type: ignore[arg-type]
    names = sorted(str(p.relative_to(tmp_path)) for p in written)
    assert names == [
        "plots/rewards.png",
        "plots/wiping.rollouts.png",
        "rollouts/wiping.bc.cleaned.rollouts.hdf5",
        "rollouts/wiping.bc.noisy.rollouts.hdf5",
        "table.json",
        "viz/eval.rrd",
    ]
    folders = [tmp_path / "plots", tmp_path / "rollouts", tmp_path / "viz", tmp_path]
    assert all(verify(folder) == [] for folder in folders)
    assert len(set().union(*(_runs(folder) for folder in folders))) == 1
    assert json.loads((tmp_path / "table.json").read_text())["results"]
    assert not list(tmp_path.rglob(f"{STAGING_PREFIX}*"))


def test_a_failure_mid_write_leaves_every_folder_as_it_was(
    evaluations, tmp_path, monkeypatch
) -> None:
    targets = _targets(tmp_path)
    write_outputs(evaluations, **targets, seed=0)  # type: ignore[arg-type]
    before = _files(tmp_path)

    def fail(*_args: object, **_kwargs: object) -> None:
        raise RuntimeError("disk full while writing the rollouts")

    # plots and .rrd are staged by then; the rollouts fail; nothing may be published
    monkeypatch.setattr(driver, "rollout_recording", fail)
    with pytest.raises(RuntimeError, match="disk full"):
        write_outputs(evaluations, **targets, seed=1)  # type: ignore[arg-type]
    assert _files(tmp_path) == before
    assert not list(tmp_path.rglob(f"{STAGING_PREFIX}*"))


def test_a_first_run_that_fails_publishes_nothing(evaluations, tmp_path, monkeypatch) -> None:
    def fail(*_args: object, **_kwargs: object) -> None:
        raise RuntimeError("stopped")

    monkeypatch.setattr(driver, "eval_json", fail)  # the last output staged
    with pytest.raises(RuntimeError):
        write_outputs(evaluations, **_targets(tmp_path), seed=0)  # type: ignore[arg-type]
    assert _files(tmp_path) == {}


def test_no_output_asked_for_writes_nothing(evaluations, tmp_path) -> None:
    assert write_outputs(evaluations) == []
