"""Demos logged at a low rate (6-12 Hz, as other labs' tools do) are scored as smooth paths."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bt_pipeline.clean.periodic import pool_preferences, segment_all, span_demo
from bt_pipeline.data.demo import demos_from_recording, resample_uniform
from bt_pipeline.data.synth_human import make_human_set
from bt_pipeline.data.tasks import Task
from bt_pipeline.score.utility import score_demos


def _every_fifth(task: Task, seed: int):
    """A human-style set of 8 with every fifth sample kept (30-60 Hz -> 6-12 Hz)."""
    synth = make_human_set(task, 8, seed)
    records = {
        name: dataclasses.replace(
            r,
            ee_pos=r.ee_pos[::5],
            timestamps=r.timestamps[::5],
            actions=None,
            ee_quat=None,
            joint_pos=None,
            gripper=None,
            states=None,
        )
        for name, r in synth.recording.demos.items()
    }
    return synth, dataclasses.replace(synth.recording, demos=records)


@pytest.mark.parametrize(
    ("task", "seed"), [("pick_and_place", 0), ("pick_and_place", 1), ("weaving", 2)]
)
def test_low_rate_sets_still_select_the_expert(task: Task, seed: int) -> None:
    """Resampled linearly, these 6-12 Hz sets' corners read as jerk and a lopsided demo was
    chosen as the best (all three); resampled by PCHIP the expert-like demo is chosen."""
    synth, recording = _every_fifth(task, seed)
    demos = demos_from_recording(recording)
    segments = segment_all(demos)
    preferences = pool_preferences(demos, segments)
    spans = [
        span_demo(d, s, d.n_samples, p)
        for d, s, p in zip(demos, segments, preferences, strict=True)
    ]
    assert score_demos(spans).best_index == synth.expert_index


def test_resampling_passes_through_samples_without_overshoot() -> None:
    """Every sample is kept where the new times meet it, and a spike or a pause does not ring."""
    t = np.array([0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    x = np.array([[0.0], [0.0], [0.0], [1.0], [0.0], [0.0], [0.0]])  # a pause, a spike, a pause
    out = resample_uniform(x, t, 61)
    assert np.allclose(out[::10], x)
    assert out.min() >= 0.0 and out.max() <= 1.0
    assert np.all(out[:20] == 0.0) and np.all(out[41:] == 0.0)
