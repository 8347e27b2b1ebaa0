"""Play reads a track's samples from its file (bt_teleop/library/track_samples.py): the same samples
as the file holds, a bounded number kept, and a clear message when the file is gone or changed since
the list was built, also in a tab (no crash, the list reloads)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from bt_pipeline.data.moderation import sidecar_path
from bt_pipeline.data.recording import read_recording
from bt_pipeline.exceptions import RecordingError
from bt_teleop.library.listing import load_library
from bt_teleop.library.replay import read_replay
from bt_teleop.library.track_samples import TrackReader
from bt_teleop.testing.harness import wait_until
from tests.teleop.library.conftest import write_cleaned


def test_play_reads_the_samples_the_file_holds(takes: Path) -> None:
    write_cleaned(takes)
    library = load_library(takes, "wiping")
    reader = TrackReader()
    for track in (*library.raw[:3], *library.cleaned):
        samples = reader.read(track)
        record = read_recording(track.file).demos[track.demo]
        np.testing.assert_array_equal(samples.positions, record.ee_pos)
        np.testing.assert_allclose(samples.times_s, record.timestamps - record.timestamps[0])
        assert samples.duration_s == pytest.approx(track.duration_s)
        assert not samples.positions.flags.writeable  # shared by every tab: read-only
    cleaned = library.cleaned[0]
    played, paths = read_replay(library, cleaned, reader)
    source = library.source_of(cleaned)
    assert source is not None
    assert [kind for kind, _ in paths] == ["cleaned", "raw"]  # its raw source beside it
    np.testing.assert_array_equal(paths[1][1], read_recording(source.file).demos["demo_0"].ee_pos)
    assert played is reader.read(cleaned)


def test_the_reader_keeps_only_the_last_tracks_played(takes: Path) -> None:
    library = load_library(takes, "wiping")
    reader = TrackReader(max_tracks=2)
    first = reader.read(library.raw[0])
    assert reader.read(library.raw[0]) is first and reader.cached == 1  # kept: not read again
    reader.read(library.raw[1])
    reader.read(library.raw[2])
    assert reader.cached == 2
    assert reader.read(library.raw[0]) is not first  # dropped, read again
    reader.clear()
    assert reader.cached == 0


def test_a_file_gone_or_changed_since_the_list_was_built_is_a_clear_error(
    takes: Path,
) -> None:
    library = load_library(takes, "wiping")
    gone, changed = library.raw[0], library.raw[1]
    reader = TrackReader()
    reader.read(changed)  # played once: kept, yet never served for another version
    gone.file.unlink()
    with pytest.raises(RecordingError, match=rf"cannot play {gone.key}: .* is gone since"):
        reader.read(gone)
    shutil.copy2(library.raw[2].file, changed.file)  # replaced by other content
    with pytest.raises(RecordingError, match=rf"cannot play {changed.key}: .* changed since"):
        reader.read(changed)
    fresh = load_library(takes, "wiping")
    assert gone.key not in [t.key for t in fresh.raw]
    replaced = fresh.find(changed.key)
    np.testing.assert_array_equal(
        reader.read(replaced).positions, read_recording(library.raw[2].file).demos["demo_0"].ee_pos
    )
    moderated = fresh.raw[3]
    sidecar_path(moderated.file).write_text("{}")  # a sidecar is not the file: still playable
    reader.read(moderated)


def test_a_tab_playing_a_vanished_take_says_so_and_reloads_its_list(
    takes: Path,
    make_app,
    tabs,
) -> None:
    app = make_app(recordings=takes)
    tabs(app)
    (ui,) = app.wait_for_sessions(1).values()
    wait_until(lambda: ui.library is not None and len(ui.library.raw) == 12, 60.0, "the list")
    library = ui.library
    assert library is not None
    gone = next(t for t in library.raw if t.usable)
    gone.file.unlink()
    ui.play(gone.key)
    assert ui.wait_idle()
    title, body = ui.messages[-1]
    assert title == "Not done" and "is gone since the list was built" in body
    assert ui.replay is None
    wait_until(lambda: ui.library is not None and len(ui.library.raw) == 11, 60.0, "a reload")
    frames = ui.frames
    wait_until(lambda: ui.frames > frames + 3, 10.0, "the tab to keep running")
    usable = [t for t in ui.library.raw if t.usable]  # type: ignore[union-attr]
    other = min(usable, key=lambda t: t.duration_s)
    ui.play(other.key)
    assert ui.wait_idle()
    wait_until(lambda: ui.last_replay is not None, 120.0, "the replay to end")
    assert ui.last_replay is not None and ui.last_replay.result is not None
    assert ui.last_replay.result.rms_error_m < 0.02
