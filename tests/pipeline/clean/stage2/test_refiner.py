"""Tests of Stage 2, the LSTM refinement with adaptive β (bt_pipeline.clean.stage2.refiner)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import torch
from scipy.spatial import KDTree

from bt_pipeline.clean.stage2.config import EpochStats, RefineConfig, RefineResult
from bt_pipeline.clean.stage2.objective import Adam
from bt_pipeline.clean.stage2.refiner import refine_demos, update_beta
from bt_pipeline.clean.stage2.scales import refine_normaliser
from bt_pipeline.evaluate.distance import distance_to_truth
from bt_pipeline.exceptions import ConfigError, DemoError
from bt_pipeline.score.losses import closure_loss, smoothness_loss, symmetry_loss
from bt_pipeline.score.utility import Normaliser

N = 120
THETAS = np.array([5.0, -5.0, 10.0, -10.0])
RHOS = np.array([1.0, 1.1, 1.2, 1.3])
FAST: dict[str, Any] = {"hidden": 8, "epochs": 30, "patience": 0}
"""A small network and few epochs: enough to see the behaviour, fast enough for CI."""


def truth_curve(i: int, phase: np.ndarray) -> np.ndarray:
    """Demonstrator i's noise-free figure-8 at the given phases [rad], shape (len, 2) [m]."""
    a = np.radians(THETAS[i])
    rotation = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    uv = np.column_stack([0.08 * np.sin(phase), 0.05 * np.sin(2 * phase)])
    return RHOS[i] * uv @ rotation.T


def toy_set(seed: int = 0) -> dict[str, Any]:
    """4 demos of known truth: demo 0 expert-like, the others noisy and drifting."""
    rng = np.random.default_rng(seed)
    phase = 2 * np.pi * np.arange(N) / N
    references = np.stack([truth_curve(i, phase) for i in range(4)])
    positions = references + rng.normal(0.0, 0.0003, references.shape)
    for i in range(1, 4):
        drift = np.linspace(0.0, 1.0, N)[:, None] * rng.uniform(-0.015, 0.015, 2)
        positions[i] += rng.normal(0.0, 0.003, (N, 2)) + drift
    dense = 2 * np.pi * np.arange(600) / 600
    trees = [KDTree(r) for r in references]

    def rewards(paths: np.ndarray) -> np.ndarray:  # Gaussian tube around each reference
        return np.array(
            [
                np.mean(np.exp(-(t.query(p)[0] ** 2) / 2e-5))
                for t, p in zip(trees, paths, strict=True)
            ]
        )

    raw = np.array(
        [
            [0.0, symmetry_loss(p, t), closure_loss(p), smoothness_loss(p)]
            for p, t in zip(positions, THETAS, strict=True)
        ]
    )
    shape = np.linalg.norm(positions - references, axis=-1).mean(axis=1)
    return {
        "positions": positions,
        "references": references,
        "thetas_deg": THETAS,
        "best_index": 0,
        "reward_fn": rewards,
        "normaliser": refine_normaliser(Normaliser.from_values(raw), shape),
        "truths": [truth_curve(i, dense) for i in range(4)],
    }


def run(data: dict[str, Any], **kwargs: Any) -> RefineResult:
    args = {k: v for k, v in data.items() if k != "truths"}
    args.update(kwargs)
    return refine_demos(**args)


@pytest.fixture(scope="module")
def data() -> dict[str, Any]:
    return toy_set()


@pytest.fixture(scope="module")
def default_result(data: dict[str, Any]) -> RefineResult:
    return run(data, config=RefineConfig(**FAST))


def test_beta_update_follows_the_reward_as_the_paper_prescribes() -> None:
    betas = np.array([0.5, 0.5, 0.5, 0.95, 0.05])
    previous = np.full(5, 0.4)
    rewards = np.array([0.5, 0.3, 0.4, 0.9, 0.0])  # up, down, same, up a lot, down a lot
    new = update_beta(betas, rewards, previous, gamma=5.0)
    assert new[0] > 0.5 and new[1] < 0.5 and new[2] == 0.5
    assert new[3] == 1.0 and new[4] == 0.0  # clipped to [0, 1]
    np.testing.assert_allclose(new[:2], 0.5 + np.tanh(5.0 * np.array([0.1, -0.1])))
    slow = update_beta(betas, rewards, previous, gamma=5.0, rate=0.1)
    np.testing.assert_allclose(slow[:2] - 0.5, 0.1 * (new[:2] - 0.5))
    assert betas[0] == 0.5  # inputs untouched


