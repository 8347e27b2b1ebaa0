"""The tabs' shared library loader (bt_teleop/library/loader.py): one queued load per task for
every tab, files read once and again only when they change, the same library as a fresh load."""

from __future__ import annotations

import concurrent.futures
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from bt_pipeline.data.recording import write_recording
from bt_pipeline.data.synth import make_demo_set
from bt_pipeline.exceptions import RecordingError
from bt_teleop.library.listing import load_library
from bt_teleop.library.loader import LibraryLoader
from bt_teleop.library.reading import read_file_tracks


def _write(root: Path, name: str, seed: int) -> Path:
    recording = make_demo_set("wiping", n_demos=1, seed=seed).recording
    return write_recording(root / "wiping" / name, recording, overwrite=True)


def _summary(library) -> list[tuple[str, float | None]]:
    return sorted((t.key, t.utility) for t in library.raw)


def test_requests_while_a_load_is_queued_share_it(tmp_path) -> None:
    _write(tmp_path, "a.hdf5", 0)
    executor = concurrent.futures.ThreadPoolExecutor(1)
    gate = threading.Event()
    try:
        executor.submit(gate.wait)  # the reader is busy: the next load stays queued
        loader = LibraryLoader(tmp_path, executor)
        futures = [loader.request("wiping") for _ in range(8)]  # 8 tabs after one save
        assert all(f is futures[0] for f in futures)
        gate.set()
        assert len(futures[0].result(60).raw) == 1
        assert loader.loads == 1
        assert loader.request("wiping") is not futures[0]  # started: a new change needs a new load
    finally:
        gate.set()
        executor.shutdown(wait=True)


def test_only_new_or_changed_files_are_read_again(tmp_path) -> None:
    for k in range(3):
        _write(tmp_path, f"d{k}.hdf5", k)
    with concurrent.futures.ThreadPoolExecutor(1) as executor:
        loader = LibraryLoader(tmp_path, executor)
        first = loader.request("wiping").result(60)
        assert loader.files_read == 3 and len(first.raw) == 3
        _write(tmp_path, "d3.hdf5", 3)
        second = loader.request("wiping").result(60)
        assert loader.files_read == 4 and len(second.raw) == 4
        assert _summary(second) == _summary(load_library(tmp_path, "wiping"))
        _write(tmp_path, "d0.hdf5", 10)  # replaced: read again
        third = loader.request("wiping").result(60)
        assert loader.files_read == 5
        assert _summary(third) == _summary(load_library(tmp_path, "wiping"))
        (tmp_path / "wiping" / "d1.hdf5").unlink()
        fourth = loader.request("wiping").result(60)
        assert len(fourth.raw) == 3 and loader.files_read == 5
        assert tmp_path / "wiping" / "d1.hdf5" not in loader._files


def test_an_unreadable_file_is_skipped_and_read_again_once_fixed(tmp_path) -> None:
    _write(tmp_path, "good.hdf5", 0)
    bad = tmp_path / "wiping" / "bad.hdf5"
    bad.write_bytes(b"not hdf5")
    with concurrent.futures.ThreadPoolExecutor(1) as executor:
        loader = LibraryLoader(tmp_path, executor)
        assert len(loader.request("wiping").result(60).raw) == 1
        _write(tmp_path, "bad.hdf5", 1)
        assert len(loader.request("wiping").result(60).raw) == 2


def test_an_unreadable_file_is_not_read_again_until_it_changes(tmp_path) -> None:
    _write(tmp_path, "good.hdf5", 0)
    bad = tmp_path / "wiping" / "bad.hdf5"
    bad.write_bytes(b"not hdf5")
    reads: list[str] = []

    def read_file(path: Path, kind):
        reads.append(path.name)
        return read_file_tracks(path, kind)

    with concurrent.futures.ThreadPoolExecutor(1) as executor:
        loader = LibraryLoader(tmp_path, executor, read_file=read_file, min_interval_s=0.0)
        for _ in range(3):
            assert len(loader.request("wiping").result(60).raw) == 1
        assert sorted(reads) == ["bad.hdf5", "good.hdf5"]  # once each, not at every load
        with pytest.raises(RecordingError, match="bad"):
            loader._read(bad, "raw")  # the same message, from the cache
        assert len(reads) == 2
        bad.unlink()
        loader.request("wiping").result(60)
        assert bad not in loader._failed  # gone: forgotten


def test_loads_of_a_task_are_spaced_by_their_own_duration(tmp_path, monkeypatch) -> None:
    """The next load waits max(min_interval_s, duty × the last load's CPU time) after it ended."""
    import bt_teleop.library.loader as module

    _write(tmp_path, "a.hdf5", 0)
    now = [100.0]
    sleeps: list[float] = []

    def sleep(seconds: float) -> None:
        sleeps.append(seconds)
        now[0] += seconds

    real_load = module.load_library

    def slow_load(*args, **kwargs):  # a load that takes 2 s of the fake clocks (busy all along)
        now[0] += 2.0
        return real_load(*args, **kwargs)

    monkeypatch.setattr(module, "load_library", slow_load)
    with concurrent.futures.ThreadPoolExecutor(1) as executor:
        loader = LibraryLoader(
            tmp_path,
            executor,
            min_interval_s=1.0,
            duty=3.0,
            clock=lambda: now[0],
            sleep=sleep,
            cpu_clock=lambda: now[0],
        )
        loader.request("wiping").result(60)
        assert sleeps == []  # the first load starts at once
        now[0] += 0.5  # a save half a second after the load ended
        loader.request("wiping").result(60)
        assert sleeps == [5.5]  # 3 × 2 s after the end, 0.5 s of which had passed
        now[0] += 100.0
        loader.request("wiping").result(60)
        assert sleeps == [5.5]  # long after: at once
        assert loader.request("weaving").result(60).task == "weaving"  # other tasks: own clock
        assert sleeps == [5.5]


