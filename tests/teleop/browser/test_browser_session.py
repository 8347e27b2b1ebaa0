"""One recorded session reads the same in the page, ``bt score`` and Rerun (issue 37, "Done
when"), in a real browser (Debian's headless Chromium, as tests/teleop/browser/test_browser.py).

The task folder starts with four real browser takes (``../shared/data/browser-takes``: alice,
bob, carol and dave, dragged in Chromium). The page then records a loop of its own through its
buttons (a circle: the target follows it as a drag of the gizmo moves it, so it is usable but
off the guide) and a junk take (Record, then Stop & save at once: flagged), cleans and replays.
The circle has the highest Ũ but is off the guide, so bob's take is the best and the ★ line
says why. Then:

* (a) the Ũ each row of the page's table shows is ``bt score --json``'s (run as a subprocess on
  the same folder), to the two decimals shown, and so are the ranks and the ★ row;
* (b) the ★ line is ``bt score``'s reason, naming the takes by who and when;
* (c) the Demo picker opens on the newest usable take (the circle, not the newer junk take) and,
  after Clean, the Replay picker on the cleaned ★;
* (d) the session's Rerun recording and its Clean's name each take as the page does (who and
  when, as an entity path part), read back from the .rrd files the app wrote (``--rerun save``).

Expected names come from the file names (``<who>_<UTC time>_<hex>``), not from the app's code.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from datetime import datetime
from pathlib import Path
from typing import Any

from playwright.sync_api import Page, expect
from rerun.chunk import RrdReader

from bt_teleop.testing.harness import (
    app_factory,
    chromium_page,
    circle_uv,
    open_tab,
    record_in_page,
    shared_dir,
    type_name,
    wait_until,
)
from tests.teleop.browser.conftest import PAGE_TIMEOUT_MS

expect.set_options(timeout=PAGE_TIMEOUT_MS)  # software WebGL on a busy machine is slow
TAKES = shared_dir() / "data/browser-takes/wiping"
PLACED = ("alice_", "bob_", "carol_", "dave_")
"""Careful loops along the guide; dave's has the highest Ũ of them, bob's follows it closest."""
NAME = "Ada Lovelace"


def names_of(path: Path, demonstrator: str) -> tuple[str, str]:
    """(the page's who and when, Rerun's entity name) of an app take, from its file name."""
    who, stamp, _ = path.stem.rsplit("_", 2)
    when = datetime.strptime(stamp, "%Y%m%dT%H%M%SZ")
    return f"{demonstrator} {when:%m-%d %H:%M:%S}", f"{who}_{when:%m-%d_%H%M%S}"


def table_rows(page: Page) -> dict[str, list[str]]:
    """The recordings table as the page shows it: who and when -> the row's cells (whitespace
    collapsed), read from the DOM."""
    tables: list[list[list[str]]] = page.evaluate(
        """() => Array.from(document.querySelectorAll('table')).map(
            t => Array.from(t.rows).map(r => Array.from(r.cells).map(c => c.innerText)))"""
    )
    (rows,) = [t for t in tables if t and "who, when" in t[0][2]]
    header = [" ".join(c.split()) for c in rows[0]]
    assert header == ["", "#", "who, when", "θ, ρ", "s", "Ũ", "note"], header
    cells = [[" ".join(c.split()) for c in row] for row in rows[1:]]
    return {row[2]: row for row in cells}


def star_lines(page: Page) -> list[str]:
    """The page's paragraphs that start with ★ (the line under the table)."""
    texts: list[str] = page.evaluate(
        "() => Array.from(document.querySelectorAll('p')).map(p => p.innerText)"
    )
    return [" ".join(t.split()) for t in texts if t.startswith("★ ")]


def bt_score(folder: Path) -> dict[str, Any]:
    """``bt score FOLDER --json`` in a process of its own: its one task."""
    done = subprocess.run(
        [sys.executable, "-m", "bt_pipeline", "score", str(folder), "--json"],
        capture_output=True,
        text=True,
        check=True,
        env=os.environ,
        timeout=300,
    )
    (task,) = json.loads(done.stdout)["tasks"]
    return task


def rrd_entities(path: Path) -> dict[str, dict[str, list[Any]]]:
    """Each entity of an .rrd: the values of its text components (labels, documents) and
    whether each of its chunks is static (``"static"``)."""
    out: dict[str, dict[str, list[Any]]] = {}
    for chunk in RrdReader(path).store().stream().to_chunks():
        batch = chunk.to_record_batch()
        columns = out.setdefault(chunk.entity_path, {})
        columns.setdefault("static", []).append(chunk.is_static)
        for name in batch.schema.names:
            if name.endswith((":labels", ":text")):
                columns.setdefault(name, []).extend(batch.column(name).to_pylist())
    return out


