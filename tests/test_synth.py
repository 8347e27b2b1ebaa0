"""Synthetic demo sets: deterministic, one expert-like demo, visible defects, valid records."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.recording import read_recording, write_recording
from bt_pipeline.data.records import MIN_SAMPLES, forward_difference_actions
from bt_pipeline.data.shapes import canonical_loop, similarity_transform
from bt_pipeline.data.synth import (
    DEFECTS,
    DEMONSTRATORS,
    NOISE_DEFECTS,
    SAMPLE_RATE_HZ,
    SHAPE_DEFECTS,
    make_d1,
    make_d2,
    make_demo_set,
)
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
