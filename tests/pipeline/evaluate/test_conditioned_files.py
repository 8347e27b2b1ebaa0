"""``bt evaluate``'s conditioned protocol on files (evaluate/files_conditioned.py, file_facts.py):
where each demo's θ/ρ and each demonstrator's reference loop come from, and the notes when the
files cannot say."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import logging
import math
from pathlib import Path

import numpy as np
import pytest

from bt_pipeline.cli import main
from bt_pipeline.data.demo import Demo
from bt_pipeline.data.recording import read_recording, write_recording
from bt_pipeline.data.synth import make_demo_set
from bt_pipeline.evaluate.file_facts import read_annotated
from bt_pipeline.evaluate.files_conditioned import (
    NO_TRUTH_NOTE,
    TRUTH_NOTE,
    ConditionedInputs,
    ConditionedTask,
    prepare_task,
    run_conditioned,
)
from bt_pipeline.exceptions import DemoError
from tests.conftest import run

SAMPLES = 100
FAST = ["--learners", "bc", "--rollouts", "4", "--steps", "5", "--samples", str(SAMPLES)]
"""Tiny runs: one learner, a few optimiser steps and rollouts (plumbing, not results)."""


def rewrite(src: Path, dst: Path, *, keep_prefs: bool, keep_truth: bool, who: str | None) -> Path:
    """`src` with θ/ρ set unknown (NaN), the truth attrs dropped, or every demonstrator renamed."""
    recording = read_recording(src)
    demos = {}
    for name, record in recording.demos.items():
        attrs = {k: v for k, v in record.attrs.items() if keep_truth or not k.startswith("truth_")}
        demos[name] = dataclasses.replace(
            record,
            theta_deg=record.theta_deg if keep_prefs else math.nan,
            rho=record.rho if keep_prefs else math.nan,
            demonstrator=record.demonstrator if who is None else who,
            attrs=attrs,
        )
    return write_recording(dst, dataclasses.replace(recording, demos=demos))


def clean(raw: Path, out: Path) -> Path:
    with contextlib.redirect_stdout(io.StringIO()):
        main(["clean", str(raw), "--out", str(out), "--epochs", "2", "--no-rrd", "--json"])
    return out / "wiping.cleaned.hdf5"


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A synthetic wiping D1 set with truth and its cleaned file; the same set with no truth and
    no stated θ/ρ, and its cleaned file (the cleaner's estimates); a set with no θ/ρ and no
    demonstrator at all."""
    root = tmp_path_factory.mktemp("conditioned_files")
    raw = write_recording(root / "raw.hdf5", make_demo_set("wiping", 4, seed=0).recording)
    hidden = rewrite(raw, root / "hidden.hdf5", keep_prefs=False, keep_truth=False, who=None)
    anonymous = rewrite(raw, root / "anon.hdf5", keep_prefs=False, keep_truth=False, who="")
    return {
        "raw": raw,
        "cleaned": clean(raw, root / "cleaned"),
        "hidden": hidden,
        "hidden_cleaned": clean(hidden, root / "hidden_cleaned"),
        "anonymous": anonymous,
    }


def evaluate_json(capsys, noisy: Path, cleaned: Path, *extra: str) -> list[dict]:
    args = ["--noisy", str(noisy), "--cleaned", str(cleaned), *FAST, "--json", *extra]
    code, out, err = run(capsys, "evaluate", *args)
    assert code == 0, err
    return json.loads(out)["results"]


def test_true_loops_are_rebuilt_from_the_files_generator_attrs(files) -> None:
    synth = make_demo_set("wiping", 4, seed=0)
    demos, facts = read_annotated([files["raw"]], SAMPLES)
    for demo, truth in zip(demos, synth.demos, strict=True):
        loop = facts[(demo.file, demo.name)].true_loop
        assert loop is not None
        np.testing.assert_allclose(loop, truth.truth, atol=1e-9)
    _, hidden = read_annotated([files["hidden"]], SAMPLES)
    assert all(f.true_loop is None for f in hidden.values())


