"""The Demo and Replay pickers' entries: each demo read as the recordings table reads it.

A picker used to show bare keys (``raw · Ada-Lovelace_20261206T120315Z_3fa2c1``), cut off by the
dropdown's width, and opened on whatever came first. Here each offered demo gets a label with
what tells takes apart, and each picker a default::

    label     [cleaned: | raw:] mark who when · θ, ρ · Ũ [· note]
              mark ★ the best usable demo (a cleaned demo: cleaned from it), ⚠ flagged or worth
              a look, ⊘ excluded; who when = who recorded the take and when, as the table and
              Rerun name it (``Ada Lovelace 12-06 12:03:15``, UTC; a cleaned demo: its raw
              take's; :func:`bt_teleop.library.tracks.track_who_when`); note = the take
              checks' flags and warnings, "excluded"
    default   Demo:   the newest usable take (neither flagged nor excluded), else the newest
              Replay: the cleaned ★ (else the best cleaned demo by Ũ), else the newest usable
                      raw take, else the first offered

Labels are unique within a picker (a repeat gets `` (2)``, `` (3)``) and map back to their
demo's key (:class:`PickerOptions`). The demonstrator's name came from a browser: it is shown
through :func:`bt_teleop.takes.escape.display_text` (the dropdown renders options as text, never as
HTML or Markdown; control and bidirectional-override characters are dropped).

A :class:`Picker` is one such dropdown in a tab: it shows the labels, answers with keys, and
follows its default as the library changes until the person picks an entry in the browser;
then it keeps that entry (under its new label: Ũ and marks change) while it is offered.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import viser

from bt_teleop.library.listing import TaskLibrary
from bt_teleop.library.tracks import ReplayTrack, track_who_when
from bt_teleop.takes.escape import display_text

__all__ = ["EMPTY", "NO_DEMOS", "Picker", "PickerOptions", "demo_label", "picker_options"]

NO_DEMOS = "(no demos yet)"
"""A picker's only option while the task has no demos."""
MAX_LABEL_CHARS = 110
"""Longest label [characters] (the name is cut first, to 24)."""


@dataclass(frozen=True)
class PickerOptions:
    """What one picker offers: labels shown, the demo key of each, and the default choice."""

    labels: tuple[str, ...]
    """Shown in the dropdown, in order, unique (``(NO_DEMOS,)`` when nothing is offered)."""
    keys: tuple[str, ...]
    """The key of the demo of each label (``("",)`` for the placeholder)."""
    default: str
    """The label chosen when the picker's choice is not offered (or was never made)."""

    def key_of(self, label: str) -> str | None:
        """The key of the demo shown as `label` (None: not a label of this picker)."""
        try:
            key = self.keys[self.labels.index(label)]
        except ValueError:
            return None
        return key or None

    def label_of(self, key: str) -> str | None:
        """The label of demo `key` (None: not offered)."""
        try:
            return self.labels[self.keys.index(key)]
        except ValueError:
            return None


EMPTY = PickerOptions((NO_DEMOS,), ("",), NO_DEMOS)
"""A picker with nothing to offer."""


def demo_label(
    track: ReplayTrack, *, best: bool, saved_ns: int | None = None, kind_prefix: bool = False
) -> str:
    """`track` as a picker shows it (see the module docstring).

    Args:
        track: A listed demo.
        best: Whether to mark it ★ (the best raw demo, or cleaned from it).
        saved_ns: When its take was saved [ns since the epoch], for a file whose name holds no
            time (:func:`bt_teleop.library.tracks.track_who_when`); its file's mtime when None.
        kind_prefix: Start with ``raw:`` or ``cleaned:`` (a picker offering both).
    """
    if track.excluded:
        mark = "⊘"
    else:
        mark = ("★" if best else "") + ("⚠" if track.flags or track.warnings else "")
    if math.isnan(track.theta_deg) or math.isnan(track.rho):
        pref = "θ, ρ ?"
    else:
        pref = f"{track.theta_deg:.0f}°, {track.rho:.2f}"
    score = "Ũ –" if track.utility is None else f"Ũ {track.utility:.2f}"
    notes = [f.replace("_", " ") for f in (*track.flags, *track.warnings)]
    if track.excluded:
        notes.append("excluded")
    head = f"{track.kind}: " if kind_prefix else ""
    who_when = track_who_when(track, saved_ns)
    parts = [f"{head}{mark} {who_when}".strip(), pref, score]
    if notes:
        parts.append(display_text(", ".join(notes), 40))
    return display_text(" · ".join(parts), MAX_LABEL_CHARS)


