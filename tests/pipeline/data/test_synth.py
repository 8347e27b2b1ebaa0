"""Synthetic demo sets: deterministic, one expert-like demo, visible defects, valid records."""

from __future__ import annotations

import dataclasses
import functools
import hashlib
from typing import Any

import numpy as np
import pytest
from scipy.spatial import KDTree

from bt_pipeline.cli import main
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.data.random_loops import draw_set_loop
from bt_pipeline.data.recording import read_recording, write_recording
from bt_pipeline.data.records import MIN_SAMPLES, forward_difference_actions
from bt_pipeline.data.shapes import canonical_loop, similarity_transform
from bt_pipeline.data.synth import (
    DEFECTS,
    DEMONSTRATORS,
    NOISE_DEFECTS,
    SAMPLE_RATE_HZ,
    SHAPE_DEFECTS,
    TRUTH_SAMPLES,
    SynthSet,
    make_d1,
    make_d2,
    make_demo_set,
)
from bt_pipeline.data.synth_human import HumanSet, make_human_set
from bt_pipeline.data.tasks import TASKS, default_plane
from bt_pipeline.evaluate.distance import distance_to_truth
from bt_pipeline.exceptions import ConfigError, UnknownTaskError

SEEDS = range(6)


def test_same_seed_same_set_other_seed_other_set() -> None:
    a, b = make_d1("weaving", 3), make_d1("weaving", 3)
    assert a.expert_index == b.expert_index
    for da, db in zip(a.demos, b.demos, strict=True):
        np.testing.assert_array_equal(da.record.ee_pos, db.record.ee_pos)
        np.testing.assert_array_equal(da.record.timestamps, db.record.timestamps)
        assert da.defects == db.defects and da.record.created == db.record.created
    c = make_d1("weaving", 4)
    assert not np.array_equal(a.demos[0].record.ee_pos[:50], c.demos[0].record.ee_pos[:50])


@pytest.mark.parametrize("task", TASKS)
def test_exactly_one_expert_and_every_naive_demo_has_defects(task) -> None:
    experts_at = set()
    for seed in SEEDS:
        synth_set = make_demo_set(task, 8, seed)
        experts = [d for d in synth_set.demos if d.is_expert]
        assert len(experts) == 1 and synth_set.demos[synth_set.expert_index].is_expert
        assert synth_set.expert_name == experts[0].name
        experts_at.add(synth_set.expert_index)
        assert experts[0].defects == ()
        for demo in synth_set.demos:
            meta = demo.record.ep_meta["synthetic"]
            assert meta["is_expert"] == demo.is_expert and meta["defects"] == list(demo.defects)
            if demo.is_expert:
                continue
            assert set(demo.defects) <= set(DEFECTS)
            others = [d for d in demo.defects if d not in NOISE_DEFECTS]
            assert set(demo.defects) & set(NOISE_DEFECTS), demo.defects
            assert 1 <= len(others) <= 3 and set(others) & set(SHAPE_DEFECTS), demo.defects
    assert len(experts_at) > 1  # which demo is the expert depends on the seed


def test_d1_has_the_papers_demonstrators() -> None:
    synth_set = make_d1("wiping", 0)
    records = [d.record for d in synth_set.demos]
    assert [d.name for d in synth_set.demos] == ["demo_0", "demo_1", "demo_2", "demo_3"]
    assert [r.theta_deg for r in records] == [5.0, -5.0, 10.0, -10.0]
    assert [r.rho for r in records] == [1.0, 1.1, 1.2, 1.3]
    assert [r.demonstrator for r in records] == [
        "teacher_a",
        "teacher_b",
        "teacher_c",
        "teacher_d",
    ]


def test_d2_has_five_demos_per_demonstrator() -> None:
    synth_set = make_d2("pick_and_place", 1)
    assert len(synth_set.demos) == 20 and len(synth_set.recording.demos) == 20
    for k, demo in enumerate(synth_set.demos):
        teacher = DEMONSTRATORS[k % 4]
        assert demo.record.demonstrator == teacher.name
        assert (demo.record.theta_deg, demo.record.rho) == (teacher.theta_deg, teacher.rho)
    names = [d.record.demonstrator for d in synth_set.demos]
    assert {names.count(t.name) for t in DEMONSTRATORS} == {5}
    assert synth_set.recording.env_args["env_kwargs"]["preset"] == "D2"


