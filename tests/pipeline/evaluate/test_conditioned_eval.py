"""The preference-conditioned protocol: starts on each demonstrator's loop, per-rollout scores
against that demonstrator's own true loop, and a conditioned learner that keeps preferences."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import KDTree

from bt_pipeline.data.shapes import canonical_loop
from bt_pipeline.data.synth import DEMONSTRATORS
from bt_pipeline.evaluate.conditioned import (
    TAUS_MM,
    DemonstratorLoop,
    evaluate_conditioned,
    loops_by_demonstrator,
    score_rollouts,
    starts_on_loops,
)
from bt_pipeline.evaluate.oracle import perfect_demos
from bt_pipeline.exceptions import ConfigError


def circle(radius: float, k: int = 600, centre: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    t = np.linspace(0.0, 2.0 * np.pi, k, endpoint=False)
    return np.stack([centre[0] + radius * np.cos(t), centre[1] + radius * np.sin(t)], axis=1)


LOOPS = [
    DemonstratorLoop("a", 0.0, 1.0, circle(0.1)),
    DemonstratorLoop("b", 10.0, 1.3, circle(0.13, centre=(0.01, 0.0))),
]


def test_a_rollout_on_its_own_loop_succeeds_and_one_on_another_fails() -> None:
    path = circle(0.1, 300)
    path = np.concatenate([path, path[:1]])
    wider = path * 1.05  # 5 mm outside everywhere
    t = np.linspace(0.0, np.pi, path.shape[0])
    half = 0.1 * np.stack([np.cos(t), np.sin(t)], axis=1)
    scores = score_rollouts(np.stack([path, path[::-1], wider, half]), [0, 0, 0, 0], LOOPS)
    ok = scores.success
    assert ok[0].all() and ok[1].all()  # either direction
    assert scores.progress[:2] == pytest.approx([1.0, 1.0], abs=0.01)
    assert scores.shape_mm[0] < 0.5 and 4.5 < scores.shape_mm[2] < 5.5
    # 5 mm off: fails at τ ≤ 3 mm, succeeds from 7.5 mm on.
    assert not ok[2, TAUS_MM.index(3.0)] and ok[2, TAUS_MM.index(7.5)]
    assert not ok[3].any() and scores.progress[3] == pytest.approx(0.5, abs=0.02)
    # Drawn for demonstrator b, the same circle lies 3 cm off b's loop.
    other = score_rollouts(path[None], [1], LOOPS)
    assert not other.success[0, TAUS_MM.index(20.0)] and other.shape_mm[0] > 25
    assert scores.by_demonstrator(scores.shape_mm).shape == (2,)
    assert np.isnan(scores.by_demonstrator(scores.shape_mm)[1])


def test_starts_lie_on_or_off_each_demonstrator_s_loop() -> None:
    x0, who = starts_on_loops(LOOPS, 5, seed=3)
    assert x0.shape == (10, 2) and list(who) == [0] * 5 + [1] * 5
    for start, w in zip(x0, who, strict=True):
        gap, _ = KDTree(LOOPS[w].loop).query(start)
        assert gap < 0.02
    off, who = starts_on_loops(LOOPS, 20, seed=3, off_m=(0.01, 0.03))
    for start, w in zip(off, who, strict=True):
        gap, _ = KDTree(LOOPS[w].loop).query(start)
        assert 0.0095 < gap < 0.0305
    with pytest.raises(ConfigError, match="≥ 1"):
        starts_on_loops(LOOPS, 0, seed=0)


def test_a_conditioned_learner_draws_every_demonstrator_s_loop_the_paper_s_does_not() -> None:
    data = perfect_demos("wiping", DEMONSTRATORS, per_teacher=1, n_samples=200, seed=2)
    prefs = np.array([[t.theta_deg, t.rho] for t in DEMONSTRATORS])
    truths = [data.truths[name] for name in data.demonstrators]
    loops, index = loops_by_demonstrator(data.demonstrators, prefs, truths)
    assert len(loops) == 4 and index["teacher_a"] == 0
    conditioned = evaluate_conditioned(
        "bc", "truth", data.positions, prefs, loops, seed=0, quick=True, per_demonstrator=4
    )
    paper = evaluate_conditioned(
        "bc",
        "truth",
        data.positions,
        prefs,
        loops,
        seed=0,
        quick=True,
        per_demonstrator=4,
        conditioned=False,
    )
    assert conditioned.scores.success_rate(5.0) == 1.0
    assert conditioned.robust.success_rate(10.0) >= 0.75
    assert np.all(conditioned.scores.by_demonstrator(conditioned.scores.shape_mm) < 2.0)
    assert paper.scores.success_rate(5.0) <= 0.25
    assert np.mean(paper.scores.shape_mm) > 4 * np.mean(conditioned.scores.shape_mm)


def test_a_figure_eight_traced_once_goes_around_once() -> None:
    """Through the crossing a path keeps to its branch: progress 1, not the 0 a global
    nearest-point projection gives when it jumps to the other branch."""
    eight = canonical_loop("weaving", 600)
    loops = [DemonstratorLoop("a", 0.0, 1.0, eight)]
    path = np.concatenate([eight[::2], eight[:1]])
    scores = score_rollouts(np.stack([path, path[::-1]]), [0, 0], loops)
    assert scores.progress == pytest.approx([1.0, 1.0], abs=0.01)
    assert scores.success[:, TAUS_MM.index(2.0)].all()


def test_l4_reads_the_timing_the_shape_distance_does_not() -> None:
    """On the loop at its own even pace L4 is ~0; the same points rushed through half the loop
    and crawling through the other half keep the shape distance ~0 but not L4 (Eq. 9)."""
    loop = circle(0.1, 600)
    s = np.linspace(0.0, 1.0, 301)
    even = 0.1 * np.stack([np.cos(2 * np.pi * s), np.sin(2 * np.pi * s)], axis=1)
    warp = s + 0.12 * np.sin(2 * np.pi * s)
    uneven = 0.1 * np.stack([np.cos(2 * np.pi * warp), np.sin(2 * np.pi * warp)], axis=1)
    scores = score_rollouts(np.stack([even, uneven]), [0, 0], [DemonstratorLoop("a", 0, 1, loop)])
    assert scores.shape_mm == pytest.approx([0.0, 0.0], abs=1.0)
    assert scores.l4_mm[0] < 0.5 and scores.l4_mm[1] > 20 * max(scores.l4_mm[0], 0.1)


def _perfect_four() -> tuple[np.ndarray, np.ndarray, list[DemonstratorLoop], list[str]]:
    data = perfect_demos("wiping", DEMONSTRATORS, per_teacher=1, n_samples=200, seed=2)
    prefs = np.array([[t.theta_deg, t.rho] for t in DEMONSTRATORS])
    truths = [data.truths[name] for name in data.demonstrators]
    loops, _ = loops_by_demonstrator(data.demonstrators, prefs, truths)
    return data.positions, prefs, loops, list(data.demonstrators)


def test_held_out_rolls_out_only_the_demonstrator_left_out_of_training() -> None:
    x, prefs, loops, names = _perfect_four()
    e = evaluate_conditioned(
        "bc", "truth", x, prefs, loops, seed=0, quick=True, per_demonstrator=3,
        demonstrators=names, approach="held_out", held_out=2,
    )  # fmt: skip
    assert set(e.scores.who.tolist()) == {2} and e.scores.who.size == 3
    assert np.isfinite(e.examples[2]).all() and np.isnan(e.examples[[0, 1, 3]]).all()
    seen = evaluate_conditioned(
        "bc", "truth", x, prefs, loops, seed=0, quick=True, per_demonstrator=3,
        demonstrators=names,
    )  # fmt: skip
    # The same starts: the demonstrator's rollouts begin where the seen policy's do.
    assert seen.scores.who.size == 12
    with pytest.raises(ConfigError, match="demonstrator"):
        evaluate_conditioned("bc", "t", x, prefs, loops, seed=0, approach="held_out")


def test_a_per_demonstrator_learner_draws_its_own_demonstrator_s_loop() -> None:
    """Trained on one demonstrator's perfect demo alone, each unconditioned policy draws that
    demonstrator's loop (the pooled unconditioned one does not: the test above)."""
    x, prefs, loops, names = _perfect_four()
    e = evaluate_conditioned(
        "bc", "truth", x, prefs, loops, seed=0, quick=True, per_demonstrator=4,
        demonstrators=names, approach="per_demonstrator",
    )  # fmt: skip
    assert sorted(set(e.scores.who.tolist())) == [0, 1, 2, 3]
    assert np.all(e.scores.by_demonstrator(e.scores.shape_mm) < 2.0)
    assert e.scores.success_rate(5.0) >= 0.9
