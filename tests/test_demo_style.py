"""bt_pipeline.viz.demo_style: demos named as the page names them, one colour each, a legend."""

from __future__ import annotations

import re

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
    unique_names,
)

SAFE = re.compile(r"[A-Za-z0-9_-]+")


def test_app_takes_are_named_who_and_when() -> None:
    assert name_from_stem("alice_20261206T120301Z_3fa2c1") == "alice_2026-12-06_1203"
    assert name_from_stem("wiping_d1") is None
    file = "recordings/wiping/bob-k_20261206T235959Z_0a.hdf5"
    # The file name wins over the attrs: the live view knows only the file name.
    assert display_name("Bob K.", "2020-01-01T00:00:00+00:00", file, "demo_0") == (
        "bob-k_2026-12-06_2359"
    )


def test_other_files_take_who_from_the_demonstrator_and_when_from_created() -> None:
    named = display_name("teacher_a", "2026-01-01T00:03:00+00:00", "x/wiping_d1.hdf5", "demo_3")
    assert named == "teacher_a_2026-01-01_0003"
    # Another time zone is written in UTC, as the app's file names are.
    assert display_name("a", "2026-01-01T01:03:00+01:00", "f.hdf5", "demo_0") == "a_2026-01-01_0003"
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
    names = ("alice_2026-12-06_1203", "bob_2026-12-06_1210", "<b>x</b>")
    text = legend_markdown(names, best=1)
    assert "| blue | `alice_2026-12-06_1203` |" in text
    assert "| orange | `bob_2026-12-06_1210` ★ best |" in text
    assert "<b>" not in text  # whatever a caller passes, no markup reaches the viewer
    assert "raw thin" in text
    assert "| cyan | `b` |" in legend_markdown(["b"], color_indices=[9], cleaned=False)