@pytest.mark.parametrize("task", TASKS)
def test_truth_is_the_canonical_loop_under_theta_and_rho(task) -> None:
    synth_set = make_d1(task, 2)
    for demo in synth_set.demos:
        expected = similarity_transform(
            canonical_loop(task, 600), demo.record.theta_deg, demo.record.rho
        )
        np.testing.assert_allclose(demo.truth, expected)
        np.testing.assert_array_equal(synth_set.truth_by_name[demo.name], demo.truth)


@pytest.mark.parametrize("task", TASKS)
@pytest.mark.parametrize("n_demos", [4, 20])
def test_expert_is_much_closer_to_its_truth_than_every_naive_demo(task, n_demos) -> None:
    for seed in range(4):
        synth_set = make_demo_set(task, n_demos, seed)
        demos = demos_from_recording(synth_set.recording)
        distances = [distance_to_truth(d.positions, synth_set.truth_by_name[d.name]) for d in demos]
        expert = distances.pop(synth_set.expert_index)
        assert expert < 1e-3, f"{task} seed {seed}: expert {expert * 1e3:.2f} mm"
        assert expert < min(distances) / 3, (
            f"{task} seed {seed}: expert {expert * 1e3:.2f} mm, "
            f"closest naive {min(distances) * 1e3:.2f} mm"
        )


@pytest.mark.parametrize("task", TASKS)
def test_records_are_valid_demos_in_the_task_plane(task) -> None:
    synth_set = make_d1(task, 5)
    recording = synth_set.recording
    plane = default_plane(task)
    assert recording.task == task and recording.plane == plane
    assert recording.env_args["env_name"] == "bt_synthetic"
    assert recording.env_args["env_kwargs"] == {
        "task": task,
        "seed": 5,
        "preset": "D1",
        "n_demos": 4,
    }
    for demo in synth_set.demos:
        record = recording.demos[demo.name]
        assert record is demo.record and record.source == "synthetic"
        n = record.num_samples
        assert n >= MIN_SAMPLES and 5.0 * SAMPLE_RATE_HZ <= n - 1 <= 8.0 * SAMPLE_RATE_HZ
        assert record.ee_pos.shape == (n, 3) and record.timestamps.shape == (n,)
        assert np.all(np.isfinite(record.ee_pos))
        assert record.timestamps[0] == 0.0 and np.all(np.diff(record.timestamps) > 0)
        np.testing.assert_allclose(np.diff(record.timestamps), 1.0 / SAMPLE_RATE_HZ)
        assert record.actions is not None
        np.testing.assert_array_equal(
            record.actions, forward_difference_actions(record.ee_pos, record.timestamps)
        )
        # Every position lies in the task plane, near the task centre.
        off_plane = (record.ee_pos - plane.origin) @ plane.normal
        np.testing.assert_allclose(off_plane, 0.0, atol=1e-12)
        assert np.abs(plane.to_plane(record.ee_pos)).max() < 0.35
        assert record.created is not None and record.created.startswith("20")


def test_defects_are_visible() -> None:
    # An incomplete loop ends far from its start; a complete expert loop closes.
    for seed in range(10):
        synth_set = make_demo_set("wiping", 8, seed)
        for demo in synth_set.demos:
            uv = default_plane("wiping").to_plane(demo.record.ee_pos)
            gap = float(np.linalg.norm(uv[-1] - uv[0]))
            if demo.is_expert:
                assert gap < 3e-3
            elif "incomplete" in demo.defects and "drift" not in demo.defects:
                assert gap > 0.03
            if "jitter" in demo.defects or "tremor" in demo.defects:
                # High-frequency noise: second differences far above the expert's.
                assert np.std(np.diff(uv, 2, axis=0)) > 1e-3


def test_demo_sets_round_trip_through_a_file(tmp_path) -> None:
    synth_set = make_d1("weaving", 7)
    back = read_recording(write_recording(tmp_path / "synth.hdf5", synth_set.recording))
    assert list(back.demos) == list(synth_set.recording.demos)
    for name, record in back.demos.items():
        np.testing.assert_allclose(record.ee_pos, synth_set.recording.demos[name].ee_pos)
        assert record.ep_meta == synth_set.recording.demos[name].ep_meta


def test_bad_arguments_are_rejected() -> None:
    with pytest.raises(ConfigError, match="n_demos"):
        make_demo_set("wiping", 0)
    with pytest.raises(ConfigError, match="seed"):
        make_demo_set("wiping", 4, -1)
    with pytest.raises(UnknownTaskError, match="valid tasks are"):
        make_demo_set("sweeping")


