"""The Demo and Replay pickers (issue 37): entries read like the recordings table (who, when,
θ/ρ, Ũ, ★/⚠/⊘ and why), stay unique and map back to their demo; each picker opens on the newest
usable take (Replay: the cleaned ★), follows that default until a person picks, then keeps
the pick."""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
import viser

from bt_teleop.library.listing import TaskLibrary, load_library
from bt_teleop.library.pickers import (
    NO_DEMOS,
    Picker,
    PickerOptions,
    demo_label,
    picker_options,
)
from bt_teleop.library.view import library_view
from bt_teleop.testing.harness import synthetic_task_files
from bt_teleop.ui.panels import TabControls

HOSTILE = "\u202eEve\u0007 <b>x</b>" + "z" * 40  # a right-to-left override, a bell, markup


def library_of(root: Path, n: int, **changes: dict[str, Any]) -> TaskLibrary:
    """A wiping task of `n` takes (take i recorded i s after take 0, 11-18 11:06:40 UTC on);
    `changes` maps ``"i"`` to fields to replace on raw take i."""
    files = synthetic_task_files(root, "wiping", n)
    library = load_library(root, "wiping", read=lambda path, kind: files[path])
    raw = tuple(
        dataclasses.replace(t, **changes.get(str(i), {})) for i, t in enumerate(library.raw)
    )
    return dataclasses.replace(library, raw=raw)


def with_cleaned(library: TaskLibrary) -> TaskLibrary:
    """`library` after a Clean of its usable takes (Ũ of a cleaned demo: 0.9 minus a little)."""
    cleaned = tuple(
        dataclasses.replace(
            t,
            key=t.key.replace("raw · ", "cleaned · "),
            kind="cleaned",
            source=t.key,
            utility=0.9 - 0.01 * i,
            warnings=(),
        )
        for i, t in enumerate(library.raw)
        if t.usable
    )
    return dataclasses.replace(library, cleaned=cleaned)


def offered(library: TaskLibrary, *, replay: bool) -> PickerOptions:
    """What the Replay (`replay`) or the Demo picker offers of `library`, as a tab shows it."""
    view = library_view(library)
    return picker_options(
        library, view.replay_keys if replay else view.moderation_keys, replay=replay
    )


def test_an_entry_reads_like_the_table(tmp_path: Path) -> None:
    library = library_of(
        tmp_path,
        4,
        **{
            "0": {"theta_deg": 10.0, "rho": 1.2},
            "2": {"flags": ("no_motion",), "utility": None},
            "3": {"excluded": True, "utility": None},
        },
    )
    best = library.best
    assert best is not None
    options = offered(library, replay=False)
    labels = dict(zip(options.keys, options.labels, strict=True))
    first = labels[library.raw[0].key]
    # who and when as the table and Rerun name them (its file name's time), θ and ρ
    assert first.startswith(("★ tab 0 11-18 11:06:40 · ", "tab 0 11-18 11:06:40 · "))
    assert "10°, 1.20" in first
    assert f"Ũ {library.raw[0].utility:.2f}" in first
    assert labels[best.key].startswith("★ ")
    assert sum(label.startswith("★") for label in labels.values()) == 1
    assert labels[library.raw[2].key].startswith("⚠ tab 2 11-18 11:06:42 · ")
    assert labels[library.raw[2].key].endswith("Ũ – · no motion")
    assert labels[library.raw[3].key].startswith("⊘ tab 3 ")
    assert labels[library.raw[3].key].endswith("excluded")
    assert not any("raw ·" in label or "_2026" in label for label in labels.values())