def test_a_load_waiting_for_its_reads_does_not_push_the_next_one_back(tmp_path) -> None:
    """A load slowed by the reader child (its reads wait, the app's thread idles) is followed by
    the next one after min_interval_s, not after duty × its wall time: with the reader child
    sharing the CPU with a Clean job, spacing by wall time made the table lag by minutes."""
    from bt_teleop.library.reading import read_file_tracks

    files = [_write(tmp_path, name, seed) for seed, name in enumerate(("a.hdf5", "b.hdf5"))]
    read = {path: read_file_tracks(path, "raw") for path in files}  # the child's answers
    files[1].rename(tmp_path / "later")
    sleeps: list[float] = []

    def slow_read(path, kind):  # the child's answer takes 0.3 s; this thread waits, idle
        time.sleep(0.3)
        return read[path]

    with concurrent.futures.ThreadPoolExecutor(1) as executor:
        loader = LibraryLoader(
            tmp_path,
            executor,
            read_file=slow_read,
            min_interval_s=0.05,
            duty=3.0,
            sleep=lambda s: sleeps.append(s),
        )
        loader.request("wiping").result(60)
        (tmp_path / "later").rename(files[1])  # a new take
        assert len(loader.request("wiping").result(60).raw) == 2
    assert len(sleeps) == 1
    assert sleeps[0] < 0.3  # wall-time spacing would wait 3 × ≥ 0.3 s


def test_close_ends_the_wait_of_a_spaced_load(tmp_path) -> None:
    _write(tmp_path, "a.hdf5", 0)
    with concurrent.futures.ThreadPoolExecutor(1) as executor:
        loader = LibraryLoader(tmp_path, executor, min_interval_s=3600.0)
        loader.request("wiping").result(60)
        waiting = loader.request("wiping")  # due in an hour
        loader.close()
        assert len(waiting.result(60).raw) == 1


def test_a_load_reuses_the_tracks_of_unchanged_demos(tmp_path) -> None:
    """After a save, only the new take and the demos whose Ũ moved are new objects (a load's
    allocations do not grow with the takes that did not change); the library equals a fresh
    load, also after an exclusion."""
    from bt_pipeline.data.moderation import exclude
    from bt_teleop.testing.harness import synthetic_task_files

    files = synthetic_task_files(tmp_path, "wiping", 200)
    first = load_library(tmp_path, "wiping", read=lambda path, kind: files[path])
    files = synthetic_task_files(tmp_path, "wiping", 201)  # the same 200 (new objects), +1
    second = load_library(tmp_path, "wiping", read=lambda path, kind: files[path], previous=first)
    assert second.raw == load_library(tmp_path, "wiping", read=lambda path, kind: files[path]).raw
    before = {t.key: t for t in first.raw}
    same = [t.key in before and before[t.key].utility == t.utility for t in second.raw]
    reused = [before.get(t.key) is t for t in second.raw]
    assert reused == same and sum(reused) >= 190  # the new take moved no min or max here
    exclude(second.raw[5].file, reason="test", by="test")
    third = load_library(tmp_path, "wiping", read=lambda path, kind: files[path], previous=second)
    assert third.raw == load_library(tmp_path, "wiping", read=lambda path, kind: files[path]).raw
    assert third.raw[5].excluded and third.raw[5] is not second.raw[5]


def test_task_files_lists_what_expand_paths_lists(tmp_path) -> None:
    from bt_pipeline.data.paths import expand_paths
    from bt_teleop.library.listing import task_files
    from bt_teleop.testing.harness import synthetic_task_files

    synthetic_task_files(tmp_path, "wiping", 30)
    folder = tmp_path / "wiping"
    for name in ("sub/x.h5", ".hidden/y.h5", ".z.hdf5", "notes.txt", "sub/.w.hdf5", "a.hdf5.tmp"):
        (folder / name).parent.mkdir(exist_ok=True)
        (folder / name).touch()
    assert task_files(folder) == expand_paths([folder])
    assert len(task_files(folder)) == 31


def test_the_best_take_is_the_one_bt_clean_takes(tmp_path) -> None:
    """★ is the highest Ũ among the takes that follow the guide about as closely as any (the
    shape gate of ``bt clean`` and ``bt score``), not the highest Ũ overall; the table lists
    those takes first."""
    from bt_pipeline.clean.selection import rank_takes
    from bt_teleop.library.listing import ranked
    from bt_teleop.testing.harness import synthetic_task_files

    files = synthetic_task_files(tmp_path, "wiping", 60)
    library = load_library(tmp_path, "wiping", read=lambda path, kind: files[path])
    takes = [files[t.file].metrics[0] for t in library.raw]
    utility, eligible = rank_takes(takes)
    assert not eligible[int(np.argmax(utility))]  # the highest Ũ may not be the best here
    best = int(np.flatnonzero(eligible)[np.argmax(utility[eligible])])
    assert library.best is library.raw[best]
    order = ranked(library, len(library.raw))
    assert [t.eligible for t in order] == sorted(eligible.tolist(), reverse=True)
    first = [t.utility for t in order[: int(eligible.sum())]]
    assert first == sorted(utility[eligible], reverse=True)
