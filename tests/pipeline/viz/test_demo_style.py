"""bt_pipeline.viz.demo_style: demos named as the page names them, one colour each, a legend."""

from __future__ import annotations

import re
from datetime import UTC, datetime, timedelta, timezone

import numpy as np
import pytest

from bt_pipeline.viz.demo_style import (
    CLEANED_RADIUS_UI,
    RAW_RADIUS_UI,
    cleaned_color,
    demo_color,
    display_name,
    legend_markdown,
    name_from_stem,
    palette_index,
    raw_color,
    take_time,
    unique_names,
    who_when,
)

SAFE = re.compile(r"[A-Za-z0-9_-]+")


def test_app_takes_are_named_who_and_when() -> None:
    assert name_from_stem("alice_20261206T120301Z_3fa2c1") == "alice_12-06_120301"
    assert name_from_stem("wiping_d1") is None
    assert name_from_stem("alice_20261306T120301Z_3fa2c1") is None  # no 13th month
    assert take_time("alice_20261206T120301Z_3fa2c1") == datetime(2026, 12, 6, 12, 3, 1, tzinfo=UTC)
    assert take_time("alice_2026-12-06_3fa2c1") is None
    file = "recordings/wiping/bob-k_20261206T235959Z_0a.hdf5"
    # The file name wins over the attrs: the live view knows only the file name.
    assert display_name("Bob K.", "2020-01-01T00:00:00+00:00", file, "demo_0") == (
        "bob-k_12-06_235959"
    )


def test_the_page_and_rerun_read_the_same_who_and_when() -> None:
    """One function names a demo for the page and for Rerun: the same who and when (UTC, to the
    second), the Rerun form an entity path part."""
    when = datetime(2026, 12, 6, 12, 3, 15, tzinfo=UTC)
    assert who_when("Ada Lovelace", when) == "Ada Lovelace 12-06 12:03:15"
    assert who_when("Ada Lovelace", when, entity=True) == "Ada-Lovelace_12-06_120315"
    assert who_when("Ada", when, sep="<br>") == "Ada<br>12-06 12:03:15"
    # Another time zone, or none (taken as UTC), is shown in UTC as the file names are.
    paris = when.astimezone(timezone(timedelta(hours=1)))
    assert who_when("a", paris) == who_when("a", when.replace(tzinfo=None)) == "a 12-06 12:03:15"
    # The Rerun form is the page's: the name as an entity part, the space "_", no colons.
    for who in ("Ada Lovelace", "<b>x</b>", "", "Zoë"):
        page, entity = who_when(who, when), who_when(who, when, entity=True)
        assert SAFE.fullmatch(entity), entity
        assert entity.endswith(page.removeprefix(who).strip().replace(" ", "_").replace(":", ""))


def test_other_files_take_who_from_the_demonstrator_and_when_from_created() -> None:
    named = display_name("teacher_a", "2026-01-01T00:03:00+00:00", "x/wiping_d1.hdf5", "demo_3")
    assert named == "teacher_a_01-01_000300"
    # Another time zone is written in UTC, as the app's file names are.
    assert display_name("a", "2026-01-01T01:03:00+01:00", "f.hdf5", "demo_0") == "a_01-01_000300"
    # No time: the file and the demo tell it apart.
    assert display_name("person_0", None, "/d/example.hdf5", "demo_2") == "person_0_example_demo_2"
    assert display_name("person_0", "not a time", "", "demo_2") == "person_0_demo_2"


@pytest.mark.parametrize(
    "typed",
    [
        "<script>alert(1)</script>",
        "../../etc/passwd",
        "a b\tc\nd",
        "Zoë 🤖",
        "\x00\x1b[31m",
        "",
        "|`*_",
    ],
)
def test_names_typed_in_browsers_become_safe_entity_path_parts(typed: str) -> None:
    for name in (
        display_name(typed, "2026-12-06T12:03:00+00:00", "", "demo_0"),
        display_name(typed, None, f"{typed}.hdf5", typed),
    ):
        assert SAFE.fullmatch(name), name


def test_repeated_names_are_made_unique_without_taking_another_demos_name() -> None:
    names = unique_names(["a", "a", "a_2", "b", "a"])
    assert len(set(names)) == 5
    assert names[0] == "a" and names[2] == "a_2" and names[3] == "b"
    assert unique_names(["x", "y"]) == ("x", "y")


def test_each_demo_has_its_own_colour_and_raw_and_cleaned_share_it() -> None:
    colours = {demo_color(i) for i in range(10)}
    assert len(colours) == 10  # distinct for a set of up to 10
    for i in range(10):
        rgb = demo_color(i)
        assert palette_index(rgb) == i
        raw, cleaned = raw_color(rgb), cleaned_color(rgb)
        assert cleaned[:3] == rgb and cleaned[3] == 255  # cleaned: the full colour
        assert all(r >= c for r, c in zip(raw[:3], rgb, strict=True))  # raw: lighter
        assert sum(raw[:3]) > sum(rgb)
        # The same hue: raw is the colour blended towards white.
        hsv = [np.array(c[:3], dtype=float) for c in (raw, rgb)]
        assert np.argmax(hsv[0]) == np.argmax(hsv[1])
    assert CLEANED_RADIUS_UI > RAW_RADIUS_UI


def test_the_legend_lists_every_name_with_its_colour() -> None:
    names = ("alice_12-06_120301", "bob_12-06_121000", "<b>x</b>")
    text = legend_markdown(names, best=1)
    assert "| blue | `alice_12-06_120301` |" in text
    assert "| orange | `bob_12-06_121000` ★ best |" in text
    assert "<b>" not in text  # whatever a caller passes, no markup reaches the viewer
    assert "raw thin" in text
    assert "| cyan | `b` |" in legend_markdown(["b"], color_indices=[9], cleaned=False)
