"""bt_teleop.takes.escape: hostile text from a browser renders as the characters typed, nowhere as
markup. Checked by rendering with a CommonMark + GFM renderer that passes raw HTML through (as
viser's page does): no tag survives, every table keeps its rows and columns."""

from __future__ import annotations

import html
import re

import pytest
from markdown_it import MarkdownIt

from bt_teleop.takes.escape import breakable, display_text, html_text, markdown_text

HOSTILE = [
    "<script>alert(1)</script>",
    "<script>alert(1)",
    "<b>bold</b>",
    "<img src=x onerror=alert(1)>",
    "**bold** _it_ `code` [link](http://evil) ![img](x)",
    "a | b | c",
    "# heading",
    "- item",
    "1. item",
    "&lt;b&gt; entity",
    "\u202egpj.exe",
    "ab\x00cd\x1b[31m\x07",
    "line\nbreak\r\nand\ttab",
    "😀👩‍🔬 emoji",
    "مرحبا שלום",
    "x" * 5000,
]

RENDER = MarkdownIt("commonmark", {"html": True}).enable("table")


def visible_text(rendered_html: str) -> str:
    """The text a browser shows for `rendered_html` (tags dropped, entities decoded)."""
    return html.unescape(re.sub(r"<[^>]+>", "", rendered_html))


@pytest.mark.parametrize("name", HOSTILE)
def test_markdown_text_renders_as_the_characters_typed(name: str) -> None:
    shown = display_text(name, 64)
    rendered = RENDER.render(markdown_text(name, 64))
    assert visible_text(rendered).strip() == shown
    tags = set(re.findall(r"</?([a-zA-Z0-9]+)", rendered))
    assert tags <= {"p"}, rendered  # no <script>, <b>, <img>, <a>, <h1>, <li>, <code>, <em>


@pytest.mark.parametrize("name", HOSTILE)
def test_a_hostile_name_in_a_table_keeps_every_row_and_column(name: str) -> None:
    cell = markdown_text(name, 24)
    table = "\n".join(["| who | s |", "|---|---|", f"| {cell} | 1 |", "| ada | 2 |"])
    rendered = RENDER.render(table)
    assert rendered.count("<tr>") == 3
    assert rendered.count("<td>") == 4
    assert "<script" not in rendered and "<b>" not in rendered and "<img" not in rendered


def test_display_text_drops_controls_and_bidi_overrides_and_keeps_letters_and_emoji() -> None:
    assert display_text("\u202egpj.exe") == "gpj.exe"
    assert display_text("ab\x00cd\x1b") == "ab cd"
    assert display_text("a\n\n b\t c") == "a b c"
    assert display_text("😀👩‍🔬 Zoë مرحبا") == "😀👩‍🔬 Zoë مرحبا"


def test_long_text_is_cut_with_an_ellipsis() -> None:
    assert display_text("x" * 100, 10) == "x" * 9 + "…"
    assert len(display_text("y" * 5000)) == 64
    assert display_text("short", 10) == "short"


def test_html_text_escapes_markup_and_quotes() -> None:
    assert html_text('<a href="x">') == "&lt;a href=&quot;x&quot;&gt;"
    assert html_text("it's") == "it&#x27;s"


def test_breakable_text_wraps_at_separators_and_reads_the_same() -> None:
    name = "script-alert-1-script_20261201T173559Z_4d9f83.hdf5"
    text = breakable(name)
    assert text.replace("\u200b", "") == name
    assert max(len(part) for part in text.split("\u200b")) <= 17  # no long unbreakable run
    assert breakable("<b>x</b>\x00") == "<b>x</\u200bb>"  # plain text, controls gone
