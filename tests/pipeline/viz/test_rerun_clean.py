"""Tests of bt_pipeline.viz.rerun_clean: a real cleaning result is saved to .rrd and read back."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from rerun.chunk import Chunk, RrdReader

from bt_pipeline.clean.pipeline import CleanOptions, TaskCleanResult, clean_demos
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.synth import make_d1
from bt_pipeline.exceptions import ConfigError, UnknownTaskError
from bt_pipeline.viz import rerun_clean as rerun_log
from bt_pipeline.viz.rerun_clean import (
    APP_ID,
    EPOCH_TIMELINE,
    METRICS,
    clean_blueprint,
    demo_entity_names,
    log_epoch,
    recording_id,
    save_clean_rrd,
)
from bt_pipeline.viz.rerun_timeline import TIME_TIMELINE

EPOCHS = 3
N_SAMPLES = 120


@dataclass(frozen=True)
class Cleaned:
    """A real cleaning result and the .rrd its epochs were logged to live."""

    result: TaskCleanResult
    live: Path


@pytest.fixture(scope="module", autouse=True)
def strict_rerun() -> Iterator[None]:
    """Make Rerun raise on bad data instead of warning."""
    previous = rr.strict_mode()
    rr.set_strict_mode(True)
    yield
    rr.set_strict_mode(previous)


@pytest.fixture(scope="module")
def cleaned(tmp_path_factory: pytest.TempPathFactory) -> Cleaned:
    """Run the real cleaner for a few epochs on a D1 wiping set, logging each epoch live."""
    demos = demos_from_recording(make_d1("wiping", 0).recording, N_SAMPLES)
    live = tmp_path_factory.mktemp("live") / "live.rrd"
    rec = rr.RecordingStream(APP_ID, recording_id="live", send_properties=False)
    rec.set_log_time_enabled(False)
    rec.save(live)
    names = demo_entity_names(demos)
    result = clean_demos(
        demos,
        CleanOptions(epochs=EPOCHS, progress=False),
        on_epoch=lambda stats: log_epoch(rec, "wiping", stats, names),
    )
    rec.disconnect()
    return Cleaned(result=result, live=live)


@pytest.fixture(scope="module")
def saved(cleaned: Cleaned, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return save_clean_rrd(cleaned.result, tmp_path_factory.mktemp("out") / "wiping.rrd")


def _chunks(path: Path) -> dict[str, list[Chunk]]:
    """Chunks of the first recording by entity path; `store()` fails on a file without footer."""
    by_entity: dict[str, list[Chunk]] = {}
    for chunk in RrdReader(path).store().stream().to_chunks():
        by_entity.setdefault(chunk.entity_path, []).append(chunk)
    return by_entity


def _values(chunks: list[Chunk], column: str, *, static: bool) -> list:
    """One column's values over the static or temporal chunks of an entity."""
    values = []
    for chunk in chunks:
        batch = chunk.to_record_batch()
        if chunk.is_static == static and column in batch.schema.names:
            values.extend(batch.column(column).to_pylist())
    return values


def test_saved_file_is_complete_with_expected_entities(cleaned: Cleaned, saved: Path) -> None:
    result = cleaned.result
    reader = RrdReader(saved)
    [recording] = reader.recordings()
    assert recording.application_id == APP_ID
    assert recording.recording_id == recording_id(result)
    assert len(reader.blueprints()) == 1
    chunks = _chunks(saved)
    names = demo_entity_names(result.demos)
    expected = {"/wiping/plane", "/wiping/plane/value_map", "/wiping/plane/best"}
    expected |= {"/wiping/plane/reference", "/wiping/plane/centre", "/wiping/summary"}
    expected |= {"/wiping/notes", "/wiping/training/loss"}
    for name in names:
        expected |= {f"/wiping/plane/{kind}/{name}" for kind in ("raw", "aligned", "cleaned")}
        expected |= {f"/wiping/training/{kind}/{name}" for kind in ("beta", "reward")}
    for metric, _ in METRICS:
        expected |= {f"/wiping/scores/{metric}/raw", f"/wiping/scores/{metric}/cleaned"}
    assert expected <= set(chunks)
    assert all(path == "/__properties" or path.startswith("/wiping/") for path in chunks)
    timelines = {t for cs in chunks.values() for c in cs for t in c.timeline_names}
    assert timelines == {EPOCH_TIMELINE, TIME_TIMELINE}  # no wall-clock log_time