def test_beta_follows_each_demos_own_reward_in_a_run(data: dict[str, Any]) -> None:
    calls: list[np.ndarray] = []

    def scripted(paths: np.ndarray) -> np.ndarray:  # demo 1 improves, demo 2 worsens
        k = len(calls)
        calls.append(paths)
        return np.array([0.5, 0.5 + 0.01 * k, 0.5 - 0.01 * k, 0.5])

    config = RefineConfig(variant="paper", hidden=8, epochs=4)
    result = run(data, reward_fn=scripted, config=config)
    assert result.beta_history.shape == (4, 4)
    assert result.betas[1] > 0.5 > result.betas[2]
    assert result.betas[0] == result.betas[3] == 0.5
    replay, last = np.full(4, 0.5), np.full(4, 0.5)  # the raw reward is 0.5 for all
    for k in range(4):  # every recorded β is the paper's update from the recorded rewards
        replay = update_beta(replay, result.reward_history[k], last, gamma=5.0)
        last = result.reward_history[k]
        np.testing.assert_allclose(result.beta_history[k], replay)


def test_training_starts_at_the_identity(data: dict[str, Any]) -> None:
    seen: list[np.ndarray] = []

    def recording(paths: np.ndarray) -> np.ndarray:
        seen.append(paths.copy())
        return np.full(len(paths), 0.5)

    x, ref = data["positions"], data["references"]
    # Call 0 scores the raw demos, call 1 the output of epoch 1 (before any step): the paper's
    # free Δ is 0 there, the default's gain ½ (halfway to the reference; the best demo as is).
    halfway = x + 0.5 * (ref - x)
    halfway[0] = x[0]
    for config, start in (
        (RefineConfig(variant="paper", hidden=8, epochs=2), x),
        (RefineConfig(variant="default", hidden=8, epochs=2), halfway),
    ):
        seen.clear()
        run(data, reward_fn=recording, config=config)
        np.testing.assert_allclose(seen[1], start, atol=1e-6)
        assert not np.allclose(seen[2], start, atol=1e-6)


def test_the_default_never_moves_a_sample_away_from_both_raw_and_reference(
    data: dict[str, Any], default_result: RefineResult
) -> None:
    x, ref, out = data["positions"], data["references"], default_result.refined
    # x̂ = x + g (ref − x) with g ∈ (0, 1): on the segment from x to ref, strictly inside.
    along = np.sum((out - x) * (ref - x), axis=2) / np.maximum(
        np.sum((ref - x) ** 2, axis=2), 1e-30
    )
    across = np.linalg.norm(out - x - along[..., None] * (ref - x), axis=2)
    assert np.all((along[1:] > 0.0) & (along[1:] < 1.0))
    assert across.max() < 1e-6
    assert 0.5 < along[1:].mean() < 1.0  # and it learnt to follow the reference


def test_refinement_is_deterministic_for_a_seed(
    data: dict[str, Any], default_result: RefineResult
) -> None:
    again = run(data, config=RefineConfig(**FAST))
    np.testing.assert_array_equal(again.refined, default_result.refined)
    np.testing.assert_array_equal(again.beta_history, default_result.beta_history)
    other = run(data, config=RefineConfig(**FAST, seed=1))
    assert not np.array_equal(other.refined, default_result.refined)


def test_default_refinement_brings_naive_demos_closer_to_the_truth(
    data: dict[str, Any], default_result: RefineResult
) -> None:
    truths = data["truths"]
    before = [distance_to_truth(p, t) for p, t in zip(data["positions"], truths, strict=True)]
    after = [distance_to_truth(p, t) for p, t in zip(default_result.refined, truths, strict=True)]
    assert np.mean(after[1:]) < 0.5 * np.mean(before[1:])
    for i in range(1, 4):
        assert closure_loss(default_result.refined[i]) < closure_loss(data["positions"][i])
        assert smoothness_loss(default_result.refined[i]) < smoothness_loss(data["positions"][i])
    # The best demo is passed through unchanged by the default variant.
    np.testing.assert_array_equal(default_result.refined[0], data["positions"][0])


def test_output_is_finite_shaped_and_inputs_untouched(data: dict[str, Any]) -> None:
    snapshot = {k: np.copy(data[k]) for k in ("positions", "references", "thetas_deg")}
    stats: list[EpochStats] = []
    result = run(
        data, config=RefineConfig(variant="paper", hidden=8, epochs=3), on_epoch=stats.append
    )
    assert result.refined.shape == (4, N, 2) and np.all(np.isfinite(result.refined))
    assert result.epochs == len(stats) == 3 and result.variant == "paper"
    assert result.loss_history.shape == (3,) and result.reward_history.shape == (3, 4)
    np.testing.assert_array_equal(result.betas, stats[-1].betas)
    assert not np.array_equal(result.refined[0], data["positions"][0])  # paper refines the best
    for key, value in snapshot.items():
        np.testing.assert_array_equal(data[key], value)


