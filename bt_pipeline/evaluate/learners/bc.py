"""Behaviour cloning: an MLP policy (x, φ) → ẋ regressed on the demos' (state, action) pairs.

As the authors' public baseline (docs/algorithms.md §5): tanh MLP of width 64 and depth 3 with
orthogonal initialisation, mean squared error between the predicted and the finite-difference
velocity, Adam with cosine annealing, rolled out by Euler integration with Δt = 1 / (N - 1).
bt adds the phase to the state and corrective (DART-style) pairs
(:mod:`bt_pipeline.evaluate.learners.common`); ``state="position", dart_fraction=0`` is the
baseline as written. The actions are the paper's forward differences a_k = (x_{k+1} - x_k) / Δt,
so an Euler rollout with the same Δt retraces a demo whose actions are matched exactly.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import torch
from numpy.typing import ArrayLike

from bt_pipeline.evaluate.learners.common import (
    TrainConfig,
    TrainedLearner,
    make_mlp,
    prepare_demos,
)
from bt_pipeline.evaluate.learners.policy import make_policy
from bt_pipeline.evaluate.learners.training import fit, sample_rows, torch_session


@dataclass(frozen=True)
class BCConfig(TrainConfig):
    """Behaviour-cloning settings (full preset by default; :meth:`quick` for CI)."""

    steps: int = 1500
    """Optimiser steps."""
    lr: float = 3e-3
    """Initial Adam learning rate."""
    batch_size: int = 512
    """(state, action) pairs per step; 0 = all."""

    @classmethod
    def quick(cls, **overrides: Any) -> BCConfig:
        """The CI-sized preset."""
        return replace(cls(steps=200, lr=5e-3, batch_size=256), **overrides)


def train_bc(
    demos: ArrayLike, config: BCConfig | None = None, preferences: ArrayLike | None = None
) -> TrainedLearner:
    """Train a BC policy on demos (M, N, 2) [m], uniform on t ∈ [0, 1].

    Args:
        demos: Task-coordinate positions, shape (M, N, 2), in [m]; never modified.
        config: Settings; default :class:`BCConfig` ().
        preferences: Each demo's demonstrator preference (θ [deg], ρ), shape (M, 2): an input
            of the policy (a conditioned learner); None: unconditioned.

    Returns:
        The trained learner (Euler policy, loss history, wall time).

    Raises:
        DemoError: The demos have the wrong shape, too few samples, or are not finite.
    """
    config = config or BCConfig()
    data = prepare_demos(demos, config, preferences=preferences)
    pairs = data.rows_with(1)  # x_k paired with a_k, k = 1..N-1
    with torch_session(config.seed, config.threads) as generator:
        net = make_mlp(data.n_features, 2, config.hidden, config.depth)

        def loss_fn(_: int) -> torch.Tensor:
            rows = sample_rows(generator, pairs, config.batch_size)
            z, _delta, labels = data.perturbed(rows, generator)
            return torch.mean(
                (net(data.features(z, data.phase[rows], data.cond[rows])) - labels) ** 2
            )

        result = fit([{"params": list(net.parameters())}], loss_fn, config)
    return TrainedLearner(
        name="bc",
        policy=make_policy(net, data, config),
        config=config,
        loss_history=result.loss_history,
        seconds=result.seconds,
        skipped_steps=result.skipped_steps,
    )
