"""Text that came from a browser, made safe to show: the one place the app escapes it.

Names, task labels and notes typed in one tab are shown in every other tab (the recordings
table, notifications, status lines) and in the Rerun viewer. viser renders Markdown with raw
HTML enabled, so an unescaped ``<script>`` or ``<b>`` in a name is markup in every tab; an
unclosed tag even hides the rest of the table. Every function here turns untrusted text into
text that renders as exactly the characters typed (minus invisible control characters)::

    display_text(s)   -> plain text: control and bidirectional-override characters removed,
                         whitespace collapsed, cut to a length with "…" (Rerun, logs)
    markdown_text(s)  -> display_text, then every character that means something in Markdown
                         or HTML written as a numeric character reference (``&#60;`` for ``<``),
                         so it renders as text inside paragraphs and table cells alike
    html_text(s)      -> display_text, then HTML-escaped (``add_html`` content, attributes)
    breakable(s)      -> plain text that may wrap after ``_ - / .`` (a zero-width space):
                         notifications show long file names whole instead of cutting them

What is stored keeps the name as typed (:func:`bt_teleop.takes.naming.clean_demonstrator`); file
names are sanitised separately (:func:`bt_teleop.takes.naming.sanitize_name`).
"""

from __future__ import annotations

import html
import unicodedata

__all__ = ["MARKDOWN_SPECIALS", "breakable", "display_text", "html_text", "markdown_text"]

ZERO_WIDTH_SPACE = "\u200b"

MARKDOWN_SPECIALS = frozenset("\\`*_{}[]()<>#+-.!|~&\"'=:;/$@^%")
"""Characters written as character references by :func:`markdown_text`."""
_BIDI_CONTROLS = frozenset(
    "\u061c\u200e\u200f\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069"
)
"""Directional marks, embeddings, overrides and isolates: they would reorder the text after
them (a right-to-left override turns ``gpj.exe`` into ``exe.jpg``)."""


def display_text(text: object, max_chars: int = 64) -> str:
    """`text` as one line of plain text to show.

    Control characters (C0, C1, zero-width format characters) and bidirectional overrides are
    dropped, runs of whitespace become one space, and text longer than `max_chars` characters
    is cut to ``max_chars - 1`` characters and "…". Letters of every script and emoji are
    kept.

    Args:
        text: Anything; ``str(text)`` is shown.
        max_chars: Longest result [characters], at least 1.
    """
    kept = []
    for ch in str(text):
        if ch in _BIDI_CONTROLS:
            continue
        category = unicodedata.category(ch)
        if category in ("Cc", "Zl", "Zp") or ch.isspace():
            kept.append(" ")
        elif category in ("Cf", "Cs", "Co", "Cn") and ch not in "\u200d\ufe0f":
            continue  # invisible format characters; keep the emoji joiner and selector
        else:
            kept.append(ch)
    line = " ".join("".join(kept).split())
    limit = max(1, int(max_chars))
    if len(line) > limit:
        line = line[: limit - 1].rstrip() + "…"
    return line


def markdown_text(text: object, max_chars: int = 64) -> str:
    """`text` as Markdown that renders as the characters themselves, in a paragraph or a table
    cell (``|`` included), with raw HTML enabled or not.

    Args:
        text: Anything; ``str(text)`` is shown.
        max_chars: Longest shown text [characters] before escaping (see :func:`display_text`).
    """
    line = display_text(text, max_chars)
    return "".join(f"&#{ord(ch)};" if ch in MARKDOWN_SPECIALS else ch for ch in line)


def html_text(text: object, max_chars: int = 64) -> str:
    """`text` as HTML text or a quoted attribute value that shows the characters themselves.

    Args:
        text: Anything; ``str(text)`` is shown.
        max_chars: Longest shown text [characters] before escaping (see :func:`display_text`).
    """
    return html.escape(display_text(text, max_chars), quote=True)


def breakable(text: object, max_chars: int = 300) -> str:
    """:func:`display_text` with a zero-width space after every ``_``, ``-``, ``/`` and ``.``,
    so a narrow box (a notification) wraps a long file name instead of cutting it."""
    line = display_text(text, max_chars)
    return "".join(ch + ZERO_WIDTH_SPACE if ch in "_-/." else ch for ch in line)