def test_a_wrong_truth_attr_is_no_truth(files, tmp_path) -> None:
    recording = read_recording(files["raw"])
    demos = {  # the stated truth θ no longer matches truth_uv: the truth cannot be trusted
        n: dataclasses.replace(
            r, attrs={**r.attrs, "truth_theta_deg": r.attrs["truth_theta_deg"] + 5}
        )
        for n, r in recording.demos.items()
    }
    path = write_recording(tmp_path / "bad.hdf5", dataclasses.replace(recording, demos=demos))
    _, facts = read_annotated([path], SAMPLES)
    assert all(f.true_loop is None for f in facts.values())


def test_synthetic_files_are_scored_against_their_truth(files, capsys, tmp_path) -> None:
    out = tmp_path / "table.json"
    rows = evaluate_json(capsys, files["raw"], files["cleaned"], "--json-out", str(out))
    assert json.loads(out.read_text())["results"] == rows  # the file holds the same rows
    assert {r["dataset"] for r in rows} == {"noisy", "cleaned"}
    for row in rows:
        c = row["conditioned"]
        assert c["gate"] == TRUTH_NOTE and c["note"].startswith(TRUTH_NOTE)
        assert "noisy 4 stated; cleaned 4 stated" in c["note"]
        assert 0.0 <= c["success_10mm"] <= 1.0 and c["shape_mm"] > 0.0
        assert c["rollouts"] == 4  # 4 asked, 4 demonstrators: one each


def test_without_truth_or_stated_preferences_the_cleaners_estimates_are_used(files, capsys) -> None:
    rows = evaluate_json(capsys, files["hidden"], files["hidden_cleaned"])
    for row in rows:
        c = row["conditioned"]
        assert c["gate"] is None and c["note"].startswith(NO_TRUTH_NOTE)
        assert "best raw demo" in c["note"]
        assert "noisy 4 the cleaner's estimates; cleaned 4 the cleaner's estimates" in c["note"]
        assert c["shape_mm"] > 0.0


def test_a_raw_demo_takes_the_estimate_of_its_cleaned_version(files) -> None:
    noisy, facts = read_annotated([files["hidden"]], SAMPLES)
    cleaned, cleaned_facts = read_annotated([files["hidden_cleaned"]], SAMPLES)
    inputs = prepare_task(noisy, cleaned[::-1], {**facts, **cleaned_facts})  # paired by source
    assert isinstance(inputs, ConditionedInputs)
    estimates = np.array([[d.theta_deg, d.rho] for d in cleaned], dtype=np.float64)
    np.testing.assert_array_equal(inputs.preferences["noisy"], estimates)
    np.testing.assert_array_equal(inputs.preferences["cleaned"], estimates[::-1])
    assert len(inputs.loops) == 4 and inputs.gate is None
    assert inputs.demonstrators["noisy"] == tuple(d.demonstrator for d in noisy)


def test_no_preference_and_no_demonstrator_keeps_the_unconditioned_learners(
    files, capsys, caplog
) -> None:
    path = str(files["anonymous"])
    with caplog.at_level(logging.WARNING, logger="bt"):
        code, out, err = run(capsys, "evaluate", "--noisy", path, "--cleaned", path, *FAST)
    assert code == 0, err
    note = "no θ/ρ or demonstrator for 4 noisy and 4 cleaned demos of wiping"
    assert any(note in r.getMessage() for r in caplog.records)
    assert "Learners trained on noisy vs cleaned demos" in out  # the unconditioned table
    assert "Conditioned learners" not in out and note in out
    rows = evaluate_json(capsys, files["anonymous"], files["anonymous"])
    assert rows and all(r["conditioned"]["success_10mm"] is None for r in rows)
    assert all(note in r["conditioned"]["note"] for r in rows)