def test_replay_entries_say_raw_or_cleaned_and_the_cleaned_best_carries_the_star(
    tmp_path: Path,
) -> None:
    library = with_cleaned(library_of(tmp_path, 5))
    best = library.best
    assert best is not None
    options = offered(library, replay=True)
    labels = dict(zip(options.keys, options.labels, strict=True))
    assert all(labels[t.key].startswith("raw: ") for t in library.raw)
    assert all(labels[t.key].startswith("cleaned: ") for t in library.cleaned)
    (star,) = [t for t in library.cleaned if t.source == best.key]
    assert labels[star.key].startswith("cleaned: ★ ")
    assert labels[best.key].startswith("raw: ★ ")
    # a cleaned demo reads its take's who and when and its own Ũ (after cleaning)
    assert f"{best.demonstrator} 11-18 11:06:4" in labels[star.key]
    assert f"Ũ {star.utility:.2f}" in labels[star.key]


def test_labels_are_unique_and_map_back_to_their_demo(tmp_path: Path) -> None:
    library = library_of(tmp_path, 3)
    twin = dataclasses.replace(library.raw[0], key="raw · twin")  # alike to the second
    library = dataclasses.replace(library, raw=(*library.raw, twin))
    options = picker_options(library, [t.key for t in library.raw], replay=False)
    assert len(set(options.labels)) == len(options.labels) == 4
    assert options.label_of("raw · twin") == f"{options.label_of(library.raw[0].key)} (2)"
    for key, label in zip(options.keys, options.labels, strict=True):
        assert options.key_of(label) == key and options.label_of(key) == label
    assert options.key_of("raw · twin") is None  # a key is not a label
    empty = picker_options(library, [], replay=True)
    assert empty.labels == (NO_DEMOS,) and empty.key_of(NO_DEMOS) is None


def test_a_name_from_a_browser_is_shown_as_plain_text() -> None:
    track = SimpleNamespace(
        excluded=False,
        flags=(),
        warnings=(),
        stamp=SimpleNamespace(mtime_ns=1_795_000_000 * 10**9),
        theta_deg=0.0,
        rho=1.0,
        utility=0.5,
        kind="raw",
        demonstrator=HOSTILE,
        file=Path("imported.hdf5"),  # no time in its name: its file's modification time
    )
    label = demo_label(track, best=False)  # type: ignore[arg-type]
    assert "\u202e" not in label and "\u0007" not in label
    assert label.startswith("Eve <b>x</b>zz") and "…" in label  # cut to 24 characters
    assert "… 11-18 11:06:40 · " in label
    assert len(label) <= 110


def test_the_demo_picker_opens_on_the_newest_usable_take(tmp_path: Path) -> None:
    # the newest take is excluded, the one before it flagged: take 3 is the newest usable
    library = library_of(
        tmp_path,
        6,
        **{"5": {"excluded": True}, "4": {"flags": ("no_motion",), "utility": None}},
    )
    options = offered(library, replay=False)
    assert options.labels[0] != options.default  # the newest is not the default
    assert options.key_of(options.default) == library.raw[3].key


def test_the_replay_picker_opens_on_the_cleaned_best_else_the_newest_usable(
    tmp_path: Path,
) -> None:
    library = library_of(tmp_path, 6, **{"5": {"excluded": True}})
    before = offered(library, replay=True)  # no Clean yet: the newest usable raw take
    assert before.key_of(before.default) == library.raw[4].key
    cleaned = with_cleaned(library)
    best = cleaned.best
    assert best is not None
    (star,) = [t for t in cleaned.cleaned if t.source == best.key]
    options = offered(cleaned, replay=True)
    assert options.key_of(options.default) == star.key
    # ★'s cleaned demo is not the highest cleaned Ũ here: the default is the ★ nonetheless
    top = max(cleaned.cleaned, key=lambda t: t.utility or 0.0)
    if top.key != star.key:
        assert options.default != options.label_of(top.key)


@pytest.fixture
def controls() -> Iterator[TabControls]:
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    ctx: Any = SimpleNamespace(
        rerun=SimpleNamespace(session_url=lambda _: None, mode="off"),
        operator_token=None,
        initial_task="wiping",
        listed_demos=50,
    )
    yield TabControls(server.gui, ctx)
    server.stop()