def test_raw_and_cleaned_side_by_side_on_the_time_timeline(cleaned: Cleaned, saved: Path) -> None:
    result = cleaned.result
    chunks = _chunks(saved)
    plane = result.demos[result.best_index].plane
    names = demo_entity_names(result.demos)
    for i, demo in enumerate(result.demos):
        for group, uv in (("raw", demo.positions), ("cleaned", result.positions[i])):
            ee = chunks[f"/wiping/timeline/world/{group}/{names[i]}/ee"]
            points = _values(ee, "Points3D:positions", static=False)
            np.testing.assert_allclose(np.concatenate(points), plane.to_world(uv), atol=1e-6)
            batches = [c.to_record_batch() for c in ee if not c.is_static]
            times = np.concatenate([b.column(TIME_TIMELINE).cast("int64") for b in batches])
            # Rerun turns float seconds into integer ns by truncation: 5.94 s is 5939999999 ns.
            assert len(times) == demo.n_samples
            assert abs(int(times[-1]) - round(demo.duration_s * 1e9)) <= 1


def test_epoch_histories_have_one_row_per_epoch(cleaned: Cleaned, saved: Path) -> None:
    refine = cleaned.result.refine
    assert refine.epochs == EPOCHS
    chunks = _chunks(saved)
    names = demo_entity_names(cleaned.result.demos)
    series = {"/wiping/training/loss": refine.loss_history}
    for i, name in enumerate(names):
        series[f"/wiping/training/beta/{name}"] = refine.beta_history[:, i]
        series[f"/wiping/training/reward/{name}"] = refine.reward_history[:, i]
    for entity, history in series.items():
        epochs = _values(chunks[entity], EPOCH_TIMELINE, static=False)
        scalars = _values(chunks[entity], "Scalars:scalars", static=False)
        assert epochs == list(range(1, EPOCHS + 1)), entity
        np.testing.assert_allclose(np.concatenate(scalars), history, err_msg=entity)


def test_live_epoch_logging_matches_the_saved_history(cleaned: Cleaned, saved: Path) -> None:
    live, final = _chunks(cleaned.live), _chunks(saved)
    assert set(live) - {"/__properties"} == {p for p in final if p.startswith("/wiping/training")}
    for entity, chunks in live.items():
        if entity == "/__properties":
            continue
        epochs = _values(chunks, EPOCH_TIMELINE, static=False)
        assert sorted(epochs) == list(range(1, EPOCHS + 1)), entity
        live_values = dict(
            zip(epochs, _values(chunks, "Scalars:scalars", static=False), strict=True)
        )
        saved_values = _values(final[entity], "Scalars:scalars", static=False)
        np.testing.assert_allclose(
            [live_values[k][0] for k in range(1, EPOCHS + 1)],
            np.concatenate(saved_values),
            rtol=1e-6,
            err_msg=entity,
        )


def test_curves_are_logged_in_task_coordinates(cleaned: Cleaned, saved: Path) -> None:
    result = cleaned.result
    chunks = _chunks(saved)
    [[flip]] = _values(chunks["/wiping/plane"], "Transform3D:scale", static=True)
    assert flip == [1.0, -1.0, 1.0]
    for i, name in enumerate(demo_entity_names(result.demos)):
        for kind, expected in (
            ("raw", result.demos[i].positions),
            ("aligned", result.stage1.aligned[i]),
            ("cleaned", result.positions[i]),
        ):
            [[strip]] = _values(
                chunks[f"/wiping/plane/{kind}/{name}"], "LineStrips2D:strips", static=True
            )
            np.testing.assert_allclose(strip, expected, atol=1e-6)
    [[best]] = _values(chunks["/wiping/plane/best"], "LineStrips2D:strips", static=True)
    np.testing.assert_allclose(best, result.demos[result.best_index].positions, atol=1e-6)
    [[reference]] = _values(chunks["/wiping/plane/reference"], "LineStrips2D:strips", static=True)
    np.testing.assert_allclose(reference, result.stage1.reference, atol=1e-6)


