"""bt_pipeline.viz.tables: tables printed to a pipe keep every file name whole."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from bt_pipeline.clean.summary import DemoCleanSummary, TaskCleanSummary
from bt_pipeline.data.recording import write_recording
from bt_pipeline.data.synth import make_demo_set
from bt_pipeline.viz.tables import PIPED_WIDTH, print_clean_summary, table_console
from tests.conftest import run

PREFIX = "newcomer_" + "take_recorded_in_the_lab_on_a_long_afternoon_" * 2
"""Long file names that differ only at their end, as a crowd's takes do."""


@pytest.fixture(scope="module")
def similar_files(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """A D1 wiping set, one demo per file, the files named alike but for their last word."""
    folder = tmp_path_factory.mktemp("takes")
    recording = make_demo_set("wiping", 4, seed=0).recording
    words = ("one", "two", "three", "four")
    return [
        write_recording(
            folder / f"{PREFIX}{word}.hdf5",
            dataclasses.replace(recording, demos={"demo_0": record}),
        )
        for word, record in zip(words, recording.demos.values(), strict=True)
    ]


def test_piped_tables_are_wide() -> None:
    """Under pytest's capture stdout is not a terminal."""
    assert table_console().width == PIPED_WIDTH
    assert table_console(130).width == PIPED_WIDTH


def test_bt_score_piped_keeps_every_file_name_whole(capsys, similar_files) -> None:
    code, out, err = run(capsys, "score", *(str(p) for p in similar_files))
    assert code == 0, err
    for path in similar_files:
        assert f"{path.name}:demo_0" in out, out
    assert "…" not in out  # nothing cut
    rows = [line for line in out.splitlines() if PREFIX in line and "demo_0" in line]
    assert len(rows) >= len(similar_files)  # one row each, on one line each


def test_bt_score_json_is_unchanged_by_the_width(capsys, similar_files) -> None:
    code, out, _ = run(capsys, "score", "--json", *(str(p) for p in similar_files))
    assert code == 0
    document = json.loads(out)  # one JSON object alone on stdout
    files = {d["file"] for d in document["tasks"][0]["demos"]}
    assert files == {str(p) for p in similar_files}


def test_clean_summary_piped_keeps_every_file_name_whole(capsys, similar_files) -> None:
    demos = tuple(
        DemoCleanSummary(
            file=str(path),
            demo="demo_0",
            output_demo=f"demo_{k}",
            demonstrator="newcomer",
            utility_raw=0.5,
            utility_cleaned=0.6,
            shape_loss_raw=0.01,
            shape_loss_cleaned=0.002,
            beta_final=1.0,
        )
        for k, path in enumerate(similar_files)
    )
    summary = TaskCleanSummary(
        task="wiping",
        best_file=str(similar_files[0]),
        best_demo="demo_0",
        output=Path("out/wiping.cleaned.hdf5"),
        rrd=None,
        seconds=1.0,
        stage_seconds={},
        demos=demos,
        notes=(),
    )
    print_clean_summary([summary])
    out = capsys.readouterr().out
    for path in similar_files:
        assert f"{path.name}:demo_0" in out, out
    assert "…" not in out
