"""The app's reader child (bt_teleop/library/reader_process.py): the same tracks as a read in the
app's process, errors that name the file, and a read that hangs or a child that dies never
blocking the next read."""

from __future__ import annotations

import os
import signal
import threading
import time
from dataclasses import replace
from pathlib import Path

import pytest

from bt_pipeline.data.recording import write_recording
from bt_pipeline.data.synth_human import make_human_set
from bt_pipeline.exceptions import RecordingError
from bt_teleop.library.reader_process import READER_NAME, READER_NICE, ReaderLost, ReaderProcess
from bt_teleop.library.reading import read_file_tracks
from bt_teleop.testing.harness import wait_until


@pytest.fixture(scope="module")
def takes(tmp_path_factory) -> list[Path]:
    root = tmp_path_factory.mktemp("takes")
    recording = make_human_set("weaving", 3, seed=2).recording
    return [  # one demo a file, as the app saves takes
        write_recording(root / f"take_{k}.hdf5", replace(recording, demos={"demo_0": demo}))
        for k, demo in enumerate(recording.demos.values())
    ]


def test_the_child_reads_what_the_app_would_and_is_replaced_after_max_reads(takes) -> None:
    reader = ReaderProcess(max_reads=2)
    try:
        for path in takes:
            tracks = reader.read(path, "raw")
            assert tracks == read_file_tracks(path, "raw")
            assert tracks.metrics[0] is not None  # scored in the child
        assert reader.started == 2  # 3 reads, 2 a child
    finally:
        reader.close()
    assert reader.pid is None


def test_an_unreadable_file_is_an_error_naming_it(tmp_path, takes) -> None:
    bad = tmp_path / "bad.hdf5"
    bad.write_bytes(b"not hdf5 at all")
    reader = ReaderProcess()
    try:
        with pytest.raises(RecordingError, match=r"bad\.hdf5"):
            reader.read(bad, "raw")
        pid = reader.pid
        assert reader.read(takes[0], "raw").tracks  # the same child reads on
        assert reader.pid == pid
    finally:
        reader.close()


def test_a_read_that_hangs_times_out_and_the_next_read_works(takes) -> None:
    # Reads that answer get a minute (a child starting on a loaded machine takes seconds); the
    # one that hangs, 1 s.
    reader = ReaderProcess(timeout_s=60.0)
    try:
        reader.read(takes[0], "raw")
        assert reader.pid is not None
        os.kill(reader.pid, signal.SIGSTOP)  # the child answers nothing from now on
        reader.timeout_s = 1.0
        start = time.monotonic()
        with pytest.raises(RecordingError, match=r"take_1.hdf5: reading it took more than 1 s"):
            reader.read(takes[1], "raw")
        assert time.monotonic() - start < 30
        assert reader.pid is None  # killed
        reader.timeout_s = 60.0
        assert reader.read(takes[1], "raw").tracks
        assert reader.started == 2
    finally:
        reader.close()


def test_a_child_that_dies_mid_read_is_reported_and_replaced(takes) -> None:
    reader = ReaderProcess(timeout_s=60.0)
    reader.read(takes[0], "raw")
    pid = reader.pid
    assert pid is not None
    os.kill(pid, signal.SIGSTOP)
    errors: list[BaseException] = []

    def read() -> None:
        try:
            reader.read(takes[2], "raw")
        except BaseException as exc:
            errors.append(exc)

    thread = threading.Thread(target=read)
    thread.start()
    try:
        time.sleep(0.5)
        os.kill(pid, signal.SIGKILL)
        thread.join(30)
        assert not thread.is_alive()
        assert len(errors) == 1 and isinstance(errors[0], ReaderLost)
        assert "take_2.hdf5" in str(errors[0]) and "exit code" in str(errors[0])
        assert reader.read(takes[1], "raw").tracks
        assert reader.pid not in (None, pid)
    finally:
        reader.close()


def test_the_child_starts_named_and_below_the_control_loops_priority() -> None:
    import psutil

    reader = ReaderProcess()
    try:
        reader.start()
        assert reader.pid is not None
        child = psutil.Process(reader.pid)
        wait_until(lambda: child.nice() == min(19, os.nice(0) + READER_NICE), 30.0, "nice")
        assert child.name() == READER_NAME
    finally:
        reader.close()
