"""How a demo looks in Rerun wherever bt logs it: its name, its colour, its line width, a legend.

Names. A demo is named as the web app's page names it: who recorded it and when (UTC, to the
second), by one function, :func:`who_when`: the page shows ``Ada Lovelace 12-06 12:03:15``,
Rerun ``Ada-Lovelace_12-06_120315`` (the same who and when made an entity path part: the name
reduced to letters, digits, ``_`` and ``-``, the time's space a ``_`` and its colons dropped).
When is the time in the app's file name (``<who>_<YYYYmmddTHHMMSSZ>_<hex>.hdf5``,
:mod:`bt_teleop.takes.naming`: when Record was pressed; :func:`take_time`) when it has that
form, and who the name there; else the demo's demonstrator and ``created`` attr; a demo with
no time is named ``<who>_<file stem>_<demo>``. A name is an entity path part: letters, digits,
``_`` and ``-`` only (whatever a browser sent is reduced to them, never used as it came), at most
:data:`MAX_NAME_CHARS` characters, and unique within its set (a repeat gets ``_2``, ``_3``, ...).

Colours. Demo i of a set gets colour i of tab10 (a qualitative palette, cycled). A raw demo and
its cleaned version share that hue: the cleaned one is drawn in the full colour and wide
(:data:`CLEANED_RADIUS_UI`), the raw one lighter (blended towards white) and thin
(:data:`RAW_RADIUS_UI`). :func:`legend_markdown` lists each name with its colour's name.
"""

from __future__ import annotations

import re
import unicodedata
from collections.abc import Iterable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from bt_pipeline.data.demo import Demo

__all__ = [
    "CLEANED_RADIUS_UI",
    "COLOR_NAMES",
    "RAW_RADIUS_UI",
    "cleaned_color",
    "color_name",
    "demo_color",
    "demo_colors",
    "demo_names",
    "display_name",
    "entity_part",
    "legend_markdown",
    "name_from_stem",
    "palette_index",
    "raw_color",
    "take_time",
    "unique_names",
    "who_when",
]

_TAB10 = "1f77b4 ff7f0e 2ca02c d62728 9467bd 8c564b e377c2 7f7f7f bcbd22 17becf"
_PALETTE = np.array([list(bytes.fromhex(c)) for c in _TAB10.split()], dtype=np.uint8)  # (10, 3)
COLOR_NAMES = ("blue", "orange", "green", "red", "purple", "brown", "pink", "grey", "olive", "cyan")
"""Names of the palette's colours, for the legend."""
RAW_LIGHTEN = 0.45
"""A raw demo's colour: its hue blended this far towards white."""
RAW_RADIUS_UI = 0.75
"""Line radius of a raw demo [UI points]."""
CLEANED_RADIUS_UI = 2.0
"""Line radius of a cleaned demo [UI points]."""
MAX_WHO_CHARS = 32
"""Longest demonstrator part of a name (as the app's file names)."""
MAX_NAME_CHARS = 80
"""Longest name, before a ``_<k>`` that makes it unique."""
ANONYMOUS = "anonymous"

_APP_STEM = re.compile(r"^(?P<who>[A-Za-z0-9_-]+?)_(?P<stamp>\d{8}T\d{6}Z)_[0-9a-f]{1,16}$")
_NOT_ALLOWED = re.compile(r"[^A-Za-z0-9_-]+")
_SAFE = re.compile(r"[A-Za-z0-9_-]+")

Rgb = tuple[int, int, int]
Rgba = tuple[int, int, int, int]


def entity_part(text: str, max_chars: int = MAX_NAME_CHARS) -> str:
    """`text` as an entity path part: accents dropped, runs of other characters than letters,
    digits, ``_`` and ``-`` made one ``-``, at most `max_chars`; "" when nothing is left."""
    ascii_text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode("ascii")
    return _NOT_ALLOWED.sub("-", ascii_text).strip("-_")[:max_chars].strip("-_")


WHEN_FORMAT = "%m-%d %H:%M:%S"
"""How the page shows when a demo was recorded (UTC): ``12-06 12:03:15``."""


def who_when(who: str, when: datetime, *, entity: bool = False, sep: str = " ") -> str:
    """Who recorded a demo and when, as every view names it (module docstring).

    Args:
        who: The demonstrator's name (the page: escape it for where it is shown first).
        when: When the take was recorded (a naive time is taken to be UTC).
        entity: The Rerun entity path part (``Ada-Lovelace_12-06_120315``) rather than the
            page's text (``Ada Lovelace 12-06 12:03:15``).
        sep: The page's text between who and when (e.g. a line break in a table cell).
    """
    if when.tzinfo is None:
        when = when.replace(tzinfo=UTC)
    text = when.astimezone(UTC).strftime(WHEN_FORMAT)
    if not entity:
        return f"{who}{sep}{text}"
    part = entity_part(who, MAX_WHO_CHARS) or ANONYMOUS
    return f"{part}_{text.replace(' ', '_').replace(':', '')}"