def test_variants_resolve_to_their_settings() -> None:
    paper = RefineConfig(variant="paper").resolve()
    assert (paper.epochs, paper.lr, paper.gamma, paper.beta_rate) == (300, 1e-3, 5.0, 1.0)
    assert paper.mi_term == "loss" and paper.refine_best and not paper.clamp_scores
    default = RefineConfig(lr=0.05).resolve()
    assert default.lr == 0.05 and default.mi_term == "floor" and not default.refine_best
    assert default.weights == (0.2, 0.2, 0.2, 0.4) and default.beta0 == 0.5


def test_early_stopping_ends_on_a_plateau(data: dict[str, Any]) -> None:
    # Demos already on their references and smooth: nothing to gain, the loss is flat.
    flat = dict(data, positions=data["references"].copy())
    result = run(flat, config=RefineConfig(hidden=8, epochs=100, patience=3, min_epochs=5))
    assert result.epochs < 100


def test_a_single_demo_is_passed_through(data: dict[str, Any]) -> None:
    one = {k: data[k][:1] for k in ("positions", "references", "thetas_deg")}
    result = refine_demos(
        **one,
        best_index=0,
        reward_fn=lambda p: np.full(len(p), 0.5),
        normaliser=data["normaliser"],
    )
    np.testing.assert_array_equal(result.refined, data["positions"][:1])
    assert result.epochs == 0 and result.betas.tolist() == [0.5]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"variant": "fast"}, "variant"),
        ({"lr": 0.0}, "lr"),
        ({"epochs": 0}, "epochs"),
        ({"hidden": 2.5}, "hidden"),
        ({"beta0": 1.5}, "beta0"),
        ({"beta_rate": 0.0}, "beta_rate"),
        ({"gamma": -1.0}, "gamma"),
        ({"weights": (0.5, 0.5, 0.5, 0.5)}, "weights"),
        ({"mi_term": "max"}, "mi_term"),
        ({"patience": -1}, "patience"),
        ({"lr": "fast"}, "lr"),
        ({"seed": -1}, "seed"),
        ({"mi_every": 0}, "mi_every"),
    ],
)
def test_config_validation(kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        RefineConfig(**kwargs)


@pytest.mark.parametrize(
    ("change", "error", "match"),
    [
        (lambda d: d.update(references=d["references"][:, :-1]), DemoError, "references"),
        (lambda d: d.update(thetas_deg=d["thetas_deg"][:3]), DemoError, "thetas_deg"),
        (lambda d: d["positions"].__setitem__((1, 5, 0), np.nan), DemoError, "positions"),
        (lambda d: d.update(best_index=4), ConfigError, "best_index"),
        (lambda d: d.update(reward_fn=lambda p: np.zeros(2)), DemoError, "reward_fn"),
    ],
)
def test_bad_inputs_are_named(
    data: dict[str, Any], change: Callable[[dict[str, Any]], None], error: type, match: str
) -> None:
    bad = dict(data, positions=data["positions"].copy())
    change(bad)
    with pytest.raises(error, match=match):
        run(bad, config=RefineConfig(hidden=8, epochs=1))


def test_refine_normaliser_adds_the_shape_column() -> None:
    base = Normaliser.from_values(np.array([[1.0, 2.0, 3.0, 4.0], [2.0, 3.0, 5.0, 8.0]]))
    extended = refine_normaliser(base, [0.01, 0.03])
    assert extended.names[-1] == "shape" and extended.names[:-1] == base.names
    assert extended.affine("shape") == pytest.approx((0.01, 50.0))
    with pytest.raises(DemoError, match="shape_losses"):
        refine_normaliser(base, [np.nan, 1.0])
    with pytest.raises(ConfigError, match="shape column"):
        refine_normaliser(extended, [0.01, 0.03])


def test_adam_matches_torch_optim_with_cosine_annealing() -> None:
    torch.manual_seed(0)
    target = torch.randn(5, 3)
    mine = [torch.zeros(5, 3, requires_grad=True), torch.ones(3, requires_grad=True)]
    theirs = [p.detach().clone().requires_grad_(True) for p in mine]
    adam = Adam([(mine[:1], 0.1), (mine[1:], 0.5)])
    reference = torch.optim.Adam([{"params": theirs[:1]}, {"params": theirs[1:], "lr": 0.5}], 0.1)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(reference, 8)
    for epoch in range(1, 9):
        for params in (mine, theirs):
            for p in params:
                p.grad = None
            ((params[0] * params[1] - target) ** 2).sum().backward()
        adam.step(0.5 * (1.0 + np.cos(np.pi * (epoch - 1) / 8)))
        reference.step()
        schedule.step()
    for a, b in zip(mine, theirs, strict=True):
        torch.testing.assert_close(a, b)