def test_value_map_pixels_land_on_their_grid_nodes(cleaned: Cleaned, saved: Path) -> None:
    vm = cleaned.result.stage1.value_map
    chunks = _chunks(saved)["/wiping/plane/value_map"]
    [[translation]] = _values(chunks, "Transform3D:translation", static=True)
    [[scale]] = _values(chunks, "Transform3D:scale", static=True)
    [[fmt]] = _values(chunks, "DepthImage:format", static=True)
    [[buffer]] = _values(chunks, "DepthImage:buffer", static=True)
    assert (fmt["width"], fmt["height"]) == (vm.x_centres.size, vm.y_centres.size)
    pixels = np.frombuffer(bytes(buffer), dtype=np.float32).reshape(fmt["height"], fmt["width"])
    np.testing.assert_allclose(pixels, vm.values, atol=1e-6)
    # Pixel (i, j) covers [i, i+1] x [j, j+1]: its centre maps to node (x_i, y_j).
    for i, j in ((0, 0), (7, 93), (vm.x_centres.size - 1, vm.y_centres.size - 1)):
        x = translation[0] + (i + 0.5) * scale[0]
        y = translation[1] + (j + 0.5) * scale[1]
        np.testing.assert_allclose([x, y], [vm.x_centres[i], vm.y_centres[j]], atol=1e-6)


def test_scores_are_bar_charts_before_and_after(cleaned: Cleaned, saved: Path) -> None:
    result = cleaned.result
    chunks = _chunks(saved)
    for metric, _ in METRICS:
        for kind, metrics in (("raw", result.raw), ("cleaned", result.cleaned)):
            entity = f"/wiping/scores/{metric}/{kind}"
            [values] = _values(chunks[entity], "BarChart:values", static=True)
            [abscissa] = _values(chunks[entity], "BarChart:abscissa", static=True)
            expected = [getattr(m, metric) for m in metrics]
            np.testing.assert_allclose(values[0]["buffer"], expected, err_msg=entity)
            assert len(abscissa[0]["buffer"]) == len(expected)


def _view_origins(path: Path) -> set[str]:
    reader = RrdReader(path)
    [blueprint] = reader.blueprints()
    origins = _values(
        reader.stream(store=blueprint).to_chunks(), "ViewBlueprint:space_origin", static=False
    )
    return {origin for row in origins for origin in row}


def test_blueprint_is_sent_with_the_recording(
    cleaned: Cleaned, saved: Path, tmp_path: Path
) -> None:
    origins = _view_origins(saved)
    assert {"/wiping", "/wiping/training/loss", "/wiping/scores/shape"} <= origins
    assert all(origin.startswith("/wiping") for origin in origins)
    both = save_clean_rrd(cleaned.result, tmp_path / "w.rrd", blueprint_tasks=["wiping", "weaving"])
    assert {"/wiping", "/weaving"} <= _view_origins(both)


def test_recording_id_is_deterministic(cleaned: Cleaned, tmp_path: Path) -> None:
    first = save_clean_rrd(cleaned.result, tmp_path / "a.rrd")
    second = save_clean_rrd(cleaned.result, tmp_path / "b.rrd")
    ids = {entry.recording_id for p in (first, second) for entry in RrdReader(p).recordings()}
    assert ids == {recording_id(cleaned.result)}