def test_a_picker_follows_its_default_until_a_person_picks(
    controls: TabControls, tmp_path: Path
) -> None:
    assert controls.moderate_input.value == NO_DEMOS and controls.play_button.disabled
    four = library_of(tmp_path / "a", 4, **{"3": {"excluded": True}})
    controls.show_library(four)
    assert controls.demo_picker.key == four.raw[2].key  # newest usable, not the excluded one
    assert controls.moderate_input.value == controls.moderate_input.options[1]
    assert not controls.exclude_button.disabled and controls.restore_button.disabled
    five = library_of(tmp_path / "b", 5, **{"3": {"excluded": True}})
    controls.show_library(five)
    assert controls.demo_picker.key == five.raw[4].key  # a new take: the default moves to it
    assert controls.replay_picker.key == five.raw[4].key

    controls.choose_demo(five.raw[3].key)  # a person picks the excluded take
    assert controls.demo_picker.key == five.raw[3].key
    assert controls.exclude_button.disabled and not controls.restore_button.disabled
    controls.replay_picker.choose(five.raw[0].key)
    six = library_of(tmp_path / "c", 6, **{"3": {"excluded": True}})
    controls.show_library(six)  # the picks stay (under their new labels: Ũ moved)
    assert (
        controls.demo_picker.key == six.raw[3].key and controls.replay_picker.key == six.raw[0].key
    )
    assert controls.moderate_input.value == offered(six, replay=False).label_of(six.raw[3].key)
    two = library_of(tmp_path / "d", 2)
    controls.show_library(two)  # the Demo pick is gone: its default again, followed from now on
    assert controls.demo_picker.key == two.raw[1].key
    assert controls.replay_picker.key == two.raw[0].key  # still offered: kept
    three = library_of(tmp_path / "e", 3)
    controls.show_library(three)
    assert controls.demo_picker.key == three.raw[2].key
    assert controls.replay_picker.key == three.raw[0].key
    with pytest.raises(KeyError, match="does not offer"):
        controls.choose_demo("raw · nothing")


class _SlowDropdown:
    """A dropdown whose first value change pauses until released (a thread switch there)."""

    def __init__(self, options: tuple[str, ...]) -> None:
        self.options, self.value = options, options[0]
        self.entered, self.release = threading.Event(), threading.Event()
        self._first = True

    def on_update(self, callback: Any) -> Any:
        return callback

    def __setattr__(self, name: str, value: Any) -> None:
        if name == "value" and getattr(self, "_first", False):
            object.__setattr__(self, "_first", False)
            self.entered.set()
            self.release.wait(10.0)
        object.__setattr__(self, name, value)


def test_a_choice_made_while_the_library_refreshes_is_kept() -> None:
    # A script chooses a demo from one thread while the library's refresh re-labels the picker
    # from another (the demo was just excluded: its label changed). The choice must stay on the
    # demo under its new label, not on a label the picker no longer offers.
    before = PickerOptions(("a · Ũ 0.5", "b · Ũ 0.4"), ("a", "b"), "a · Ũ 0.5")
    after = PickerOptions(("a · Ũ 0.5", "⊘ b · excluded"), ("a", "b"), "a · Ũ 0.5")
    dropdown = _SlowDropdown(before.labels)
    picker = Picker(dropdown, "Demo")  # type: ignore[arg-type]
    picker.offered = before
    choose = threading.Thread(target=picker.choose, args=("b",))
    choose.start()
    assert dropdown.entered.wait(10.0)
    refresh = threading.Thread(target=picker.offer, args=(after,))
    refresh.start()
    refresh.join(0.3)  # unguarded, the refresh runs to its end here, inside the choice
    dropdown.release.set()
    choose.join(10.0)
    refresh.join(10.0)
    assert picker.key == "b" and dropdown.value == "⊘ b · excluded"
