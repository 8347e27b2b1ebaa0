"""What a save makes every tab send stays bounded as a task's takes grow (issue 10, soak memory):
the recordings table and the Demo and Replay pickers offer the newest takes, the table's and
the newest excluded ones, never every take; the counts still cover every take."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import msgspec
import numpy as np
import pytest
import viser

from bt_teleop.library.listing import TaskLibrary, load_library
from bt_teleop.library.tracks import ReplayTrack
from bt_teleop.library.view import library_view
from bt_teleop.testing.harness import synthetic_task_files
from bt_teleop.ui.panels import TabControls


def task_library(root: Path, n: int, excluded: tuple[int, ...] = ()) -> TaskLibrary:
    """A wiping task of `n` takes (take i saved i seconds after take 0); `excluded` marked so."""
    files = synthetic_task_files(root, "wiping", n)
    library = load_library(root, "wiping", read=lambda path, kind: files[path])
    raw = tuple(
        dataclasses.replace(t, excluded=True) if i in excluded else t
        for i, t in enumerate(library.raw)
    )
    return dataclasses.replace(library, raw=raw)


@pytest.fixture
def server() -> Iterator[viser.ViserServer]:
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    yield server
    server.stop()


def controls_with_log(server: viser.ViserServer) -> tuple[TabControls, list[Any]]:
    """A tab's panels on `server`, and the list every message they queue is appended to."""
    ctx: Any = SimpleNamespace(
        rerun=SimpleNamespace(session_url=lambda _: None, mode="off"),
        operator_token=None,
        initial_task="wiping",
        listed_demos=50,
    )
    controls = TabControls(server.gui, ctx)
    sent: list[Any] = []
    interface = server.gui._websock_interface
    queue = interface.queue_message

    def logged(message: Any) -> None:
        sent.append(message)
        queue(message)

    interface.queue_message = logged  # type: ignore[method-assign]
    return controls, sent


def sent_bytes(messages: list[Any]) -> int:
    """The GUI updates' payload bytes, encoded as viser encodes them (msgpack)."""
    return sum(
        len(msgspec.msgpack.encode(m.updates))
        for m in messages
        if type(m).__name__ == "GuiUpdateMessage"
    )


def test_what_a_save_sends_a_tab_does_not_grow_with_the_takes(
    server: viser.ViserServer, tmp_path: Path
) -> None:
    controls, sent = controls_with_log(server)
    per_save = {}
    for n in (100, 1000):
        before = task_library(tmp_path / f"{n}a", n)
        after = task_library(tmp_path / f"{n}b", n + 1)  # the same task after one more save
        controls.show_library(before)
        sent.clear()
        controls.show_library(after)
        per_save[n] = sent_bytes(sent)
        assert len(controls.replay_input.options) <= 3 * 50 + 2 * 12
        assert len(controls.moderate_input.options) <= 3 * 50 + 2 * 12
    assert per_save[100] > 0  # the newest take is offered: something was sent
    # the old pickers listed every take: 10 times the takes, ~10 times the bytes
    assert per_save[1000] < 1.2 * per_save[100]
    assert per_save[1000] < 12_000


def test_the_pickers_offer_the_newest_the_best_and_the_newest_excluded(tmp_path: Path) -> None:
    library = task_library(tmp_path, 300, excluded=(3, 250))
    view = library_view(library, listed=20)
    raw = library.raw
    newest = [t.key for t in sorted(raw, key=lambda t: t.stamp.mtime_ns, reverse=True)[:20]]
    assert view.moderation_keys[:20] == newest  # newest first: the picker's default
    best = library.best
    assert best is not None and best.key in view.moderation_keys
    assert raw[3].key in view.moderation_keys and raw[3].key in view.excluded
    assert raw[250].key in view.excluded
    assert len(view.moderation_keys) <= 20 + 12 + 2
    assert view.replay_keys[: len(view.moderation_keys)] == view.moderation_keys
    # the counts cover every take; a line says what the pickers offer
    assert view.markdown.startswith("300 demos of wiping, 298 usable")
    assert "offer the newest 20 of the 300 demos" in view.markdown


def test_a_small_task_offers_every_take(tmp_path: Path) -> None:
    library = task_library(tmp_path, 30)
    view = library_view(library, listed=50)
    assert sorted(view.moderation_keys) == sorted(t.key for t in library.raw)
    assert "offer" not in view.markdown


