"""One Ũ (issue 37): on the same recorded takes, the app's table, ``bt score --json``, ``bt clean``
(raw and cleaned), the Rerun summary of the clean and ``bt view`` show the same Ũ for each demo;
cleaning says what it changed (how far each demo moved, why a Ũ fell).

Real browser takes (../shared/data/browser-takes/wiping, copied to a temporary folder) are
scored and cleaned once for the module.
"""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rerun.chunk import RrdReader

from bt_pipeline.cli import main
from bt_pipeline.data.paths import expand_paths
from bt_pipeline.data.recording import read_recording
from bt_pipeline.viz.view import view_demos
from bt_teleop.library.listing import load_library
from bt_teleop.testing.harness import shared_dir

TAKES = shared_dir() / "data/browser-takes/wiping"


@dataclass(frozen=True)
class Session:
    """The takes, and what ``bt score --json`` and ``bt clean --json`` printed for them."""

    root: Path
    """The recordings root (``<root>/wiping/*.hdf5``), as the app keeps it."""
    out: Path
    """``bt clean``'s output folder."""
    score: dict[str, Any]
    clean: dict[str, Any]


def bt_json(*args: str) -> dict[str, Any]:
    """Run ``bt args --json`` in this process; its JSON document."""
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        main([*args, "--json"])
    return json.loads(stdout.getvalue())


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Session:
    base = tmp_path_factory.mktemp("views")
    folder = base / "rec" / "wiping"
    folder.mkdir(parents=True)
    for path in sorted(TAKES.glob("*.hdf5")):
        shutil.copy2(path, folder / path.name)
    score = bt_json("score", str(folder))
    out = base / "out"
    clean = bt_json("clean", str(folder), "--out", str(out), "--epochs", "3", "--executor", "local")
    return Session(base / "rec", out, score, clean)


def by_file(demos: list[dict[str, Any]], key: str) -> dict[str, float]:
    return {Path(d["file"]).name: d[key] for d in demos}


def test_the_page_bt_score_bt_clean_rerun_and_bt_view_show_one_utility(session: Session) -> None:
    (scored,) = session.score["tasks"]
    (cleaned,) = session.clean["tasks"]
    score = by_file(scored["demos"], "utility")
    assert len(score) >= 3
    # bt clean's raw Ũ is bt score's, over the same set.
    assert by_file(cleaned["demos"], "utility_raw") == score
    assert cleaned["best"] == scored["best"]
    # The app's table: the same takes, the same Ũ; unscored and flagged takes have none.
    library = load_library(session.root, "wiping")
    page = {t.file.name: t.utility for t in library.raw if t.utility is not None}
    assert page.keys() == score.keys()
    for name, value in score.items():
        assert page[name] == pytest.approx(value, abs=1e-12)
    assert library.best is not None and library.best.file.name == Path(scored["best"]["file"]).name
    ranks = {Path(d["file"]).name: d["rank"] for d in scored["demos"]}
    listed = zip(library.raw, library.ranks, strict=True)
    assert {t.file.name: r for t, r in listed if r} == ranks  # 0: not ranked
    # The Rerun summary of the clean: the Ũ bars and the summary table.
    bars, summary = rerun_scores(session.out / "wiping.rrd")
    np.testing.assert_array_equal(bars["raw"], [d["utility_raw"] for d in cleaned["demos"]])
    np.testing.assert_array_equal(bars["cleaned"], [d["utility_cleaned"] for d in cleaned["demos"]])
    for d in cleaned["demos"]:
        assert f"{d['utility_raw']:.3f} → {d['utility_cleaned']:.3f}" in summary
    # bt view of the takes, and of the takes with the cleaned file beside them.
    files = [p.name for p in expand_paths([session.root / "wiping"])]
    ((_, shown),) = view_demos([session.root / "wiping"]).values()
    view = {f: d.utility for f, d in zip(files, shown, strict=True) if d.utility is not None}
    assert view == score
    assert [d.best for d in shown].count(True) == 1
    (best,) = [f for f, d in zip(files, shown, strict=True) if d.best]
    assert best == Path(scored["best"]["file"]).name
    cleaned_file = session.out / "wiping.cleaned.hdf5"
    ((_, both),) = view_demos([session.root / "wiping", cleaned_file]).values()
    raw_shown = zip(files, both[: len(files)], strict=True)
    assert {f: d.utility for f, d in raw_shown if d.utility is not None} == score
    assert [d.utility for d in both[len(files) :]] == [
        d["utility_cleaned"] for d in cleaned["demos"]
    ]


