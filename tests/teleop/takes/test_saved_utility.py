"""The page marks a Ũ that moved since its take was saved (bt_teleop/takes/saved_utility.py): Ũ is
relative to the task's current set, so a take saved later can move the others' Ũ."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from bt_teleop.library.listing import RELATIVE_NOTE, library_markdown, load_library
from bt_teleop.takes.saved_utility import SAVED_NAME, read_saved, remember
from bt_teleop.testing.harness import shared_dir

TAKES = shared_dir() / "data/browser-takes/wiping"


def copy_takes(folder: Path, prefixes: tuple[str, ...]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for prefix in prefixes:
        (path,) = TAKES.glob(f"{prefix}_*.hdf5")
        shutil.copy2(path, folder / path.name)


def test_a_take_shows_what_its_utility_was_when_it_was_saved(tmp_path: Path) -> None:
    root = tmp_path / "rec"
    copy_takes(root / "wiping", ("alice", "bob", "carol"))
    first = load_library(root, "wiping")
    saved = {t.key: t.utility for t in first.raw}
    assert all(v is not None for v in saved.values())
    assert all(t.utility_saved == t.utility for t in first.raw)
    text = library_markdown(first)
    assert "(was" not in text and RELATIVE_NOTE in text
    assert read_saved(root / "wiping") == saved
    copy_takes(root / "wiping", ("dave",))  # saved later, in another tab
    second = load_library(root, "wiping")
    text = library_markdown(second)
    moved = 0
    for track in second.raw:
        if track.key in saved:
            assert track.utility_saved == saved[track.key]  # kept from the first listing
            before, now = f"{saved[track.key]:.2f}", f"{track.utility:.2f}"
            if before != now:
                assert f"{now} (was {before})" in text
                moved += 1
        else:
            assert track.utility_saved == track.utility  # the new take: kept now
    assert moved >= 1  # dave moved someone's min or max
    assert text.count("(was") == moved


def test_the_kept_values_are_written_once_and_follow_the_listing(tmp_path: Path) -> None:
    folder = tmp_path / "wiping"
    folder.mkdir()
    assert remember(folder, {"a": 0.5, "b": None}) == {"a": 0.5}
    stamp = (folder / SAVED_NAME).stat().st_mtime_ns
    assert remember(folder, {"a": 0.1}) == {"a": 0.5}  # kept, not overwritten
    assert (folder / SAVED_NAME).stat().st_mtime_ns == stamp  # nothing new: not written
    assert remember(folder, {"c": 0.7}, listed={"c"}) == {"c": 0.7}  # "a" is no longer listed
    assert sorted(p.name for p in folder.iterdir()) == [SAVED_NAME]  # no temporary file left
    (folder / SAVED_NAME).write_text("not json")
    assert read_saved(folder) == {}


def test_a_folder_that_cannot_be_written_keeps_the_marks_in_memory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import bt_teleop.takes.saved_utility as saved_utility

    def refuse(path: Path, text: str) -> None:
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(saved_utility, "_write_atomically", refuse)
    folder = tmp_path / "wiping"
    folder.mkdir()
    assert remember(folder, {"a": 0.5}) == {"a": 0.5}
    assert not (folder / SAVED_NAME).exists()
