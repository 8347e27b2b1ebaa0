"""A cleaned file is listed from its attributes, without its samples
(bt_teleop/library/cleaned_listing.py): the same tracks as from a full read, and a broken file is
a RecordingError naming what broke."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import h5py
import pytest

from bt_pipeline.data.recording import read_recording, write_recording
from bt_pipeline.data.synth import make_demo_set
from bt_pipeline.exceptions import RecordingError
from bt_teleop.library.cleaned_listing import read_cleaned_listing
from bt_teleop.library.reading import _cleaned_tracks, read_file_tracks
from bt_teleop.library.tracks import file_stamp


def cleaned_file(path: Path, n: int = 6) -> Path:
    """A recording shaped like a Clean's output: each demo names its raw source and its Ũ."""
    recording = make_demo_set("wiping", n_demos=n, seed=3).recording
    demos = {}
    for i, (name, demo) in enumerate(recording.demos.items()):
        attrs: dict[str, object] = {"utility_cleaned": 0.1 * i} if i != 2 else {}  # one unscored
        if i != 4:  # one without its source: listed by its own name
            source_demo = "demo_3" if i == 1 else "demo_0"  # one of a multi-demo raw file
            attrs["cleaned_from"] = f"/rec/wiping/tab {i}_x.hdf5:{source_demo}"
        demos[name] = dataclasses.replace(demo, attrs={**demo.attrs, **attrs})
    return write_recording(path, dataclasses.replace(recording, demos=demos))


def test_the_listing_equals_the_tracks_of_a_full_read(tmp_path: Path) -> None:
    path = cleaned_file(tmp_path / "wiping.cleaned.hdf5")
    stamp = file_stamp(path)
    recording = read_recording(path)
    listed = read_cleaned_listing(path, stamp)
    assert listed.task == recording.task
    assert listed.tracks == _cleaned_tracks(recording, stamp)
    assert read_file_tracks(path, "cleaned").tracks == listed.tracks
    keys = [t.key for t in listed.tracks]
    assert "cleaned · tab 1_x · demo_3" in keys and len(set(keys)) == len(keys)
    assert [t.utility is None for t in listed.tracks].count(True) == 1
    assert all(t.duration_s > 0.0 and t.num_samples > 16 for t in listed.tracks)


def test_a_broken_cleaned_file_is_a_recording_error(tmp_path: Path) -> None:
    path = cleaned_file(tmp_path / "wiping.cleaned.hdf5")
    with h5py.File(path, "a") as file:
        del file["data/demo_1/timestamps"]
    with pytest.raises(RecordingError, match="demo_1: missing dataset timestamps"):
        read_cleaned_listing(path, file_stamp(path))
    with h5py.File(path, "a") as file:
        file["data/demo_2"].attrs["num_samples"] = 3
    with pytest.raises(RecordingError, match="demo_"):
        read_cleaned_listing(path, file_stamp(path))
    junk = tmp_path / "junk.hdf5"
    junk.write_bytes(b"\x89HDF\r\n" + bytes(range(256)) * 8)
    with pytest.raises(RecordingError, match=r"junk\.hdf5"):
        read_file_tracks(junk, "cleaned")
    with h5py.File(tmp_path / "other.hdf5", "w") as file:
        file.create_group("data").attrs["format"] = "something else"
    with pytest.raises(RecordingError, match="attr format"):
        read_cleaned_listing(tmp_path / "other.hdf5", file_stamp(tmp_path / "other.hdf5"))
