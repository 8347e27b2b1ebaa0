"""The competence (oracle) checks: perfect demos, and learners that can learn every task from them
(the figure-eight included) and make the loop attracting; several preferences get averaged."""

from __future__ import annotations

import numpy as np
import pytest

from bt_pipeline.data.synth import DEMONSTRATORS
from bt_pipeline.evaluate.distance import chamfer_distance
from bt_pipeline.evaluate.learners import LEARNERS, learner_config, train_learner
from bt_pipeline.evaluate.oracle import competence_check, coverage, perfect_demos
from bt_pipeline.exceptions import ConfigError


def test_perfect_demos_lie_on_their_true_loops_with_their_own_timing() -> None:
    data = perfect_demos("weaving", DEMONSTRATORS[:2], per_teacher=2, n_samples=300, seed=3)
    assert data.positions.shape == (4, 300, 2)
    assert data.demonstrators == ("teacher_a", "teacher_b", "teacher_a", "teacher_b")
    for demo, name in zip(data.positions, data.demonstrators, strict=True):
        assert chamfer_distance(demo, data.truths[name]) < 0.001
        assert coverage(demo, data.truths[name]) == 1.0
    # own timing: different start points and uneven speed along the loop
    assert np.linalg.norm(data.positions[0, 0] - data.positions[2, 0]) > 0.005
    speeds = np.linalg.norm(np.diff(data.positions[0], axis=0), axis=1)
    assert speeds.max() > 1.5 * speeds.min()


def test_coverage_counts_the_share_of_the_loop_passed_within_5_mm() -> None:
    t = np.linspace(0.0, 2.0 * np.pi, 400, endpoint=False)
    loop = np.stack([0.1 * np.cos(t), 0.1 * np.sin(t)], axis=1)
    assert coverage(loop[:200], loop) == pytest.approx(0.5, abs=0.02)
    assert coverage(loop * 1.1, loop) == 0.0  # 1 cm outside everywhere


@pytest.mark.parametrize("learner", LEARNERS)
def test_every_learner_learns_the_figure_eight_from_one_demonstrator(learner: str) -> None:
    row = competence_check("one", "weaving", learner, quick=True, rollouts=6)  # type: ignore[arg-type]
    assert row.coverage >= 0.9, row
    assert row.passed, row
    assert row.converged >= 0.8, row  # starts 1-3 cm off the loop


def test_one_policy_on_four_demonstrators_averages_their_preferences() -> None:
    row = competence_check("four", "wiping", "bc", quick=True, rollouts=8)
    # nearer the mean-preference loop than to the loop of the demonstrator it started from
    assert row.mean_loop_error_m < 0.5 * row.shape_error_m, row
    assert not row.passed


@pytest.mark.parametrize("learner", LEARNERS)
def test_a_conditioned_learner_keeps_each_demonstrator_s_preference(learner: str) -> None:
    """Given each demonstrator's (θ, ρ) as an input, one policy trained on the four D1
    demonstrators draws each one's own loop (within 2 mm), not their mean."""
    row = competence_check("four", "wiping", learner, quick=True, rollouts=8, conditioned=True)  # type: ignore[arg-type]
    assert row.check == "four_conditioned"
    assert row.nearest_own == 1.0, row
    assert row.coverage >= 0.9 and row.shape_error_m <= 0.002, row
    assert row.mean_loop_error_m > 4 * row.shape_error_m, row


def test_a_conditioned_policy_needs_the_preference_it_draws() -> None:
    data = perfect_demos("wiping", DEMONSTRATORS[:2], per_teacher=1, n_samples=120, seed=1)
    prefs = np.array([[t.theta_deg, t.rho] for t in DEMONSTRATORS[:2]])
    config = learner_config("bc", quick=True, steps=5)
    policy = train_learner("bc", data.positions, None, config, prefs).policy
    x0 = data.positions[:, 0]
    assert policy.conditioned
    assert policy.rollout(x0, 4, preferences=prefs).shape == (2, 4, 2)
    assert policy.rollout(x0, 4, preferences=prefs[0]).shape == (2, 4, 2)
    with pytest.raises(ConfigError, match="needs the preference"):
        policy.rollout(x0, 4)
    with pytest.raises(ConfigError, match="one per state"):
        policy.rollout(x0, 4, preferences=np.tile(prefs, (2, 1)))
    with pytest.raises(ConfigError, match="ρ > 0"):
        policy.rollout(x0, 4, preferences=[10.0, -1.0])
    with pytest.raises(ConfigError, match="one \\(θ, ρ\\) per demo"):
        train_learner("bc", data.positions, None, config, prefs[:1])
    plain = train_learner("bc", data.positions, None, config).policy
    with pytest.raises(ConfigError, match="without preferences"):
        plain.rollout(x0, 4, preferences=prefs)
