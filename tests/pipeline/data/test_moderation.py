"""Tests of bt_pipeline.data.moderation: exclusion is a sidecar; the recording is never touched."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from bt_pipeline.data.moderation import exclude, exclusion, is_excluded, restore, sidecar_path
from bt_pipeline.data.records import DemoRecord
from bt_pipeline.exceptions import RecordingError


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_exclude_and_restore_leave_the_recording_untouched(tmp_path: Path) -> None:
    rec = tmp_path / "alice_take.hdf5"
    rec.write_bytes(b"not really hdf5, but bytes that must not change")
    before = _digest(rec)
    assert not is_excluded(rec)
    side = exclude(rec, reason="junk <b>take</b>", by="operator")
    assert side == sidecar_path(rec) and side.is_file()
    assert is_excluded(rec)
    info = exclusion(rec)
    assert info is not None and info["reason"] == "junk <b>take</b>" and info["by"] == "operator"
    assert _digest(rec) == before
    assert restore(rec) is True
    assert not is_excluded(rec) and restore(rec) is False
    assert _digest(rec) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["alice_take.hdf5"]


def test_unreadable_sidecar_still_excludes(tmp_path: Path) -> None:
    rec = tmp_path / "r.hdf5"
    rec.write_bytes(b"x")
    sidecar_path(rec).write_bytes(b"\xff\xfe{")
    assert is_excluded(rec)
    assert exclusion(rec) == {"reason": "(unreadable sidecar)", "by": "", "at": ""}


def test_cannot_exclude_a_missing_file(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="does not exist"):
        exclude(tmp_path / "missing.hdf5")


def _demo(**kw: object) -> DemoRecord:
    base: dict = dict(
        ee_pos=np.zeros((16, 3)),
        timestamps=np.arange(16) / 50.0,
        demonstrator="x",
        theta_deg=0.0,
        rho=1.0,
        source="teleop",
    )
    base.update(kw)
    return DemoRecord(**base)


def test_demo_flags_parse_attr_and_legacy_incomplete() -> None:
    assert _demo().flags == ()
    assert _demo(attrs={"flags": "too_short, no_motion"}).flags == ("too_short", "no_motion")
    assert _demo(attrs={"flags": b"incomplete"}).flags == ("incomplete",)
    assert _demo(attrs={"flags": ["too_short", "no_motion"]}).flags == ("too_short", "no_motion")
    assert _demo(attrs={"flags": np.array([b"no_motion"])}).flags == ("no_motion",)
    assert _demo(ep_meta={"incomplete": True}).flags == ("closed_mid_take",)
    assert _demo(ep_meta={"incomplete": False}).flags == ()