def picker_options(library: TaskLibrary, keys: list[str], *, replay: bool) -> PickerOptions:
    """The labels and default of a picker offering the demos `keys` of `library`, in order.

    Args:
        library: The task's library (`keys` are its tracks' keys; unknown keys are left out).
        keys: What the picker offers (:func:`bt_teleop.library.view.library_view`), raw
            newest first, then (Replay) cleaned.
        replay: The Replay picker (raw and cleaned, labels prefixed with the kind, default
            the cleaned ★) rather than the Demo picker (raw only).
    """
    by_key = {t.key: t for t in library.tracks}
    tracks = [by_key[k] for k in keys if k in by_key]
    if not tracks:
        return EMPTY
    best = library.best
    best_key = "" if best is None else best.key
    saved_ns = {t.key: t.stamp.mtime_ns for t in library.raw}
    labels: list[str] = []
    taken: set[str] = set()
    for track in tracks:
        is_best = bool(best_key) and best_key in (track.key, track.source)
        base = demo_label(
            track, best=is_best, saved_ns=saved_ns.get(track.source), kind_prefix=replay
        )
        label, n = base, 1
        while label in taken:  # two takes alike to the second: tell them apart
            n += 1
            label = f"{base} ({n})"
        taken.add(label)
        labels.append(label)
    chosen = _default(tracks, best_key, replay)
    return PickerOptions(tuple(labels), tuple(t.key for t in tracks), labels[chosen])


def _default(tracks: list[ReplayTrack], best_key: str, replay: bool) -> int:
    """Index in `tracks` (raw newest first, then cleaned) of the picker's default."""
    if replay:
        cleaned = [i for i, t in enumerate(tracks) if t.kind == "cleaned"]
        starred = [i for i in cleaned if best_key and tracks[i].source == best_key]
        if starred:
            return starred[0]
        scored = [i for i in cleaned if tracks[i].utility is not None]
        if scored:
            return max(scored, key=lambda i: tracks[i].utility or 0.0)
    raw = [i for i, t in enumerate(tracks) if t.kind == "raw"]
    usable = [i for i in raw if tracks[i].usable]
    if usable:
        return max(usable, key=lambda i: (tracks[i].stamp.mtime_ns, -i))
    return 0


class Picker:
    """One dropdown of demos in a tab (see the module docstring)."""

    def __init__(self, dropdown: viser.GuiDropdownHandle[str], name: str) -> None:
        """Drive `dropdown` (called `name` in messages), offering nothing yet."""
        self.dropdown = dropdown
        self.name = name
        self.offered: PickerOptions = EMPTY
        """What it offers now."""
        self.follows_default = True
        """No entry picked in the browser since the choice was last reset to the default."""
        # A script's choice (another thread) and the library's refresh each read the offered
        # labels and then set the value: interleaved, a choice lands as a label no longer
        # offered (a CI run saw Restore stay disabled). Each runs whole under this lock.
        self._lock = threading.RLock()

        @dropdown.on_update
        async def _(event: viser.GuiEvent) -> None:
            if event.client is not None:  # picked in the browser (the server's own sets: None)
                self.follows_default = False

    @property
    def key(self) -> str:
        """The chosen demo's key (the value itself when it is no label, e.g. a key a script
        sent: the library then finds it or says what is valid)."""
        value = self.dropdown.value
        return self.offered.key_of(value) or value

    def choose(self, key: str) -> None:
        """Choose demo `key` as a person would (scripts, tests).

        Raises:
            KeyError: It does not offer `key`.
        """
        with self._lock:
            label = self.offered.label_of(key)
            if label is None:
                raise KeyError(f"the {self.name} picker does not offer {key!r}")
            self.follows_default = False
            self.dropdown.value = label

    def offer(self, options: PickerOptions) -> None:
        """Offer `options`: the default while it follows it, else the demo chosen while it is
        offered, else the default again (and follow it)."""
        with self._lock:
            chosen = self.offered.key_of(self.dropdown.value)
            self.offered = options
            label = None if self.follows_default or chosen is None else options.label_of(chosen)
            if label is None:
                label, self.follows_default = options.default, True
            if tuple(self.dropdown.options) != options.labels:
                self.dropdown.options = options.labels
            if self.dropdown.value != label:
                self.dropdown.value = label