def test_file_is_complete_before_it_is_moved_into_place(
    cleaned: Cleaned, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    replace = os.replace
    moved: list[int] = []

    def checked_replace(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
        assert Path(src).parent == Path(dst).parent  # same directory: an atomic rename
        moved.append(len(RrdReader(Path(src)).store()))  # needs the footer: the stream is closed
        replace(src, dst)

    monkeypatch.setattr(os, "replace", checked_replace)
    save_clean_rrd(cleaned.result, tmp_path / "wiping.rrd")
    assert len(moved) == 1 and moved[0] > 0


def test_failure_mid_save_leaves_no_file(
    cleaned: Cleaned, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken(*args: object) -> None:
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(rerun_log, "_log_training", broken)
    with pytest.raises(RuntimeError, match="disk on fire"):
        save_clean_rrd(cleaned.result, tmp_path / "wiping.rrd")
    assert list(tmp_path.iterdir()) == []


def test_failure_mid_save_keeps_the_previous_file(
    cleaned: Cleaned, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = save_clean_rrd(cleaned.result, tmp_path / "wiping.rrd")
    before = path.read_bytes()

    def broken(*args: object) -> None:
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(rerun_log, "_log_text", broken)
    with pytest.raises(RuntimeError):
        save_clean_rrd(cleaned.result, path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["wiping.rrd"]


def test_bad_arguments_write_nothing(cleaned: Cleaned, tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"\.rrd"):
        save_clean_rrd(cleaned.result, tmp_path / "wiping.hdf5")
    with pytest.raises(UnknownTaskError, match="invalid task name 'mop/ping'"):
        save_clean_rrd(cleaned.result, tmp_path / "wiping.rrd", blueprint_tasks=["mop/ping"])
    assert list(tmp_path.iterdir()) == []


def test_one_demo_task_saves_without_epochs(tmp_path: Path) -> None:
    demos = demos_from_recording(make_d1("wiping", 1).recording, N_SAMPLES)[:1]
    result = clean_demos(demos, CleanOptions(epochs=EPOCHS, progress=False))
    assert result.refine.epochs == 0
    chunks = _chunks(save_clean_rrd(result, tmp_path / "wiping.rrd"))
    assert _values(chunks["/wiping/training/loss"], EPOCH_TIMELINE, static=False) == []
    texts = _values(chunks["/wiping/notes"], "TextLog:text", static=False)
    assert any("only demo" in text[0] for text in texts)


def test_blueprint_validates_tasks() -> None:
    assert isinstance(clean_blueprint(["wiping", "weaving", "wiping"]), rr.blueprint.Blueprint)
    assert isinstance(clean_blueprint(["stirring"]), rr.blueprint.Blueprint)  # no guide needed
    with pytest.raises(UnknownTaskError, match="a task name is 1-64 characters"):
        clean_blueprint(["../mopping"])
    with pytest.raises(ConfigError, match="at least one task"):
        clean_blueprint([])


def test_entity_names_are_who_and_when_unique_and_path_safe(cleaned: Cleaned) -> None:
    demos = cleaned.result.demos
    # As the page names them: who and when (make_d1's demo k was created at 00:0k UTC).
    expected = tuple(f"{d.demonstrator}_01-01_000{d.name[-1]}00" for d in demos)
    assert demo_entity_names(demos) == expected
    twice = demo_entity_names([demos[0], demos[0].with_positions(demos[0].positions)])
    assert twice == (expected[0], f"{expected[0]}_2")
    # App takes are named from their file name, each in a file of its own as demo_0.
    takes = [
        dataclasses.replace(demos[k], file=f"rec/wiping/ann_20261206T12030{k}Z_ab{k}.hdf5")
        for k in range(2)
    ]
    takes = [dataclasses.replace(t, name="demo_0") for t in takes]
    assert demo_entity_names(takes) == ("ann_12-06_120300", "ann_12-06_120301")  # to the second
    odd = dataclasses.replace(demos[0], demonstrator="<img src=x> 1/a", created=None, file="")
    assert demo_entity_names([odd]) == ("img-src-x-1-a_demo_0",)


def test_raw_and_cleaned_share_a_colour_each_demo_its_own_with_a_legend(
    cleaned: Cleaned, saved: Path
) -> None:
    result = cleaned.result
    chunks = _chunks(saved)
    names = demo_entity_names(result.demos)
    cleaned_rgb, widths = [], []
    for name in names:
        [[raw]] = _values(chunks[f"/wiping/plane/raw/{name}"], "LineStrips2D:colors", static=True)
        [[clean]] = _values(
            chunks[f"/wiping/plane/cleaned/{name}"], "LineStrips2D:colors", static=True
        )
        raw_rgba, clean_rgba = raw.to_bytes(4, "big"), clean.to_bytes(4, "big")
        assert clean_rgba[3] == 255 and sum(raw_rgba[:3]) > sum(clean_rgba[:3])  # raw lighter
        cleaned_rgb.append(clean_rgba[:3])
        [[raw_r]] = _values(chunks[f"/wiping/plane/raw/{name}"], "LineStrips2D:radii", static=True)
        [[clean_r]] = _values(
            chunks[f"/wiping/plane/cleaned/{name}"], "LineStrips2D:radii", static=True
        )
        widths.append((abs(raw_r), abs(clean_r)))  # UI points are stored negative
    assert len(set(cleaned_rgb)) == len(names)  # a colour per demo
    assert all(clean > raw for raw, clean in widths)  # cleaned wider
    [[legend]] = _values(chunks["/wiping/legend"], "TextDocument:text", static=True)
    assert all(f"`{name}`" in legend for name in names)
    assert "★ best" in legend
    [[timeline_legend]] = _values(
        chunks["/wiping/timeline/legend"], "TextDocument:text", static=True
    )
    assert all(f"`{name}`" in timeline_legend for name in names)
