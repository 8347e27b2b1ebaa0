"""Output sets (data/output_set.py) and stale temp files (data/atomic.py): all or nothing."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from bt_pipeline.data.atomic import pid_alive, publish_dir, recover_dir, remove_stale_temps
from bt_pipeline.data.output_set import (
    JOURNAL,
    MANIFEST,
    STAGING_PREFIX,
    OutputSet,
    recover,
    sha256_file,
    verify,
)


@pytest.fixture(scope="module")
def dead_pid() -> int:
    """The id of a process that has exited."""
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    assert not pid_alive(child.pid)
    return child.pid


def _publish(out: Path, files: dict[str, bytes]) -> list[Path]:
    with OutputSet(out) as outputs:
        for name, body in files.items():
            outputs.path(name).write_bytes(body)
        return outputs.commit()


def test_commit_publishes_every_file_and_a_manifest_of_their_hashes(tmp_path) -> None:
    published = _publish(tmp_path, {"a.cleaned.hdf5": b"A1", "a.rrd": b"R1"})
    assert sorted(p.name for p in published) == ["a.cleaned.hdf5", "a.rrd"]
    manifest = json.loads((tmp_path / MANIFEST).read_text())["files"]
    assert manifest["a.rrd"]["sha256"] == sha256_file(tmp_path / "a.rrd")
    assert verify(tmp_path) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.cleaned.hdf5", "a.rrd", MANIFEST]
    # A later run for another task keeps the first task's entries.
    _publish(tmp_path, {"b.cleaned.hdf5": b"B1"})
    assert set(json.loads((tmp_path / MANIFEST).read_text())["files"]) == {
        "a.cleaned.hdf5",
        "a.rrd",
        "b.cleaned.hdf5",
    }
    (tmp_path / "a.rrd").write_bytes(b"changed by hand")
    assert verify(tmp_path) == ["a.rrd"]


def test_an_error_before_commit_leaves_the_folder_as_it_was(tmp_path) -> None:
    _publish(tmp_path, {"a.cleaned.hdf5": b"old"})
    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(RuntimeError), OutputSet(tmp_path) as outputs:
        outputs.path("a.cleaned.hdf5").write_bytes(b"new")
        raise RuntimeError("stage 2 failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert (tmp_path / "a.cleaned.hdf5").read_bytes() == b"old"


def test_a_run_killed_before_its_commit_point_is_rolled_back(tmp_path, dead_pid) -> None:
    _publish(tmp_path, {"a.cleaned.hdf5": b"old", "a.rrd": b"old rrd"})
    staging = tmp_path / f"{STAGING_PREFIX}{dead_pid}-abc123"
    staging.mkdir()
    (staging / "a.cleaned.hdf5").write_bytes(b"new")  # killed before a.rrd and the journal
    lines = recover(tmp_path)
    assert len(lines) == 1 and "removed the partial outputs" in lines[0]
    assert not staging.exists()
    assert (tmp_path / "a.cleaned.hdf5").read_bytes() == b"old" and verify(tmp_path) == []


def test_a_run_killed_after_its_commit_point_is_rolled_forward(tmp_path, dead_pid) -> None:
    _publish(tmp_path, {"a.cleaned.hdf5": b"old", "a.rrd": b"old rrd"})
    staging = tmp_path / f"{STAGING_PREFIX}{dead_pid}-def456"
    staging.mkdir()
    new = {"a.cleaned.hdf5": b"new", "a.rrd": b"new rrd"}
    manifest = {n: {"sha256": hashlib.sha256(b).hexdigest()} for n, b in new.items()}
    (staging / MANIFEST).write_text(json.dumps({"files": manifest}))
    (staging / "a.rrd").write_bytes(new["a.rrd"])
    (staging / JOURNAL).write_text(json.dumps({"files": [*new, MANIFEST]}))
    (tmp_path / "a.cleaned.hdf5").write_bytes(new["a.cleaned.hdf5"])  # the first rename was done
    # Without recovery the folder mixes two runs; the manifest says so.
    assert verify(tmp_path) == ["a.cleaned.hdf5"]
    assert "completed the outputs" in recover(tmp_path)[0]
    assert (tmp_path / "a.rrd").read_bytes() == b"new rrd"
    assert verify(tmp_path) == [] and not staging.exists()


def test_a_live_runs_staging_folder_is_left_alone(tmp_path) -> None:
    with OutputSet(tmp_path) as outputs:
        outputs.path("x.rrd").write_bytes(b"x")
        assert recover(tmp_path) == []
        assert outputs.staging.exists()
        outputs.commit()
    assert (tmp_path / "x.rrd").read_bytes() == b"x"


def test_stale_temp_files_of_killed_writers_are_removed(tmp_path, dead_pid) -> None:
    target = tmp_path / "s.hdf5"
    stale = tmp_path / f".s.hdf5.tmp-{dead_pid}-0badcafe"
    legacy = tmp_path / ".s.hdf5.0123456789ab.tmp"
    live = tmp_path / f".s.hdf5.tmp-{os.getpid()}-feedbeef"
    other = tmp_path / f".t.hdf5.tmp-{dead_pid}-0badcafe"
    for path in (stale, legacy, live, other):
        path.write_bytes(b"partial")
    assert sorted(remove_stale_temps(target)) == sorted([stale, legacy])
    assert live.exists() and other.exists()
    assert any(str(other) in line for line in recover(tmp_path))
    assert not other.exists() and live.exists()


@pytest.mark.parametrize("name", ["", "../x", ".hidden", "a/b", MANIFEST])
def test_output_names_must_be_plain(tmp_path, name) -> None:
    with OutputSet(tmp_path) as outputs, pytest.raises(Exception, match="plain"):
        outputs.path(name)


def _publish_two(a: Path, b: Path, body: bytes) -> None:
    with OutputSet(a) as outputs:
        outputs.path("x.png").write_bytes(body)
        outputs.path("y.hdf5", b).write_bytes(body)
        outputs.commit()


def test_a_set_across_two_folders_is_published_together(tmp_path) -> None:
    a, b = tmp_path / "plots", tmp_path / "rollouts"
    _publish_two(a, b, b"one")
    assert (a / "x.png").read_bytes() == (b / "y.hdf5").read_bytes() == b"one"
    assert verify(a) == [] and verify(b) == []
    runs = [json.loads((f / MANIFEST).read_text())["files"] for f in (a, b)]
    assert runs[0]["x.png"]["run"] == runs[1]["y.hdf5"]["run"]
    assert not list(tmp_path.rglob(f"{STAGING_PREFIX}*"))


def _killed_run(a: Path, b: Path, pid: int, committed: bool) -> tuple[Path, Path]:
    """Staging folders of run `pid` into a (primary) and b, as a kill leaves them."""
    primary, secondary = a / f"{STAGING_PREFIX}{pid}-aa", b / f"{STAGING_PREFIX}{pid}-aa"
    primary.mkdir()
    secondary.mkdir()
    (secondary / "PRIMARY.json").write_text(json.dumps({"primary": str(primary)}))
    for folder, name in ((primary, "x.png"), (secondary, "y.hdf5")):
        (folder / name).write_bytes(b"two")
        digest = hashlib.sha256(b"two").hexdigest()
        (folder / MANIFEST).write_text(json.dumps({"files": {name: {"sha256": digest}}}))
    if committed:
        journal = {"files": ["x.png", MANIFEST], "folders": {str(b): str(secondary)}}
        (primary / JOURNAL).write_text(json.dumps(journal))
    return primary, secondary


@pytest.mark.parametrize("first", ["primary", "secondary"])
@pytest.mark.parametrize(("committed", "kept"), [(False, b"one"), (True, b"two")])
def test_a_killed_two_folder_set_is_recovered_from_either_folder(
    tmp_path, dead_pid, first, committed, kept
) -> None:
    """Before its commit point: rolled back; after: rolled forward; whichever folder's next
    run comes first."""
    a, b = tmp_path / "plots", tmp_path / "rollouts"
    _publish_two(a, b, b"one")
    primary, secondary = _killed_run(a, b, dead_pid, committed=committed)
    recover(a if first == "primary" else b)
    recover(b if first == "primary" else a)
    assert not primary.exists() and not secondary.exists()
    assert (a / "x.png").read_bytes() == (b / "y.hdf5").read_bytes() == kept
    assert verify(a) == [] and verify(b) == []


def test_a_secondary_whose_primary_is_gone_is_rolled_back(tmp_path, dead_pid) -> None:
    """Roll-forward deletes the primary last, so a secondary without one was being undone."""
    a, b = tmp_path / "plots", tmp_path / "rollouts"
    _publish_two(a, b, b"one")
    primary, secondary = _killed_run(a, b, dead_pid, committed=False)
    shutil.rmtree(primary)
    assert "removed the partial outputs" in recover(b)[0]
    assert not secondary.exists() and (b / "y.hdf5").read_bytes() == b"one"


def test_a_directory_replaced_by_a_killed_writer_is_put_back_or_finished(
    tmp_path, dead_pid
) -> None:
    out = tmp_path / "ds"
    out.mkdir()
    (out / "info.json").write_text("old")
    # killed between its two renames: the old tree set aside, the new one still hidden
    os.rename(out, tmp_path / f".ds.old-{dead_pid}-ab12")
    (tmp_path / f".ds.tmp-{dead_pid}-cd34").mkdir()
    lines = recover_dir(out)
    assert len(lines) == 2 and (out / "info.json").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]
    # killed after the second rename: the new tree is in place, the old one is deleted
    (tmp_path / f".ds.old-{dead_pid}-ef56").mkdir()
    recover_dir(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]
    live = tmp_path / f".ds.tmp-{os.getpid()}-0a0b"  # a running writer's tree: left alone
    live.mkdir()
    assert recover_dir(out) == [] and live.exists()


def test_publish_dir_replaces_a_tree_only_when_asked(tmp_path) -> None:
    out, new = tmp_path / "ds", tmp_path / ".ds.tmp-1-aa"
    out.mkdir()
    (out / "a").write_text("old")
    new.mkdir()
    (new / "a").write_text("new")
    with pytest.raises(Exception, match="exists"):
        publish_dir(new, out, overwrite=False)
    publish_dir(new, out, overwrite=True)
    assert (out / "a").read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == ["ds"]
