"""Every relative link in the project's Markdown resolves: the file exists and, with a ``#``
fragment, the target holds a heading (or an explicit ``<a id>``) of that anchor, slugged as
GitHub slugs headings. Links to web addresses are not followed."""

from __future__ import annotations

import re
import urllib.parse
from collections import Counter
from functools import cache
from pathlib import Path

from markdown_it import MarkdownIt
from markdown_it.token import Token

REPO = Path(__file__).resolve().parents[2]
SKIPPED_DIRS = {"out", "build", "dist", "node_modules", "__pycache__"}
"""Folders of outputs and tools, not the project's docs (and any folder whose name starts
with a dot: .git, .venv, caches)."""

_PARSER = MarkdownIt("commonmark").enable("table")
_EXPLICIT_ANCHOR = re.compile(r"""<a\s+(?:id|name)=["']([^"']+)["']""")
_NOT_IN_SLUG = re.compile(r"[^\w\- ]")


def markdown_files(root: Path) -> list[Path]:
    """The ``*.md`` files under `root`, outputs and hidden folders left out."""
    return sorted(
        path
        for path in root.rglob("*.md")
        if not any(
            part.startswith(".") or part in SKIPPED_DIRS
            for part in path.relative_to(root).parts[:-1]
        )
    )


def slug(heading: str) -> str:
    """The anchor GitHub gives a heading's text: lower case, punctuation but ``-`` and ``_``
    dropped, each space a ``-``."""
    return _NOT_IN_SLUG.sub("", heading.strip().lower()).replace(" ", "-")


def _inline_text(token: Token) -> str:
    """The text of an inline token as GitHub reads it for a slug (code spans included)."""
    return "".join(child.content for child in token.children or () if child.content)


@cache
def anchors(path: Path) -> frozenset[str]:
    """The anchors of a Markdown file: its headings' slugs (repeats numbered ``-1``, ``-2``
    as GitHub numbers them) and its explicit ``<a id=...>`` / ``<a name=...>``."""
    text = path.read_text(encoding="utf-8")
    tokens = _PARSER.parse(text)
    seen: Counter[str] = Counter()
    found: set[str] = set(_EXPLICIT_ANCHOR.findall(text))
    for i, token in enumerate(tokens):
        if token.type == "heading_open":
            base = slug(_inline_text(tokens[i + 1]))
            found.add(base if not seen[base] else f"{base}-{seen[base]}")
            seen[base] += 1
    return frozenset(found)


def links(path: Path) -> list[str]:
    """Every link and image target of a Markdown file (not those inside code)."""
    targets: list[str] = []
    for token in _PARSER.parse(path.read_text(encoding="utf-8")):
        for child in token.children or ():
            if child.type == "link_open":
                targets.append(str(child.attrs.get("href", "")))
            elif child.type == "image":
                targets.append(str(child.attrs.get("src", "")))
    return targets


def broken_links(path: Path) -> list[str]:
    """The relative links of `path` that do not resolve, each with the reason."""
    problems = []
    for target in links(path):
        parsed = urllib.parse.urlsplit(target)
        if parsed.scheme or parsed.netloc:
            continue  # a web address (http, https, mailto): not followed
        file_part = urllib.parse.unquote(parsed.path)
        fragment = urllib.parse.unquote(parsed.fragment)
        linked = (path.parent / file_part).resolve() if file_part else path
        if not linked.exists():
            problems.append(f"{target}: no file {file_part}")
        elif fragment and linked.suffix == ".md" and fragment not in anchors(linked):
            problems.append(f"{target}: no heading #{fragment} in {linked.name}")
    return problems


def test_every_relative_link_and_anchor_resolves() -> None:
    files = markdown_files(REPO)
    assert REPO / "README.md" in files and len(files) > 5
    broken = {
        str(path.relative_to(REPO)): problems for path in files if (problems := broken_links(path))
    }
    assert broken == {}


def test_a_missing_file_or_heading_is_reported(tmp_path: Path) -> None:
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "page.md").write_text(
        "# A page\n\n## The task's loop: learned (θ/ρ)\n\n## Speed (`bench_x.py --runs 5`)\n"
        '\n## Repeated\n\n## Repeated\n\n<a id="kept"></a>\n'
    )
    (tmp_path / "README.md").write_text(
        "[ok](docs/page.md#the-tasks-loop-learned-θρ) [ok](docs/page.md#speed-bench_xpy---runs-5)"
        " [ok](docs/page.md#repeated-1) [ok](docs/page.md#kept) [web](https://example.org/x)\n"
        "[gone](docs/missing.md) [no anchor](docs/page.md#not-there) [self](#nowhere)\n"
        "`[in code](docs/nothing.md)`\n\n```\n[in a block](docs/nothing.md)\n```\n"
    )
    assert markdown_files(tmp_path) == [tmp_path / "README.md", tmp_path / "docs" / "page.md"]
    assert broken_links(tmp_path / "README.md") == [
        "docs/missing.md: no file docs/missing.md",
        "docs/page.md#not-there: no heading #not-there in page.md",
        "#nowhere: no heading #nowhere in README.md",
    ]
