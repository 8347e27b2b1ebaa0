"""Trajectory BC: a policy that predicts the next H positions of the trajectory (a chunk).

The paper's Traj-BC (its ref. [21]) cannot be recovered (docs/algorithms.md §5). bt reads
"trajectory-level behaviour cloning" as a policy whose output is a piece of trajectory rather than
one action: from the state (x_k, φ_k) the MLP predicts x_{k+1..k+H}, and the rollout executes the
first `execute` positions before predicting again (receding horizon; action chunking as in ACT,
Zhao et al., RSS 2023). Conditioning on the phase makes it a function of where along the
trajectory the robot is, not only of where it stands. docs/evaluation.md gives the reasons.

Details:

* **Output.** H mean velocities: position j of the chunk is x_k + j Δt (s_v ⊙ o_j + μ_v), so each
  output is O(1) in BC's standardised units whatever j, and H = 1 is BC.
* **Loss.** Mean squared error of the standardised mean velocities over the H positions of random
  windows (never crossing a demo's end).
* **Corrective chunks.** A perturbed start x̃_k = x_k + δ (the shared DART-style data) is labelled
  with the chunk x_{k+j} + δ e^{-K j Δt}, which returns to the demo at the same rate K as the
  other learners' corrective actions.
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
from bt_pipeline.exceptions import ConfigError


@dataclass(frozen=True)
class TrajBCConfig(TrainConfig):
    """Trajectory-BC settings (full preset by default; :meth:`quick` for CI)."""

    steps: int = 1500
    """Optimiser steps."""
    lr: float = 3e-3
    """Initial Adam learning rate."""
    batch_size: int = 512
    """Windows per step; 0 = every window start."""
    horizon: int = 10
    """H, positions per predicted chunk."""
    execute: int = 2
    """Positions of each chunk the rollout executes before predicting again (≤ H)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.horizon < 1:
            raise ConfigError(f"horizon must be >= 1; got {self.horizon}")
        if not 1 <= self.execute <= self.horizon:
            raise ConfigError(f"execute must be in [1, horizon={self.horizon}]; got {self.execute}")

    @classmethod
    def quick(cls, **overrides: Any) -> TrajBCConfig:
        """The CI-sized preset."""
        return replace(cls(steps=400, lr=5e-3, batch_size=256), **overrides)


def train_traj_bc(
    demos: ArrayLike, config: TrajBCConfig | None = None, preferences: ArrayLike | None = None
) -> TrainedLearner:
    """Train a Traj-BC policy on demos (M, N, 2) [m], uniform on t ∈ [0, 1].

    Args:
        demos: Task-coordinate positions, shape (M, N, 2), in [m]; never modified.
        config: Settings; default :class:`TrajBCConfig` ().
        preferences: Each demo's demonstrator preference (θ [deg], ρ), shape (M, 2): an input
            of the policy (a conditioned learner); None: unconditioned.

    Returns:
        The trained learner (chunk policy, loss history, wall time).

    Raises:
        DemoError: Wrong shape, not finite, or N <= `config.horizon` + 1.
    """
    config = config or TrajBCConfig()
    data = prepare_demos(demos, config, config.horizon + 2, preferences)
    h = config.horizon
    windows = data.rows_with(h)
    offsets = torch.arange(1, h + 1)
    times = offsets.to(torch.float32) * data.dt  # (H,)
    ratio = data.velocity_ratio
    with torch_session(config.seed, config.threads) as generator:
        net = make_mlp(data.n_features, 2 * h, config.hidden, config.depth)

        def loss_fn(_: int) -> torch.Tensor:
            rows = sample_rows(generator, windows, config.batch_size)
            z, delta_z, _labels = data.perturbed(rows, generator)
            decay = torch.exp(-data.gain * times)[None, :, None]  # (1, H, 1)
            targets = data.z[rows[:, None] + offsets] + delta_z[:, None] * decay  # (B, H, 2)
            # standardised mean velocity over j steps, as the net predicts it
            mean_v = (targets - z[:, None]) / times[None, :, None]
            labels = (mean_v - data.velocity_offset) / ratio
            out = net(data.features(z, data.phase[rows], data.cond[rows])).reshape(-1, h, 2)
            return torch.mean((out - labels) ** 2)

        result = fit([{"params": list(net.parameters())}], loss_fn, config)
    return TrainedLearner(
        name="traj_bc",
        policy=make_policy(net, data, config, kind="chunk", horizon=h, execute=config.execute),
        config=config,
        loss_history=result.loss_history,
        seconds=result.seconds,
        skipped_steps=result.skipped_steps,
    )