def test_cleaned_demos_of_offered_takes_and_the_best_cleaned_are_replayable(
    tmp_path: Path,
) -> None:
    library = task_library(tmp_path, 200)
    cleaned = tuple(  # the cleaned versions of the oldest takes score best
        dataclasses.replace(
            t, key=f"cleaned · {i}", kind="cleaned", source=t.key, utility=1.0 - i / 200
        )
        for i, t in enumerate(library.raw)
    )
    library = dataclasses.replace(library, cleaned=cleaned)
    view = library_view(library, listed=10)
    offered = set(view.replay_keys[len(view.moderation_keys) :])
    of_offered_raw = {t.key for t in cleaned if t.source in view.moderation_keys}
    assert of_offered_raw and of_offered_raw <= offered
    assert {f"cleaned · {i}" for i in range(10)} <= offered  # the 10 best by Ũ
    assert len(offered) <= 10 + 10 + 12


def test_listed_must_be_positive(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="listed"):
        library_view(task_library(tmp_path, 3), listed=0)


def test_listed_demos_reaches_the_app_from_bt_teleop(monkeypatch) -> None:
    import bt_teleop.app as app_module
    from bt_pipeline.exceptions import ConfigError
    from bt_teleop.app import AppOptions
    from bt_teleop.cli import teleop

    seen: list[AppOptions] = []
    monkeypatch.setattr(app_module, "serve", seen.append)  # do not bind
    teleop(listed_demos=7)
    assert seen[0].listed_demos == 7
    assert AppOptions().listed_demos == 50
    with pytest.raises(ConfigError, match="--listed-demos"):
        AppOptions(listed_demos=0)


def test_the_table_explains_the_star_and_sorts_by_rank_or_utility(tmp_path: Path) -> None:
    """When the ★ take is not the highest Ũ, one line says why (the shape gate's line, as ``bt
    score`` prints it); rows sort by rank (★ first) or by Ũ, with each take's rank shown."""
    from bt_pipeline.clean.selection import rank_takes
    from bt_teleop.library.listing import library_markdown
    from bt_teleop.takes.escape import markdown_text

    files = synthetic_task_files(tmp_path, "wiping", 60)
    library = load_library(tmp_path, "wiping", read=lambda path, kind: files[path])
    takes = [files[t.file].metrics[0] for t in library.raw]
    utility, eligible = rank_takes(takes)
    top = int(np.argmax(utility))
    assert not eligible[top] and library.best is not None  # the gate overrides Ũ in this set

    # Takes named by who and when, as the rows and pickers (a synthetic take's file name holds
    # the time of its mtime).
    def who_when(track: ReplayTrack) -> str:
        when = time.strftime("%m-%d %H:%M:%S", time.gmtime(track.stamp.mtime_ns / 1e9))
        return f"{track.demonstrator} {when}"

    assert library.best_reason.startswith(f"{who_when(library.raw[top])} has the highest Ũ")
    assert library.best_reason.endswith(f": {who_when(library.best)} is the best demo")
    by_rank = library_markdown(library, 5, "rank")
    by_utility = library_markdown(library, 5, "utility")
    assert "★ " + markdown_text(library.best_reason, 400) in by_rank
    rows = [line for line in by_rank.splitlines() if line.startswith("| ★")]
    assert rows and rows[0].split("|")[2].strip() == "1"  # ★ has rank 1
    first_row = [line for line in by_utility.splitlines() if line.startswith("| ")][1]
    assert f"{utility[top]:.2f}" in first_row and "★" not in first_row  # highest Ũ, not ★
    assert sorted(library.ranks) == list(range(1, len(library.raw) + 1))
    assert library.ranks[library.raw.index(library.best)] == 1


def test_sort_rows_reorders_the_table_in_the_tab(server: viser.ViserServer, tmp_path: Path) -> None:
    controls, _ = controls_with_log(server)
    library = task_library(tmp_path, 40)
    controls.show_library(library)
    assert "by rank" in controls.library_text.content
    controls._order = "utility"  # what a click on "by Ũ" stores
    controls._show_table(library)
    assert "by Ũ" in controls.library_text.content
