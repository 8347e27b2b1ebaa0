"""Tests of ILEED's learned expertise (bt_pipeline.evaluate.learners.ileed)."""

from __future__ import annotations

import numpy as np

from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.synth import make_d1
from bt_pipeline.evaluate.learners import learner_config, train_learner
from bt_pipeline.evaluate.learners.ileed import demonstrator_ids

N = 300


def loops_by_two_demonstrators(seed: int = 0) -> tuple[np.ndarray, list[str]]:
    """Two clean and two jittery (4 mm white noise) ellipses: demonstrators "clean" and "noisy"."""
    rng = np.random.default_rng(seed)
    demos = []
    for k in range(4):
        phase = np.linspace(0.0, 2.0 * np.pi, N) + rng.uniform(0.0, 2.0 * np.pi)
        loop = np.stack([0.12 * np.cos(phase), 0.06 * np.sin(phase)], axis=1)
        demos.append(loop + (0.004 if k >= 2 else 0.0) * rng.standard_normal((N, 2)))
    return np.stack(demos), ["clean", "clean", "noisy", "noisy"]


def test_expertise_of_a_clean_demonstrator_exceeds_a_jittery_ones() -> None:
    demos, who = loops_by_two_demonstrators()
    trained = train_learner("ileed", demos, who, learner_config("ileed", quick=True))
    assert set(trained.expertise) == {"clean", "noisy"}
    assert trained.expertise["clean"] > 0.9
    assert trained.expertise["clean"] > trained.expertise["noisy"] + 0.3


def test_expertise_ranks_the_synthetic_expert_first() -> None:
    # pick_and_place seed 0 has a tremor-only naive demo the uniform random model ties with the
    # expert (both σ ≈ 1).
    synth = make_d1("pick_and_place", seed=0)
    demos = demos_from_recording(synth.recording)
    positions = np.stack([d.positions for d in demos])
    who = [d.demonstrator for d in demos]
    trained = train_learner("ileed", positions, who, learner_config("ileed", quick=True))
    expert = who[synth.expert_index]
    others = [v for name, v in trained.expertise.items() if name != expert]
    assert trained.expertise[expert] > max(others) + 0.2, trained.expertise


def test_uniform_random_model_also_trains() -> None:
    demos, who = loops_by_two_demonstrators()
    config = learner_config("ileed", quick=True, random_model="uniform", steps=50)
    trained = train_learner("ileed", demos, who, config)
    assert np.all(np.isfinite(trained.loss_history))
    assert set(trained.expertise) == {"clean", "noisy"}
    assert all(0.0 <= v <= 1.0 for v in trained.expertise.values())


def test_demonstrator_ids_group_equal_names_in_order_of_first_appearance() -> None:
    names, index = demonstrator_ids(["b", "a", "b", "c"], 4)
    assert names == ["b", "a", "c"]
    np.testing.assert_array_equal(index, [0, 1, 0, 2])
    names, index = demonstrator_ids(None, 3)
    assert names == ["0", "1", "2"]
    np.testing.assert_array_equal(index, [0, 1, 2])
