"""File names from browser input: whitelist, length cap, never a way out of the task folder."""

from __future__ import annotations

import re
from datetime import UTC, datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pytest

from bt_pipeline.exceptions import ConfigError, UnknownTaskError
from bt_teleop.takes.naming import (
    MAX_NAME_CHARS,
    clean_demonstrator,
    demo_path,
    sanitize_name,
    utc_stamp,
)

WHEN = datetime(2025, 3, 4, 5, 6, 7, tzinfo=UTC)
HOSTILE = [
    "../../etc/passwd",
    "..",
    "/absolute/path",
    "C:\\Windows\\system32",
    "a/../../b",
    "name\x00with\nnul",
    "....//....//",
    "~root",
    " ",
    "",
    "Zoë Ünïcode 名前",
]


@pytest.mark.parametrize("name", HOSTILE)
def test_sanitiser_rejects_traversal_and_separators(name: str) -> None:
    slug = sanitize_name(name)
    assert re.fullmatch(r"[A-Za-z0-9_-]{1,32}", slug)
    assert ".." not in slug and "/" not in slug and "\\" not in slug


def test_sanitiser_on_random_text_stays_in_the_whitelist() -> None:
    rng = np.random.default_rng(0)
    alphabet = [chr(c) for c in range(0, 0x250)] + ["/", "\\", ".", "..", "\u202e"]
    for _ in range(300):
        name = "".join(rng.choice(alphabet, size=int(rng.integers(0, 80))))
        slug = sanitize_name(name)
        assert re.fullmatch(r"[A-Za-z0-9_-]+", slug) and len(slug) <= MAX_NAME_CHARS


def test_sanitiser_keeps_plain_names_and_caps_length() -> None:
    assert sanitize_name("alice_B-2") == "alice_B-2"
    assert sanitize_name("Zoë Smith") == "Zoe-Smith"
    assert sanitize_name("") == "anonymous"
    assert len(sanitize_name("x" * 500)) == MAX_NAME_CHARS
    with pytest.raises(ConfigError, match="text"):
        sanitize_name(None)


@pytest.mark.parametrize("name", HOSTILE)
def test_demo_path_stays_in_the_task_folder(tmp_path: Path, name: str) -> None:
    path = demo_path(tmp_path, "wiping", name, WHEN, suffix="abc123")
    assert path.parent == tmp_path / "wiping"
    assert path.resolve().parent == (tmp_path / "wiping").resolve()
    assert path.name.endswith("_20250304T050607Z_abc123.hdf5")


def test_demo_path_suffix_is_random_and_checked(tmp_path: Path) -> None:
    names = {demo_path(tmp_path, "weaving", "ann", WHEN).name for _ in range(20)}
    assert len(names) == 20
    with pytest.raises(ConfigError, match="hex"):
        demo_path(tmp_path, "weaving", "ann", WHEN, suffix="../x")
    with pytest.raises(UnknownTaskError):
        demo_path(tmp_path, "../escape", "ann", WHEN)


def test_utc_stamp_converts_time_zones() -> None:
    local = WHEN.astimezone(timezone(timedelta(hours=5)))
    assert utc_stamp(local) == utc_stamp(WHEN) == "20250304T050607Z"


def test_clean_demonstrator_keeps_free_text_printable() -> None:
    assert clean_demonstrator("  Zoë \n Smith\t") == "Zoë Smith"
    assert clean_demonstrator("\x00\x01") == "anonymous"
    assert len(clean_demonstrator("y" * 300)) == 64


@pytest.mark.parametrize("task", ["stirring", "Wiping", "../escape", "wiping/..", ""])
def test_the_app_keeps_to_its_three_tasks(tmp_path: Path, task: str) -> None:
    """Files may name any task; the app has scenes and folders for the three guided ones only."""
    from bt_teleop.app_options import AppOptions
    from bt_teleop.clean.task import cleaned_path, task_dir
    from bt_teleop.session.script import parse_script
    from bt_teleop.sim.scene import load_scene

    valid = "valid tasks are wiping, weaving, pick_and_place"
    with pytest.raises(UnknownTaskError, match=valid):
        demo_path(tmp_path, task, "ann", WHEN)
    with pytest.raises(UnknownTaskError, match=valid):
        task_dir(tmp_path, task)
    with pytest.raises(UnknownTaskError, match=valid):
        cleaned_path(tmp_path, task)
    with pytest.raises(UnknownTaskError, match=valid):
        load_scene(task)
    with pytest.raises(UnknownTaskError, match=valid):
        parse_script({"task": task, "waypoints": [[0, 0, 0], [1, 0.01, 0]]})
    with pytest.raises(UnknownTaskError, match=valid):
        AppOptions(initial_task=task, recordings=tmp_path)  # type: ignore[arg-type]
    assert list(tmp_path.iterdir()) == []