def test_a_session_reads_the_same_in_the_page_bt_score_and_rerun(tmp_path: Path) -> None:
    root = tmp_path / "recordings"
    folder = root / "wiping"
    folder.mkdir(parents=True)
    for path in sorted(TAKES.glob("*.hdf5")):
        if path.name.startswith(PLACED):
            shutil.copy2(path, folder / path.name)
    with (
        app_factory(root) as make,
        chromium_page(viewport={"width": 1400, "height": 900}, timeout_ms=PAGE_TIMEOUT_MS) as page,
    ):
        app = make(rerun="save", clean_epochs=1)
        ui = open_tab(page, app)
        type_name(page, ui, NAME)
        circle = record_in_page(page, ui, circle_uv, seconds=5.0)
        junk = record_in_page(page, ui, None)  # Record, then Stop & save at once
        assert junk.stat().st_mtime_ns > circle.stat().st_mtime_ns  # the newest take
        wait_until(lambda: ui.library is not None and len(ui.library.raw) == 6, 60.0, "6 takes")
        expect(page.get_by_text("6 demos of wiping, 5 usable", exact=False)).to_be_visible()

        scored = bt_score(folder)  # the same files, as the command line scores them
        by_file = {Path(d["file"]).name: d for d in scored["demos"]}
        assert len(by_file) == 5 and junk.name not in by_file  # flagged: not scored
        page_name = {
            name: names_of(folder / name, d["demonstrator"])[0] for name, d in by_file.items()
        }
        page_name[junk.name] = names_of(junk, NAME)[0]

        # (c) The Demo picker opens on the newest usable take: the circle, not the junk take.
        demo_default = page.get_by_role("combobox", name="Demo")
        expect(demo_default).to_have_value(re.compile("^⚠ " + re.escape(page_name[circle.name])))
        circle_u = by_file[circle.name]["utility"]
        assert f" · Ũ {circle_u:.2f} · " in demo_default.input_value()  # bt score's Ũ

        # (a) Each row's Ũ and rank are bt score's, to the two decimals shown; the junk take has
        # none; the ★ row is bt score's best.
        rows = table_rows(page)
        assert set(rows) == set(page_name.values())
        for name, d in by_file.items():
            _, rank, _, _, _, utility, _ = rows[page_name[name]]
            assert utility.split()[0] == f"{d['utility']:.2f}", (name, utility)
            assert rank == str(d["rank"]), (name, rank)
        assert rows[page_name[junk.name]][5] == "–"
        best = Path(scored["best"]["file"]).name
        assert best.startswith("bob_") and by_file[best]["rank"] == 1
        assert [who for who, row in rows.items() if "★" in row[0]] == [page_name[best]]

        # (b) The ★ line: bt score's reason (a take off the guide, the circle or another, has a
        # higher Ũ than bob's, who follows the guide most closely), each take named by who and
        # when instead of its file.
        reason = scored["best_reason"]
        assert reason, "this set must put the ★ on a take that is not the highest Ũ"
        top = max(by_file, key=lambda name: by_file[name]["utility"])
        assert top != best and page_name[top] in star_lines(page)[0].replace(page_name[best], "")
        for name, d in by_file.items():
            reason = reason.replace(f"{d['file']}:{d['demo']}", page_name[name])
        assert "/" not in reason and page_name[best] in reason
        assert star_lines(page) == [f"★ {reason}"]

        # Clean, then (c) the Replay picker opens on the cleaned ★; replay it.
        page.get_by_role("button", name="Clean", exact=True).click()
        expect(page.get_by_text("Cleaned: 5 demos", exact=False)).to_be_visible(timeout=300_000)
        replay = page.get_by_role("combobox", name="Replay")
        expect(replay).to_have_value(re.compile("^cleaned: ★ " + re.escape(page_name[best])))
        page.screenshot(path=str(tmp_path / "after-clean.png"))
        page.get_by_role("button", name="Play", exact=True).click()
        done = page.get_by_text(f"cleaned: {page_name[best]}: tracked within", exact=False)
        expect(done).to_be_visible(timeout=180_000)
        assert "(was " in table_rows(page)[page_name[best]][5]  # Ũ moved as takes came in
        page.close()  # the session ends: its .rrd is complete
        wait_until(lambda: not app.sessions() and app.settled(), 60.0, "the session to end")

    # (d) Rerun names each take as the page does: who and when, as an entity path part.
    entity = {name: names_of(folder / name, by_file[name]["demonstrator"])[1] for name in by_file}
    entity[junk.name] = names_of(junk, NAME)[1]
    (session_rrd,) = [p for p in (root / "rerun").glob("*.rrd") if "_clean_" not in p.name]
    (clean_rrd,) = (root / "rerun").glob("*_clean_wiping_*.rrd")
    session = rrd_entities(session_rrd)
    assert {e for e in session if e.startswith("/demos/")} == {
        f"/demos/{entity[p.name]}" for p in (circle, junk)
    }
    replayed = session["/replay/cleaned"]  # static: drawn in the robot view at any time
    assert replayed["LineStrips3D:labels"] == [[f"cleaned: {page_name[best]}"]]
    assert replayed["static"] == [True]
    cleaned = rrd_entities(clean_rrd)
    for kind in ("raw", "cleaned"):
        under = f"/wiping/plane/{kind}/"
        named = {e.removeprefix(under) for e in cleaned if e.startswith(under)}
        assert named == {entity[name] for name in by_file}, kind
    [[legend]] = cleaned["/wiping/legend"]["TextDocument:text"]
    assert f"`{entity[best]}` ★ best" in legend
