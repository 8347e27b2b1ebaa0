"""Skip, don't stop (data/skipping.py, clean/skipping.py): what bt score and bt clean leave out."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from bt_pipeline.clean.driver import clean_paths
from bt_pipeline.clean.pipeline import CleanOptions
from bt_pipeline.cli import main
from bt_pipeline.data.demo import Demo, demos_from_recording
from bt_pipeline.data.moderation import exclude
from bt_pipeline.data.recording import read_recording, write_recording
from bt_pipeline.data.records import DemoRecord, Recording
from bt_pipeline.data.skipping import named_demo, skip_failing
from bt_pipeline.data.synth import make_d1
from bt_pipeline.exceptions import DemoError

FAST = CleanOptions(epochs=2, progress=False, write_rrd=False)


def _with(recording: Recording, **changes: DemoRecord) -> Recording:
    return dataclasses.replace(recording, demos={**recording.demos, **changes})


def _still(record: DemoRecord) -> DemoRecord:
    still = np.repeat(record.ee_pos[:1], record.num_samples, axis=0)
    return dataclasses.replace(record, ee_pos=still, actions=None)


def _flagged(record: DemoRecord, flags: str) -> DemoRecord:
    return dataclasses.replace(record, attrs={**record.attrs, "flags": flags})


@pytest.fixture
def mixed(tmp_path: Path) -> tuple[Path, str]:
    """A D1 wiping set whose expert is flagged, plus a still demo; and an excluded file."""
    synth = make_d1("wiping", 0)
    recording = synth.recording
    expert = synth.expert_name
    recording = _with(
        recording,
        **{expert: _flagged(recording.demos[expert], "incomplete")},
        demo_9=_still(recording.demos["demo_0"]),
    )
    write_recording(tmp_path / "in" / "set.hdf5", recording)
    other = write_recording(tmp_path / "in" / "other.hdf5", make_d1("wiping", 1).recording)
    exclude(other, reason="bad take")
    return tmp_path / "in", expert


def test_clean_skips_flagged_still_and_excluded_and_cleans_the_rest(tmp_path, mixed) -> None:
    folder, expert = mixed
    (summary,) = clean_paths([folder], tmp_path / "out", FAST)
    cleaned = read_recording(summary.output)
    sources = {d.attrs["cleaned_from"].rsplit(":", 1)[1] for d in cleaned.demos.values()}
    assert sources == {"demo_0", "demo_1", "demo_2", "demo_3"} - {expert}
    assert summary.best_demo != expert  # a flagged demo is never the best
    notes = "\n".join(summary.notes)
    assert f"set.hdf5:{expert}: flagged incomplete" in notes
    assert "set.hdf5:demo_9 does not move" in notes
    assert "other.hdf5: excluded: bad take" in notes
    assert all(n.startswith("skipped ") for n in summary.notes[:3])


def test_strict_still_stops_at_a_degenerate_demo_naming_it(tmp_path, mixed) -> None:
    folder, _ = mixed
    strict = CleanOptions(**{**FAST.__dict__, "strict": True})
    with pytest.raises(DemoError, match=r"set\.hdf5:demo_9 does not move"):
        clean_paths([folder], tmp_path / "out", strict)
    assert not (tmp_path / "out").exists()


def test_a_task_of_only_unusable_demos_is_one_error_listing_them(tmp_path) -> None:
    recording = make_d1("wiping", 0).recording
    only = Recording(recording.task, recording.plane, {"demo_0": _still(recording.demos["demo_0"])})
    path = write_recording(tmp_path / "still.hdf5", only)
    with pytest.raises(DemoError, match=r"no task could be cleaned: skipped .*demo_0 does not"):
        clean_paths([path], tmp_path / "out", FAST)


def test_an_error_naming_no_demo_is_traced_to_the_demo_that_fails_alone() -> None:
    demos = demos_from_recording(make_d1("weaving", 0).recording)
    demos = [dataclasses.replace(d, file="f.hdf5") for d in demos]
    bad = demos[2]

    def run(kept: list[Demo]) -> int:
        if any(d is bad for d in kept):
            raise DemoError("values contain NaN or infinite metric values")  # names nothing
        return len(kept)

    def probe(demo: Demo) -> None:
        if demo is bad:
            raise ValueError("data must be finite")

    result, notes = skip_failing(run, demos, probe)
    assert result == 3
    assert notes == [f"skipped f.hdf5:{bad.name}: values contain NaN or infinite metric values"]
    with pytest.raises(DemoError, match=f"^f.hdf5:{bad.name}: values contain NaN"):
        skip_failing(run, demos, probe, strict=True)
    with pytest.raises(DemoError, match=r"^task weaving \(f\.hdf5\): values contain NaN"):
        skip_failing(run, demos, lambda demo: None)


def test_named_demo_prefers_the_longest_label() -> None:
    demos = demos_from_recording(make_d1("wiping", 0).recording)
    one, ten = (dataclasses.replace(demos[0], file="a.hdf5", name=n) for n in ("demo_1", "demo_10"))
    assert named_demo("a.hdf5:demo_10 does not move", [one, ten]) is ten
    assert named_demo("a.hdf5:demo_1 does not move", [one, ten]) is one
    assert named_demo("nothing here", [one, ten]) is None


def test_bt_score_lists_flagged_demos_with_a_warning_and_never_ranks_them(
    tmp_path, mixed, capsys
) -> None:
    folder, expert = mixed
    main(["score", str(folder), "--json"])  # returns (no SystemExit) on success
    document = json.loads(capsys.readouterr().out)
    (task,) = document["tasks"]
    assert [f["demo"] for f in task["flagged"]] == [expert]
    assert task["flagged"][0]["flags"] == ["incomplete"]
    ranked = {d["demo"] for d in task["demos"]}
    assert expert not in ranked and task["best"]["demo"] != expert
    assert any("other.hdf5: excluded" in n for n in document["notes"])
    main(["score", str(folder)])
    out = capsys.readouterr().out
    (row,) = [line for line in out.splitlines() if "⚠" in line]
    assert expert in row and "flagged" in row