def take_time(stem: str) -> datetime | None:
    """The UTC time in an app file stem (``<who>_<YYYYmmddTHHMMSSZ>_<hex>``), else None."""
    parsed = _parse_stem(stem)
    return None if parsed is None else parsed[1]


def name_from_stem(stem: str) -> str | None:
    """``<who>_<mm-dd>_<HHMMSS>`` (:func:`who_when`) from an app file stem ``<who>_<UTC
    stamp>_<hex>``, else None."""
    parsed = _parse_stem(stem)
    return None if parsed is None else who_when(*parsed, entity=True)


def _parse_stem(stem: str) -> tuple[str, datetime] | None:
    """(who, when) of an app file stem, else None."""
    match = _APP_STEM.match(stem)
    if match is None:
        return None
    try:
        when = datetime.strptime(match["stamp"], "%Y%m%dT%H%M%SZ").replace(tzinfo=UTC)
    except ValueError:
        return None
    return match["who"], when


def display_name(demonstrator: str, created: str | None, file: str, demo: str) -> str:
    """A demo's name (module docstring); not yet unique (:func:`unique_names`).

    Args:
        demonstrator: Who recorded it (free text).
        created: Its ISO 8601 creation time, or None.
        file: The file it came from ("" when built in memory).
        demo: Its name in that file (``demo_<k>``).
    """
    stem = Path(file).stem if file else ""
    from_file = name_from_stem(stem)
    if from_file is not None:
        return from_file
    who = entity_part(demonstrator, MAX_WHO_CHARS) or ANONYMOUS
    when: datetime | None = None
    if created:
        try:
            when = datetime.fromisoformat(created)
        except ValueError:
            when = None
    if when is not None:
        return who_when(who, when, entity=True)
    tail = "_".join(p for p in (entity_part(stem), demo) if p)
    return entity_part(f"{who}_{tail}") or ANONYMOUS


def unique_names(names: Iterable[str]) -> tuple[str, ...]:
    """`names` in order, each repeat given ``_2``, ``_3``, ... (never another demo's name)."""
    names = list(names)
    own = set(names)
    used: set[str] = set()
    out = []
    for name in names:
        unique, k = name, 1
        while unique in used or (unique != name and unique in own):
            k += 1
            unique = f"{name}_{k}"
        used.add(unique)
        out.append(unique)
    return tuple(out)


def demo_names(demos: Sequence[Demo]) -> tuple[str, ...]:
    """Unique names of `demos` as the page names them (module docstring)."""
    return unique_names(display_name(d.demonstrator, d.created, d.file, d.name) for d in demos)


def demo_color(index: int) -> Rgb:
    """Demo `index`'s colour (tab10, cycled), RGB."""
    r, g, b = (int(c) for c in _PALETTE[index % len(_PALETTE)])
    return r, g, b


def demo_colors(n_demos: int) -> np.ndarray:
    """One RGB colour per demo (tab10, cycled), shape (M, 3), uint8."""
    return _PALETTE[np.arange(n_demos) % len(_PALETTE)]


def raw_color(rgb: Sequence[int], alpha: int = 220) -> Rgba:
    """A raw demo's colour: `rgb` lighter (blended towards white by :data:`RAW_LIGHTEN`)."""
    r, g, b = (round(c + RAW_LIGHTEN * (255 - c)) for c in rgb[:3])
    return r, g, b, alpha


def cleaned_color(rgb: Sequence[int]) -> Rgba:
    """A cleaned demo's colour: `rgb` itself, opaque."""
    r, g, b = (int(c) for c in rgb[:3])
    return r, g, b, 255


def palette_index(rgb: Sequence[int]) -> int:
    """The palette index of colour `rgb` (one of :func:`demo_color`'s), else 7 (grey)."""
    hits = np.flatnonzero((np.asarray(rgb[:3]) == _PALETTE).all(axis=1))
    return int(hits[0]) if hits.size else 7


def color_name(index: int) -> str:
    """The name of demo `index`'s colour."""
    return COLOR_NAMES[index % len(COLOR_NAMES)]


def legend_markdown(
    names: Sequence[str],
    best: int | None = None,
    cleaned: bool = True,
    color_indices: Sequence[int] | None = None,
) -> str:
    """A Markdown legend: each demo's colour name and name; `best` is marked ★; `cleaned`: say
    how raw and cleaned lines differ.

    Demo i has colour `color_indices[i]` (default i). Names are entity path parts
    (:func:`demo_names`), shown as code so that nothing in them is read as Markdown.
    """
    indices = range(len(names)) if color_indices is None else color_indices
    head = "**Demos**: one colour each"
    if cleaned:
        head += "; raw thin and light, cleaned wide and in the full colour"
    rows = ["| colour | demo |", "|---|---|"]
    for i, (name, index) in enumerate(zip(names, indices, strict=True)):
        safe = name if _SAFE.fullmatch(name) else (entity_part(name) or ANONYMOUS)
        star = " ★ best" if i == best else ""
        rows.append(f"| {color_name(index)} | `{safe}`{star} |")
    return head + ".\n\n" + "\n".join(rows) + "\n"
