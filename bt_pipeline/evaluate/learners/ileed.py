"""ILEED for continuous actions: imitation with a learned expertise per demonstrator.

Beliaev, Shih, Ermon, Sadigh, Pedarsani, "Imitation Learning by Estimating Expertise of
Demonstrators", ICML 2022 (docs/algorithms.md §4). Demonstrator i acts optimally in state s with
probability σ_i(s) = sigmoid(⟨f_θ(s), ω_i⟩), and otherwise at random::

    p_i(a | s) = σ_i(s) · N(a; μ_φ(s), diag σ_a²) + (1 - σ_i(s)) · p_rand(a)

* μ_φ: the shared policy, the same tanh MLP as BC (standardised position → standardised velocity).
* σ_a: a learned per-axis action standard deviation (clamped to [`min_action_std`,
  `max_action_std`]), or fixed when `learn_action_std` is False.
* f_θ: a state embedding in R^e (tanh MLP, e = `embed_dim`), ω_i ∈ R^e: one expertise embedding
  per **demonstrator** (docs/algorithms.md §7 row 21: D2's 20 demos share 4 embeddings), drawn
  from N(0, 1) as in the official code, with its own learning rate (official: 1e-2).
* p_rand, the random-action density (`random_model`):
  - ``"gaussian"`` (default): N(μ_v, Σ_v) of all observed velocities, i.e. N(0, I) in
    standardised units: a demonstrator who errs draws a velocity of typical size at random (the
    continuous analogue of the official "any other action");
  - ``"uniform"``: the uniform density on the box of all observed velocities (docs/algorithms.md
    §4's first suggestion). Measured on synthetic D1 sets (3 tasks × 3 seeds): a spike or jitter
    outlier makes that box so wide that its density rarely beats a broad σ_a, so every
    demonstrator's σ_i ends near 1 (expert minus best naive: 0.00-0.14, ties at 1.0); with the
    Gaussian the expert leads by 0.82-0.97 and the rollouts are as close to the truth
    (mean Chamfer 0.070 vs 0.078 of the shape's size).

The state features and the corrective (DART-style) pairs are every learner's
(:mod:`bt_pipeline.evaluate.learners.common`); a corrective pair keeps its demo's demonstrator.
Training maximises the mean mixture log-likelihood over all (state, action) pairs of every demo
(computed stably with logaddexp) jointly over φ, σ_a, θ and {ω_i}, with the shared loop of
:func:`bt_pipeline.evaluate.learners.common.fit`. At test time only μ_φ is used, rolled out by Euler
like BC. The learned expertise of demonstrator i is reported as the mean of σ_i(s) over its own
states.

Departures from the official code (discrete actions only, MiniGrid): a normalised Gaussian instead
of a softmax policy, a continuous random-action density instead of "uniform over the other
actions", tanh MLPs of BC's size instead of tiny ReLU nets, one run instead of 20 restarts.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np
import torch
from numpy.typing import ArrayLike
from torch import nn
from torch.nn import functional

from bt_pipeline.evaluate.learners.common import (
    TrainConfig,
    TrainedLearner,
    make_mlp,
    prepare_demos,
)
from bt_pipeline.evaluate.learners.policy import make_policy
from bt_pipeline.evaluate.learners.training import fit, sample_rows, torch_session
from bt_pipeline.exceptions import ConfigError

RandomModel = Literal["uniform", "gaussian"]
"""The density of a demonstrator's random (non-optimal) actions."""


