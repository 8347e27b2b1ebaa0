"""What the app keeps per take (bt_teleop/library/tracks.py): the listing of real browser takes,
with no samples anywhere in a library or in the shared loader's cache, and scores equal to scoring
the files' usable demos from scratch (bt_pipeline.score.utility.score_demos)."""

from __future__ import annotations

import concurrent.futures
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bt_pipeline.clean.selection import select_demos
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.moderation import exclude
from bt_pipeline.data.recording import read_recording
from bt_pipeline.exceptions import DemoError
from bt_teleop.library.listing import library_markdown, load_library
from bt_teleop.library.loader import LibraryLoader
from bt_teleop.library.reading import read_file_tracks
from bt_teleop.library.tracks import file_stamp
from bt_teleop.testing.harness import reachable
from tests.teleop.library.conftest import write_cleaned


def arrays_reachable(root: Any) -> list[tuple[int, ...]]:
    """The shapes of the numpy arrays reachable from `root` through containers and records."""
    return [item.shape for item in reachable(root) if isinstance(item, np.ndarray)]


def test_a_library_and_the_loader_cache_hold_no_samples(takes: Path) -> None:
    write_cleaned(takes)
    with concurrent.futures.ThreadPoolExecutor(1) as executor:
        loader = LibraryLoader(takes, executor)
        library = loader.request("wiping").result(120)
    assert len(library.raw) == 12 and len(library.cleaned) == 3
    assert arrays_reachable(library) == []
    assert arrays_reachable(loader._files) == []
    # The check itself sees arrays where there are some.
    assert arrays_reachable(read_recording(library.raw[0].file))


def test_the_listing_matches_the_files(takes: Path) -> None:
    cleaned_file = write_cleaned(takes)
    library = load_library(takes, "wiping")
    for track in library.tracks:
        record = read_recording(track.file).demos[track.demo]
        assert track.num_samples == record.num_samples
        assert track.duration_s == pytest.approx(record.timestamps[-1] - record.timestamps[0])
        assert track.stamp == file_stamp(track.file)
        assert track.demonstrator == record.demonstrator
    by_prefix = {t.file.name.split("_")[0]: t for t in library.raw}
    assert by_prefix["erin"].flags == ("closed_mid_take",)  # ep_meta incomplete (older app)
    assert not by_prefix["erin"].usable and by_prefix["erin"].utility is None
    assert "clamped" in by_prefix["dave"].warnings  # 56 clamped samples
    assert by_prefix["script-alert-1-script"].demonstrator.startswith("<script")
    for track in library.cleaned:  # each cleaned demo names the raw take it came from
        source = library.source_of(track)
        assert track.file == cleaned_file and source is not None and source.kind == "raw"
        cleaned_from = read_recording(cleaned_file).demos[track.demo].attrs["cleaned_from"]
        assert cleaned_from == f"{source.file}:{source.demo}"
    assert library.source_of(library.raw[0]) is None


def test_scores_equal_scoring_the_usable_files_from_scratch(takes: Path) -> None:
    """The table's Ũ and ★ are what ``bt score`` and ``bt clean`` compute over the usable takes
    (their periodic parts, the shape gate); a usable take with no loop (it does not move) is
    listed unscored, as ``bt clean`` leaves it out."""
    exclude(sorted((takes / "wiping").glob("alice_*.hdf5"))[0], reason="test")
    library = load_library(takes, "wiping")
    usable = [t for t in library.raw if t.usable]
    scored = [t for t in usable if t.utility is not None]
    assert 3 <= len(scored) < len(usable) < len(library.raw)
    demos = [demos_from_recording(read_recording(t.file))[0] for t in scored]
    truth = select_demos(demos).scores
    for track, score in zip(scored, truth.scores, strict=True):
        assert track.utility == pytest.approx(score.utility, abs=1e-9)
    assert library.best is not None and library.best.file == scored[truth.best_index].file
    assert all(t.utility is None for t in library.raw if not t.usable)
    shown = library_markdown(library, len(library.raw))
    assert shown.count("no loop found") == len(usable) - len(scored)
    for track in usable:
        if track.utility is None:
            with pytest.raises(DemoError, match="does not move"):
                select_demos(demos_from_recording(read_recording(track.file)))


def test_a_file_replaced_while_it_is_read_is_read_again(takes: Path, monkeypatch) -> None:
    import bt_pipeline.data.recording as recording_module

    path = sorted((takes / "wiping").glob("bob_*.hdf5"))[0]
    other = sorted((takes / "wiping").glob("carol_*.hdf5"))[0]
    real_read = recording_module.read_recording
    calls: list[Path] = []

    def read_then_replace(where: Path, *args: Any) -> Any:
        calls.append(where)
        result = real_read(where, *args)
        if len(calls) == 1:  # the file is replaced right after the first read
            shutil.copy2(other, path.with_suffix(".tmp"))
            path.with_suffix(".tmp").replace(path)
        return result

    monkeypatch.setattr(recording_module, "read_recording", read_then_replace)
    tracks = read_file_tracks(path, "raw")
    assert len(calls) == 2 and tracks.stamp == file_stamp(path)
    assert tracks.tracks[0].num_samples == read_recording(other).demos["demo_0"].num_samples