def test_sets_are_frozen() -> None:
    synth_set = make_d1("wiping", 0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        synth_set.expert_index = 1  # type: ignore[misc]


# Intended loops other than the guide (shape=...; bt_pipeline.data.synth_loop, random_loops).


def _feed(h: Any, value: object) -> None:
    """Hash `value` exactly: arrays by dtype, shape and bytes; floats by their hex form."""
    if isinstance(value, np.ndarray):
        h.update(f"{value.dtype.str}{value.shape}".encode())
        h.update(np.ascontiguousarray(value).tobytes())
    elif isinstance(value, dict):
        for key in sorted(value):
            h.update(f"<{key}>".encode())
            _feed(h, value[key])
    elif isinstance(value, list | tuple):
        h.update(b"[")
        for item in value:
            _feed(h, item)
        h.update(b"]")
    elif isinstance(value, bool | np.bool_):
        h.update(b"T" if value else b"F")
    elif isinstance(value, int | np.integer):
        h.update(f"i{int(value)}".encode())
    elif isinstance(value, float | np.floating):
        h.update(float(value).hex().encode())
    else:
        h.update(f"s{value}".encode())


def _set_hash(synth_set: SynthSet | HumanSet) -> str:
    h = hashlib.sha256()
    rec = synth_set.recording
    _feed(h, [rec.task, rec.plane.origin, rec.plane.axes, rec.env_args, rec.attrs])
    _feed(h, synth_set.expert_index)
    for demo in synth_set.demos:
        r = demo.record
        _feed(h, [demo.name, r.ee_pos, r.timestamps, r.actions, r.demonstrator, r.theta_deg])
        _feed(h, [r.rho, r.created, r.ep_meta, r.attrs, list(demo.defects)])
        _feed(h, getattr(demo, "truth", None))
    return h.hexdigest()[:16]


# Computed with the generators as they were before the shape choice (commit d9ae020).
_HASHES_BEFORE_SHAPES = {
    ("single", "wiping", 0): "49209513bc72d748",
    ("human", "wiping", 0): "b8fa40483160fa81",
    ("single", "wiping", 3): "097c8ea59a89d633",
    ("human", "wiping", 3): "1a7afac8275a66cd",
    ("single", "weaving", 0): "ea0a2df9201b48ca",
    ("human", "weaving", 0): "cb7936f5503b416d",
    ("single", "weaving", 3): "19f722cbedbb790b",
    ("human", "weaving", 3): "634218de03685821",
    ("single", "pick_and_place", 0): "98c43c7a6a3b29c1",
    ("human", "pick_and_place", 0): "767b4b75d9746246",
    ("single", "pick_and_place", 3): "b41c79067f3838ef",
    ("human", "pick_and_place", 3): "161be04eec87ab1d",
}


def test_the_guide_sets_are_bit_identical_to_before_the_shape_choice() -> None:
    for (style, task, seed), expected in _HASHES_BEFORE_SHAPES.items():
        make = make_demo_set if style == "single" else make_human_set
        assert _set_hash(make(task, 4, seed)) == expected, (style, task, seed)
        assert _set_hash(make(task, 4, seed, shape=None)) == expected, (style, task, seed)


@functools.cache
def _dense(shape: LoopShape) -> KDTree:
    """20000 points of the loop (≤ 0.05 mm apart), by one inverse FFT of its coefficients."""
    spectrum = np.zeros(20000, dtype=complex)
    spectrum[np.arange(-shape.harmonics, shape.harmonics + 1) % 20000] = shape.coefficients
    z = np.fft.ifft(spectrum) * 20000
    return KDTree(np.stack([z.real, z.imag], axis=1))


def _on_loop_distance(truth_uv: np.ndarray, theta_deg: float, rho: float, shape) -> float:
    """Largest distance [m] of truth samples, mapped back by θ/ρ, from the loop's points."""
    back = similarity_transform(np.asarray(truth_uv, float), -theta_deg, 1.0 / rho)
    return float(_dense(shape).query(back)[0].max())


@pytest.mark.parametrize("kind", ["random", "figure_eight", "stroke"])
def test_single_style_sets_draw_the_given_loop_with_the_usual_defects(kind) -> None:
    shape = draw_set_loop(kind, 11)
    synth_set = make_demo_set("weaving", 8, 2, shape=shape)
    demos = demos_from_recording(synth_set.recording)
    distances = []
    for demo, raw in zip(synth_set.demos, demos, strict=True):
        record = demo.record
        np.testing.assert_allclose(
            demo.truth,
            similarity_transform(shape.points(TRUTH_SAMPLES), record.theta_deg, record.rho),
        )
        truth_uv = record.attrs["truth_uv"]
        assert _on_loop_distance(truth_uv, record.theta_deg, record.rho, shape) < 1e-4
        distances.append(distance_to_truth(raw.positions, demo.truth))
        if not demo.is_expert:
            assert set(demo.defects) & set(NOISE_DEFECTS) and set(demo.defects) & set(SHAPE_DEFECTS)
    expert = distances.pop(synth_set.expert_index)
    assert expert < 1e-3 and expert < min(distances) / 3, (expert, min(distances))


def test_human_style_sets_draw_the_given_loop_with_the_usual_defects() -> None:
    shape = draw_set_loop("random", 4)
    human = make_human_set("wiping", 8, 1, shape=shape)
    plane = default_plane("wiping")
    errors = []
    for demo in human.demos:
        truth = demo.record.attrs["truth_uv"]
        on = demo.record.attrs["truth_on_loop"].astype(bool)
        assert 0 < np.count_nonzero(on) < on.size  # rest, approach and retreat around the loops
        assert _on_loop_distance(truth[on], demo.theta_deg, demo.rho, shape) < 1e-4
        errors.append(
            float(np.mean(np.linalg.norm(plane.to_plane(demo.record.ee_pos) - truth, axis=1)))
        )
        if not demo.is_expert:
            assert set(demo.defects) & set(NOISE_DEFECTS) and set(demo.defects) & set(SHAPE_DEFECTS)
    expert = errors.pop(human.expert_index)
    assert expert < 1e-3 and expert < min(errors) / 2, (expert, min(errors))


def test_the_loop_is_stored_with_the_set() -> None:
    shape = draw_set_loop("d_shape", 0)
    for synth_set in (
        make_d1("wiping", 0, shape=shape),
        make_human_set("wiping", 2, 0, shape=shape),
    ):
        kwargs = synth_set.recording.env_args["env_kwargs"]
        assert kwargs["shape"] == "d_shape" and kwargs["task"] == "wiping"
        stored = LoopShape(
            np.array([complex(re, im) for re, im in kwargs["shape_coefficients"]]), "x"
        )
        np.testing.assert_array_equal(stored.coefficients, shape.coefficients)
    assert "shape" not in make_d1("wiping", 0).recording.env_args["env_kwargs"]


def test_the_cli_draws_one_loop_per_set_from_its_seed(tmp_path) -> None:
    path = tmp_path / "random.hdf5"
    main(
        [
            "synth",
            "--task",
            "weaving",
            "--style",
            "human",
            "--seed",
            "5",
            "--shape",
            "random",
            "--out",
            str(path),
        ]
    )
    recording = read_recording(path)
    kwargs = recording.env_args["env_kwargs"]
    shape = draw_set_loop("random", 5, "weaving")
    assert (kwargs["shape_kind"], kwargs["shape_seed"], kwargs["shape"]) == (
        "random",
        5,
        shape.label,
    )
    for record in recording.demos.values():
        on = np.asarray(record.attrs["truth_on_loop"]).astype(bool)
        theta, rho = record.attrs["truth_theta_deg"], record.attrs["truth_rho"]
        assert _on_loop_distance(record.attrs["truth_uv"][on], theta, rho, shape) < 1e-4
    main(
        [
            "synth",
            "--task",
            "weaving",
            "--seed",
            "5",
            "--shape",
            "oval",
            "--shape-seed",
            "9",
            "--out",
            str(tmp_path / "oval.hdf5"),
        ]
    )
    kwargs = read_recording(tmp_path / "oval.hdf5").env_args["env_kwargs"]
    oval = draw_set_loop("oval", 9)
    assert kwargs["shape_seed"] == 9
    np.testing.assert_array_equal(
        np.array(kwargs["shape_coefficients"])[:, 0], np.real(oval.coefficients)
    )


def test_a_task_without_a_guide_needs_a_shape_and_a_safe_name() -> None:
    shape = draw_set_loop("arch", 1)
    a = make_human_set("stirring", 4, 3, shape=shape)
    b = make_human_set("stirring", 4, 3, shape=shape)
    assert a.task == "stirring" and a.recording.plane == default_plane("wiping")
    assert _set_hash(a) == _set_hash(b)  # seeded from the name, stably
    assert _set_hash(a) != _set_hash(make_human_set("wiping", 4, 3, shape=shape))
    single = make_demo_set("stirring", 4, 3, shape=shape)
    assert single.recording.env_args["env_kwargs"]["task"] == "stirring"
    with pytest.raises(UnknownTaskError, match="valid tasks are"):
        make_human_set("stirring", 4, 3)
    with pytest.raises(ConfigError, match="not safe"):
        make_demo_set("../stirring", 4, 3, shape=shape)