@dataclass(frozen=True)
class ILEEDConfig(TrainConfig):
    """ILEED settings (full preset by default; :meth:`quick` for CI)."""

    steps: int = 1200
    """Optimiser steps."""
    lr: float = 3e-3
    """Initial Adam learning rate of the policy, σ_a and the state embedding."""
    batch_size: int = 512
    """(state, action) pairs per step; 0 = all."""
    embed_dim: int = 4
    """e, dimension of the state and expertise embeddings."""
    embed_depth: int = 2
    """Hidden layers of the state-embedding MLP."""
    embed_hidden: int = 32
    """Width of the state-embedding MLP's hidden layers."""
    embedding_lr: float = 1e-2
    """Initial Adam learning rate of the expertise embeddings ω_i."""
    learn_action_std: bool = True
    """Learn σ_a (per axis); otherwise keep it at `action_std`."""
    action_std: float = 0.5
    """Initial (or fixed) σ_a, in standardised velocity units."""
    min_action_std: float = 0.02
    """Floor of a learned σ_a, in standardised velocity units."""
    max_action_std: float = 10.0
    """Cap of a learned σ_a, in standardised velocity units."""
    random_model: RandomModel = "gaussian"
    """The random-action density: uniform on the observed velocity box, or N(μ_v, diag s_v²) of
    all observed velocities (N(0, I) in standardised units)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("embed_dim", "embed_depth", "embed_hidden"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} must be >= 1; got {getattr(self, name)}")
        if not self.embedding_lr > 0.0:
            raise ConfigError(f"embedding_lr must be > 0; got {self.embedding_lr}")
        if not 0.0 < self.min_action_std <= self.action_std <= self.max_action_std:
            raise ConfigError(
                "need 0 < min_action_std <= action_std <= max_action_std; got "
                f"{self.min_action_std}, {self.action_std}, {self.max_action_std}"
            )
        if self.random_model not in ("uniform", "gaussian"):
            raise ConfigError(
                f"random_model must be 'uniform' or 'gaussian'; got {self.random_model!r}"
            )

    @classmethod
    def quick(cls, **overrides: Any) -> ILEEDConfig:
        """The CI-sized preset."""
        return replace(cls(steps=200, lr=5e-3, embedding_lr=2e-2, batch_size=256), **overrides)


class _ILEEDModel(nn.Module):
    """Policy mean μ_φ, action std σ_a, state embedding f_θ and expertise embeddings ω."""

    def __init__(self, n_demonstrators: int, n_features: int, config: ILEEDConfig) -> None:
        super().__init__()
        self.policy = make_mlp(n_features, 2, config.hidden, config.depth)
        self.embedding = make_mlp(
            n_features, config.embed_dim, config.embed_hidden, config.embed_depth
        )
        self.omega = nn.Parameter(torch.randn(n_demonstrators, config.embed_dim))
        self.log_std = nn.Parameter(
            torch.full((2,), math.log(config.action_std)), requires_grad=config.learn_action_std
        )
        self.min_log_std = math.log(config.min_action_std)
        self.max_log_std = math.log(config.max_action_std)

    def competence_logit(self, states: torch.Tensor, who: torch.Tensor) -> torch.Tensor:
        """⟨f_θ(s), ω_i⟩, shape (B,), for state features (B, F) of demonstrators `who` (B,)."""
        return torch.sum(self.embedding(states) * self.omega[who], dim=-1)

    def log_likelihood(
        self,
        states: torch.Tensor,
        actions: torch.Tensor,
        who: torch.Tensor,
        log_random: torch.Tensor,
    ) -> torch.Tensor:
        """log p_i(a | s) of the mixture, shape (B,), given log p_rand(a) (B,)."""
        log_std = self.log_std.clamp(min=self.min_log_std, max=self.max_log_std)
        residual = (actions - self.policy(states)) / log_std.exp()
        log_gauss = -0.5 * residual.pow(2).sum(-1) - log_std.sum() - math.log(2.0 * math.pi)
        logit = self.competence_logit(states, who)
        return torch.logaddexp(
            functional.logsigmoid(logit) + log_gauss, functional.logsigmoid(-logit) + log_random
        )


def demonstrator_ids(
    demonstrators: Sequence[str] | None, n_demos: int
) -> tuple[list[str], np.ndarray]:
    """Distinct demonstrator names (in order of first appearance) and each demo's index into them.

    None gives every demo its own demonstrator, named by its index.

    Raises:
        ConfigError: `demonstrators` does not have one name per demo.
    """
    names = [str(k) for k in range(n_demos)] if demonstrators is None else list(demonstrators)
    if len(names) != n_demos:
        raise ConfigError(f"need one demonstrator name per demo ({n_demos}); got {len(names)}")
    distinct = list(dict.fromkeys(names))
    return distinct, np.array([distinct.index(n) for n in names], dtype=np.int64)


def _log_random_density(actions: torch.Tensor, model: RandomModel) -> torch.Tensor:
    """log p_rand of every standardised action (B, 2), shape (B,)."""
    if model == "gaussian":  # N(0, I) in standardised units
        return -0.5 * actions.pow(2).sum(-1) - math.log(2.0 * math.pi)
    extent = (actions.max(dim=0).values - actions.min(dim=0).values).clamp(min=1e-6)
    return torch.full((actions.shape[0],), -float(torch.log(extent).sum()))  # 1 / box area


def train_ileed(
    demos: ArrayLike,
    demonstrators: Sequence[str] | None = None,
    config: ILEEDConfig | None = None,
    preferences: ArrayLike | None = None,
) -> TrainedLearner:
    """Train ILEED on demos (M, N, 2) [m] (uniform on t ∈ [0, 1]) with their demonstrators.

    Args:
        demos: Task-coordinate positions, shape (M, N, 2), in [m]; never modified.
        demonstrators: Who recorded each demo (M names; equal names share one ω). None: every
            demo is its own demonstrator, named "0", "1", ...
        config: Settings; default :class:`ILEEDConfig` ().
        preferences: Each demo's demonstrator preference (θ [deg], ρ), shape (M, 2): an input
            of the policy (a conditioned learner); None: unconditioned.

    Returns:
        The trained learner: the policy mean rolled out by Euler, and `expertise` (mean σ_i(s)
        over each demonstrator's own states, by demonstrator name).

    Raises:
        DemoError: The demos have the wrong shape, too few samples, or are not finite.
        ConfigError: `demonstrators` does not have one name per demo.
    """
    config = config or ILEEDConfig()
    data = prepare_demos(demos, config, preferences=preferences)
    names, demo_who = demonstrator_ids(demonstrators, len(np.asarray(demos)))
    # every row's demonstrator: rows are the demos' samples in order, each demo ending with
    # remaining == 0
    ends = torch.nonzero(data.remaining == 0).squeeze(1)
    lengths = torch.diff(torch.cat([torch.tensor([-1]), ends])).numpy()
    who = torch.as_tensor(np.repeat(demo_who, lengths))
    pairs = data.rows_with(1)
    with torch_session(config.seed, config.threads) as generator:
        model = _ILEEDModel(len(names), data.n_features, config)

        def loss_fn(_: int) -> torch.Tensor:
            rows = sample_rows(generator, pairs, config.batch_size)
            z, _delta, labels = data.perturbed(rows, generator)
            features = data.features(z, data.phase[rows], data.cond[rows])
            log_random = _log_random_density(labels, config.random_model)
            return -model.log_likelihood(features, labels, who[rows], log_random).mean()

        networks = [*model.policy.parameters(), *model.embedding.parameters()]
        groups = [{"params": networks}, {"params": [model.omega], "lr": config.embedding_lr}]
        if config.learn_action_std:
            groups[0]["params"] = [*networks, model.log_std]
        result = fit(groups, loss_fn, config)
        with torch.no_grad():
            features = data.features(data.z[pairs], data.phase[pairs], data.cond[pairs])
            competence = torch.sigmoid(model.competence_logit(features, who[pairs]))
        expertise = {
            name: float(competence[who[pairs] == i].mean()) for i, name in enumerate(names)
        }
    return TrainedLearner(
        name="ileed",
        policy=make_policy(model.policy, data, config),
        config=config,
        loss_history=result.loss_history,
        seconds=result.seconds,
        skipped_steps=result.skipped_steps,
        expertise=expertise,
    )
