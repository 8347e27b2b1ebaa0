"""bt_pipeline.clean.cleaned_utility: a cleaned demo's Ũ on its raw set's scale, a note for
every Ũ that cleaning lowered, and how far cleaning moved a demo from its raw samples."""

from __future__ import annotations

import numpy as np
import pytest

from bt_pipeline.clean.cleaned_utility import cleaned_span, moved_from_raw, utility_notes
from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.data.demo import Demo, demos_from_recording
from bt_pipeline.data.synth import make_d1
from bt_pipeline.data.tasks import default_plane
from bt_pipeline.score.utility import RawMetrics, ScoreConfig, score_demos


def plain_demo(name: str, rng: np.random.Generator) -> Demo:
    t = np.linspace(0.0, 1.0, 64)
    positions = np.column_stack([np.cos(2 * np.pi * t), np.sin(2 * np.pi * t)]) * 0.1
    positions += rng.normal(0.0, 1e-3, positions.shape)
    return Demo(positions, "wiping", "f.hdf5", name, "ann", 0.0, 1.0, default_plane("wiping"))


def test_a_lowered_utility_is_explained_by_the_terms_that_cost_it() -> None:
    """A demo whose MI fell to the set's lowest (its losses unchanged) gets one note naming MI
    and the fall; a demo left as it was, or better in every metric, gets none."""
    rng = np.random.default_rng(3)
    config = ScoreConfig()
    demos = [plain_demo(f"demo_{k}", rng) for k in range(4)]
    metrics = [RawMetrics(*(float(v) for v in rng.uniform(0.2, 1.0, 4))) for _ in demos]
    scores = score_demos(demos, config, metrics=metrics)
    top = int(np.argmax([m.mutual_information for m in metrics]))
    lowest = min(m.mutual_information for m in metrics)
    cleaned = list(metrics)
    m = metrics[top]
    cleaned[top] = RawMetrics(lowest, m.symmetry, m.closure, m.smoothness)  # Ĩ 1 -> 0
    other = (top + 1) % 4
    cleaned[other] = RawMetrics(10.0, 0.0, 0.0, 0.0)  # better than every raw demo
    (note,) = utility_notes(demos, scores, cleaned, config)
    before = scores.scores[top].utility
    assert note.startswith(f"{demos[top].label}: cleaning lowered its Ũ from {before:.3f} to ")
    assert f"to {before - (1 - config.beta):.3f} (I(S; A) -{1 - config.beta:.3f})" in note


def test_moved_is_measured_at_the_raw_sample_times() -> None:
    rng = np.random.default_rng(0)
    demo = plain_demo("demo_0", rng)
    shift = np.array([0.003, -0.004])  # 5 mm
    span = cleaned_span(demo, demo.positions + shift, passed=False)
    mean, most = moved_from_raw(demo, span.raw_samples()[0])
    assert mean == pytest.approx(0.005, abs=1e-12) and most == pytest.approx(0.005, abs=1e-12)
    bent = demo.positions.copy()
    bent[10] += [0.0, 0.02]
    mean, most = moved_from_raw(demo, cleaned_span(demo, bent, passed=False).raw_samples()[0])
    assert most == pytest.approx(0.02, abs=1e-12) and mean == pytest.approx(0.02 / 64, abs=1e-12)
    passed = cleaned_span(demo, demo.positions + shift, passed=True)
    assert moved_from_raw(demo, passed.raw_samples()[0]) == (0.0, 0.0)


def test_the_best_demo_passed_through_keeps_its_utility_and_the_others_are_rescored() -> None:
    """Raw Ũ is selection's (bt score's); a cleaned demo is read by the same function against
    the raw set's normaliser; the passed-through best demo did not move and kept its Ũ."""
    demos = demos_from_recording(make_d1("wiping", 1).recording)
    result = clean_demos(demos, CleanOptions(epochs=3, progress=False, write_rrd=False))
    best = result.best_index
    raw = [s.utility for s in result.scores.scores]
    assert [m.utility for m in result.raw] == raw
    assert result.cleaned[best].utility == raw[best] and result.moved(best) == (0.0, 0.0)
    others = [i for i in range(len(demos)) if i != best]
    assert all(result.moved(i)[0] > 0.0 for i in others)
    assert all(0.0 <= m.utility <= 1.0 for m in result.cleaned)
    assert [m.utility for m in result.cleaned] != raw  # cleaning changed the others' Ũ
    lowered = {n.split(": cleaning lowered")[0] for n in result.notes if "lowered its Ũ" in n}
    fell = {result.demos[i].label for i in others if result.cleaned[i].utility < raw[i] - 5e-4}
    assert lowered == fell