def rerun_scores(path: Path) -> tuple[dict[str, list[float]], str]:
    """The Ũ bar charts (raw, cleaned) and the summary text of a ``bt clean`` .rrd."""
    bars: dict[str, list[float]] = {}
    summary = ""
    for chunk in RrdReader(path).store().stream().to_chunks():
        batch = chunk.to_record_batch()
        for kind in ("raw", "cleaned"):
            if chunk.entity_path == f"/wiping/scores/utility/{kind}":
                [values] = batch.column("BarChart:values").to_pylist()
                bars[kind] = list(values[0]["buffer"])
        if chunk.entity_path == "/wiping/summary":
            [[summary]] = batch.column("TextDocument:text").to_pylist()
    return bars, summary


def test_cleaning_reports_how_far_each_demo_moved(session: Session) -> None:
    """moved mean / max: distance between each raw sample and the cleaned demo at the same time,
    measured here from the files (task plane); the best demo, passed through, moved 0 and kept
    its Ũ. Every Ũ that cleaning lowered has a note saying by how much and why."""
    (task,) = session.clean["tasks"]
    cleaned = read_recording(session.out / "wiping.cleaned.hdf5")
    plane = cleaned.plane
    moved_any = False
    for d in task["demos"]:
        record = cleaned.demos[d["output_demo"]]
        raw = read_recording(d["file"]).demos[d["demo"]]
        at = np.searchsorted(raw.timestamps, record.timestamps)
        np.testing.assert_array_equal(raw.timestamps[at], record.timestamps)  # the same times
        gap = np.linalg.norm(plane.to_plane(record.ee_pos) - plane.to_plane(raw.ee_pos[at]), axis=1)
        assert d["moved_mean_m"] == pytest.approx(float(np.mean(gap)), abs=1e-7)
        assert d["moved_max_m"] == pytest.approx(float(np.max(gap)), abs=1e-7)
        assert record.attrs["moved_mean"] == d["moved_mean_m"]
        assert record.attrs["utility_cleaned"] == d["utility_cleaned"]
        best = (d["file"], d["demo"]) == (task["best"]["file"], task["best"]["demo"])
        if best:
            assert d["moved_max_m"] == 0.0 and d["utility_cleaned"] == d["utility_raw"]
        else:
            moved_any |= d["moved_mean_m"] > 1e-4
            # L4 of the raw demo is measured against its aligned reference: never 0 for a take.
            assert d["shape_loss_raw"] > 1e-4
        if d["utility_cleaned"] < d["utility_raw"] - 5e-4:
            label = f"{d['file']}:{d['demo']}"
            assert any(n.startswith(f"{label}: cleaning lowered its Ũ") for n in task["notes"])
    assert moved_any  # a cleaned take that followed its reference reads L4 ≈ 0, not "unchanged"


def test_bt_clean_tables_say_what_their_columns_measure(session: Session) -> None:
    from bt_pipeline.clean.summary import TaskCleanSummary
    from bt_pipeline.viz.tables import CLEAN_CAPTION, print_clean_summary

    (task,) = session.clean["tasks"]
    summary = TaskCleanSummary(
        task=task["task"],
        best_file=task["best"]["file"],
        best_demo=task["best"]["demo"],
        output=Path(task["output"]),
        rrd=None,
        seconds=task["seconds"],
        stage_seconds=task["stage_seconds"],
        demos=(),
        notes=("a note",),
        best_reason="x has the highest Ũ but follows the task's guide loop less closely",
    )
    from rich.console import Console

    console = Console(file=io.StringIO(), width=400)
    print_clean_summary([summary], console)
    text = console.file.getvalue()  # type: ignore[attr-defined]
    assert "moved [mm]" in text and "off ref. [mm]" in text
    assert " ".join(CLEAN_CAPTION.split()[:6]) in " ".join(text.split())
    assert "★ x has the highest Ũ" in text and "note: a note" in text
