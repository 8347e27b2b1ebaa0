"""Shared by the library's tests: the real browser takes.

* ``takes`` (fixture): a recordings folder under ``tmp_path`` holding copies of the wiping takes.
* ``write_cleaned(root)`` writes the cleaned file `bt clean` would for the first three of them.
"""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import pytest

from bt_pipeline.data.recording import read_recording, write_recording
from bt_teleop.clean.runner import cleaned_path
from bt_teleop.testing.harness import shared_dir

TAKES = shared_dir() / "data/browser-takes/wiping"


@pytest.fixture
def takes(tmp_path: Path) -> Path:
    """A recordings folder holding copies of the real browser takes (wiping)."""
    folder = tmp_path / "rec" / "wiping"
    folder.mkdir(parents=True)
    for path in sorted(TAKES.glob("*.hdf5")):
        shutil.copy2(path, folder / path.name)
    return tmp_path / "rec"


def write_cleaned(root: Path) -> Path:
    """A cleaned file as `bt clean` names its demos: each raw take's demo, renumbered."""
    raws = sorted((root / "wiping").glob("*.hdf5"))[:3]
    recordings = [read_recording(path) for path in raws]
    demos = {}
    for k, (path, recording) in enumerate(zip(raws, recordings, strict=True)):
        demo = recording.demos["demo_0"]
        attrs = {"cleaned_from": f"{path}:demo_0", "utility_cleaned": 0.5 + 0.1 * k}
        demos[f"demo_{k}"] = dataclasses.replace(demo, ee_pos=demo.ee_pos + 0.001, attrs=attrs)
    cleaned = dataclasses.replace(recordings[0], demos=demos, path=None)
    return write_recording(cleaned_path(root, "wiping"), cleaned, overwrite=True)
