"""The geometry of a crowd set's shared biases (bt_pipeline.data.crowd_biases)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bt_pipeline.data.crowd_biases import (
    MARGIN,
    MIN_LOBE,
    CrowdBiases,
    apply_biases,
    draw_biases,
    self_crossing,
    stop_short,
)
from bt_pipeline.data.random_loops import LoopFamily, draw_set_loop
from bt_pipeline.data.shapes import canonical_shape


def _guide(task: str):
    return lambda phase: canonical_shape(task, phase)


def _drawn(loop, seed: int) -> CrowdBiases:
    return draw_biases(loop, [0, 1, 2, 3], np.random.default_rng(seed))


def test_the_figure_eight_guide_crosses_itself_at_its_centre() -> None:
    crossing = self_crossing(_guide("weaving"))
    assert crossing is not None
    np.testing.assert_allclose(crossing, (0.0, 0.5), atol=1e-9)  # φ = 0 and π, at the origin


@pytest.mark.parametrize("task", ["wiping", "pick_and_place"])
def test_the_other_guides_do_not_cross_themselves(task) -> None:
    assert self_crossing(_guide(task)) is None


@pytest.mark.parametrize("family", ["figure_eight", "oval", "asymmetric", "stroke", "arch"])
def test_only_the_random_figure_eights_cross_themselves(family: LoopFamily) -> None:
    for seed in range(4):
        shape = draw_set_loop(family, seed)
        crossing = self_crossing(shape.at)
        if family != "figure_eight":
            assert crossing is None, (family, seed)
            continue
        assert crossing is not None, seed
        a, b = crossing
        assert MIN_LOBE <= b - a <= 1.0 - MIN_LOBE
        ends = shape.at(2.0 * np.pi * np.array([a, b]))
        assert np.linalg.norm(ends[0] - ends[1]) < 1e-9  # refined onto the crossing


@pytest.mark.parametrize("task", ["wiping", "weaving", "pick_and_place"])
def test_the_bias_intervals_are_disjoint_and_the_pause_is_on_the_drawn_part(task) -> None:
    for seed in range(20):
        biases = _drawn(_guide(task), seed)
        names = ("cut", "undershoot", "bulge", "missing")
        spans = sorted(
            (getattr(biases, f"{n}_start"), getattr(biases, f"{n}_width")) for n in names
        )
        # Round the loop once in order of start, each interval ends MARGIN before the next.
        for (start, width), (following, _) in zip(spans, [*spans[1:], spans[0]], strict=True):
            assert (following - start) % 1.0 - width >= MARGIN - 1e-12, (seed, spans)
        drawn = (biases.pause_phase - biases.missing_start - biases.missing_width) % 1.0
        assert 0.2 - 1e-9 <= drawn / (1.0 - biases.missing_width) <= 0.8 + 1e-9
        assert (biases.lobe_start is None) == (task != "weaving")


def test_stopping_short_eases_to_a_rest_before_the_left_out_part() -> None:
    biases = _drawn(_guide("wiping"), 0)
    progress = np.linspace(0.0, 1.0, 20_001)
    drawn = stop_short(progress, biases)
    stop = 1.0 - biases.missing_width
    np.testing.assert_array_equal(drawn[progress <= stop - 0.02], progress[progress <= stop - 0.02])
    np.testing.assert_allclose(drawn[progress >= stop + 0.02], stop)
    speed = np.diff(drawn) / np.diff(progress)
    assert speed.min() >= -1e-9 and speed.max() <= 1.0 + 1e-9  # never back, never faster
    assert np.abs(np.diff(speed)).max() < 1e-2  # no jump in speed


@pytest.mark.parametrize("task", ["wiping", "weaving"])
def test_without_magnitudes_only_the_wrong_lobe_moves_the_hand_and_the_path_stays_smooth(
    task,
) -> None:
    loop = _guide(task)
    biases = dataclasses.replace(_drawn(loop, 3), cut_blend=0.0, undershoot_depth=0.0, bulge_m=0.0)
    phase = 2.0 * np.pi * np.linspace(0.0, 1.0, 40_001)
    path = apply_biases(loop, phase, biases, np.zeros(2))
    step = np.linalg.norm(np.diff(path, axis=0), axis=1)
    if biases.lobe_start is None:
        np.testing.assert_allclose(path, loop(phase), atol=1e-12)
    else:
        assert not np.allclose(path, loop(phase))
    # Continuous everywhere, the kisses included: no step much longer than the loop's own.
    own = np.linalg.norm(np.diff(loop(phase), axis=0), axis=1)
    assert step.max() < 2.5 * own.max()