def test_a_named_demonstrator_lends_its_preference_to_its_other_demos(files) -> None:
    demos, facts = read_annotated([files["raw"]], SAMPLES)
    d = demos[0]
    twin = dataclasses.replace(d, name="twin", theta_deg=None, rho=None)
    facts[(twin.file, twin.name)] = facts[(d.file, d.name)]
    noisy = [*demos, twin]
    inputs = prepare_task(noisy, noisy, facts)
    assert isinstance(inputs, ConditionedInputs)
    assert tuple(inputs.preferences["noisy"][-1]) == (d.theta_deg, d.rho)
    assert "1 from their demonstrator's other demos" in inputs.note
    unknown = [dataclasses.replace(x, demonstrator="unknown") for x in (d, twin)]
    alone = prepare_task(unknown, unknown, facts)
    assert isinstance(alone, ConditionedTask) and not alone.cells  # "unknown" lends nothing
    assert "for 1 noisy and 1 cleaned demos" in alone.note


def test_demos_without_a_demonstrator_are_grouped_by_preference(files) -> None:
    demos, facts = read_annotated([files["raw"]], SAMPLES)
    anonymous = [dataclasses.replace(d, demonstrator="") for d in demos]
    inputs = prepare_task(anonymous, anonymous, facts)
    assert isinstance(inputs, ConditionedInputs)
    assert [loop.name for loop in inputs.loops] == [
        f"θ {d.theta_deg:.1f}° ρ {d.rho:.3f}" for d in demos
    ]
    assert inputs.gate == TRUTH_NOTE  # the truth follows the demos, not their names


def test_one_demonstrator_is_conditioned_on_a_constant(files) -> None:
    demos, facts = read_annotated([files["raw"]], SAMPLES)
    same = [dataclasses.replace(d, demonstrator="ann", theta_deg=10.0, rho=0.9) for d in demos]
    for d in same:
        facts[(d.file, d.name)] = dataclasses.replace(facts[(d.file, d.name)], true_loop=None)
    inputs = prepare_task(same, same, facts)
    assert isinstance(inputs, ConditionedInputs) and len(inputs.loops) == 1
    (task,) = run_conditioned([inputs], ["bc"], seed=0, rollouts=3, steps=5, progress=False)
    assert [c.rollouts for c in task.cells] == [3, 3]
    assert all(np.isfinite(c.shape_mm) for c in task.cells)


def test_an_impossible_preference_is_a_clear_error(files) -> None:
    demos, facts = read_annotated([files["raw"]], SAMPLES)
    bad = [dataclasses.replace(demos[0], rho=0.0), *demos[1:]]
    with pytest.raises(DemoError, match=r"demo_0 has θ = .*ρ = 0.0; a preference must be finite"):
        prepare_task(bad, demos, facts)
    short = [
        Demo(d.positions[:50], d.task, d.file, d.name, d.demonstrator, 0.0, 1.0, d.plane)
        for d in demos
    ]
    with pytest.raises(DemoError, match="same N"):
        prepare_task(demos, short, facts)


def test_no_conditioned_skips_them(files, capsys) -> None:
    args = ["--noisy", str(files["raw"]), "--cleaned", str(files["cleaned"]), *FAST]
    code, out, err = run(capsys, "evaluate", *args, "--json", "--no-conditioned")
    assert code == 0, err
    document = json.loads(out)
    assert list(document) == ["results"]
    assert all("conditioned" not in row for row in document["results"])
    assert "conditioned learners" not in err
    code, out, _ = run(capsys, "evaluate", *args, "--no-conditioned")
    assert code == 0 and "Conditioned learners" not in out and TRUTH_NOTE not in out


def test_the_table_shows_the_conditioned_learners_and_the_note(files, capsys) -> None:
    args = ["--noisy", str(files["hidden"]), "--cleaned", str(files["hidden_cleaned"]), *FAST]
    code, out, err = run(capsys, "evaluate", *args)
    assert code == 0, err
    assert "Conditioned learners" in out and "shape [mm]" in out
    assert f"wiping: {NO_TRUTH_NOTE}" in " ".join(out.split())
