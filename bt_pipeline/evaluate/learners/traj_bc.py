"""Trajectory BC: the BC policy trained with a multi-step loss, unrolled over windows of the demos.

The paper's Traj-BC (its ref. [21]) cannot be recovered; docs/algorithms.md §5 resolves it as choice
(b): **BC with a trajectory-level loss**. The same MLP policy as
:mod:`bt_pipeline.evaluate.learners.bc` is unrolled with Euler for H = 20 steps of Δt = 1 / (N - 1)
from random window starts x_k of the demos, and the unrolled states x̂_{k+1..k+H} are matched to the
demo's x_{k+1..k+H}. So the policy is trained on the states its own rollout reaches, and compounding
errors within a window are penalised, which one-step BC never sees. It sits between one-step BC and
the full-horizon Neural ODE.

Details:

* **Loss.** The squared error of step j is weighted by 1 / (j Δt)²: each term is then the error of
  the mean velocity over the first j steps, in BC's standardised velocity units, so the loss is
  O(1) whatever H, and H = 1 is exactly BC's loss.
  ``L = mean_{windows, j} ‖(ẑ_{k+j} - z_{k+j}) / (j Δt) / (s_v / s_x)‖²``.
* **Windows** never cross a demo's end (k ∈ [0, N - 1 - H]); a step draws `batch_size` windows
  with replacement.
* **Horizon curriculum.** H grows linearly from 1 to `horizon` over the first `warmup_fraction` of
  the steps (short unrolls are cheap and start the field near BC's), then stays at `horizon`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import torch
from numpy.typing import ArrayLike

from bt_pipeline.evaluate.learners.common import (
    TrainConfig,
    TrainedLearner,
    make_mlp,
    make_policy,
    prepare_demos,
)
from bt_pipeline.evaluate.learners.training import fit, torch_session
from bt_pipeline.exceptions import ConfigError


@dataclass(frozen=True)
class TrajBCConfig(TrainConfig):
    """Trajectory-BC settings (full preset by default; :meth:`quick` for CI)."""

    steps: int = 500
    """Optimiser steps."""
    lr: float = 3e-3
    """Initial Adam learning rate."""
    batch_size: int = 64
    """Windows per step; 0 = every window start."""
    horizon: int = 20
    """H, Euler steps per window (docs/algorithms.md §5)."""
    warmup_fraction: float = 0.5
    """Fraction of the steps over which H grows from 1 to `horizon`."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.horizon < 1:
            raise ConfigError(f"horizon must be >= 1; got {self.horizon}")
        if not 0.0 <= self.warmup_fraction <= 1.0:
            raise ConfigError(f"warmup_fraction must be in [0, 1]; got {self.warmup_fraction}")

    @classmethod
    def quick(cls, **overrides: Any) -> TrajBCConfig:
        """The CI-sized preset."""
        return replace(cls(steps=100, lr=5e-3), **overrides)

    def horizon_at(self, step: int) -> int:
        """H of optimiser step `step` (the curriculum)."""
        warmup = self.warmup_fraction * self.steps
        if warmup <= 0.0:
            return self.horizon
        return max(1, min(self.horizon, math.ceil(self.horizon * (step + 1) / warmup)))


def train_traj_bc(demos: ArrayLike, config: TrajBCConfig | None = None) -> TrainedLearner:
    """Train a Traj-BC policy on demos (M, N, 2) [m], uniform on t ∈ [0, 1].

    Args:
        demos: Task-coordinate positions, shape (M, N, 2), in [m]; never modified.
        config: Settings; default :class:`TrajBCConfig` ().

    Returns:
        The trained learner (Euler policy, loss history, wall time).

    Raises:
        DemoError: Wrong shape, not finite, or N <= `config.horizon` + 1.
    """
    config = config or TrajBCConfig()
    data = prepare_demos(demos, config.box_padding, min_samples=config.horizon + 2)
    n_starts = data.n_samples - 1 - config.horizon  # k + H <= N - 1
    n_windows = data.n_demos * (n_starts + 1)
    ratio, offset, dt = data.velocity_ratio, data.velocity_offset, data.dt
    with torch_session(config.seed, config.threads) as generator:
        net = make_mlp(2, 2, config.hidden, config.depth)

        def loss_fn(step: int) -> torch.Tensor:
            h = config.horizon_at(step)
            if config.batch_size == 0:
                window = torch.arange(n_windows)
            else:
                window = torch.randint(n_windows, (config.batch_size,), generator=generator)
            demo, start = window // (n_starts + 1), window % (n_starts + 1)
            offsets = torch.arange(1, h + 1)
            targets = data.z[demo[:, None], start[:, None] + offsets]  # (B, h, 2)
            z = data.z[demo, start]
            predicted = []
            for _ in range(h):  # Euler, as at test time
                z = z + dt * (net(z) * ratio + offset)
                predicted.append(z)
            error = (torch.stack(predicted, dim=1) - targets) / ratio
            weights = (1.0 / (offsets * dt)) ** 2  # mean-velocity error of j steps
            return torch.mean(error.pow(2).sum(-1) * weights) / 2.0

        result = fit([{"params": list(net.parameters())}], loss_fn, config)
    return TrainedLearner(
        name="traj_bc",
        policy=make_policy(net, data, config),
        config=config,
        loss_history=result.loss_history,
        seconds=result.seconds,
        skipped_steps=result.skipped_steps,
    )
