"""Neural ODE: a vector field ẋ = f(x, φ) trained through an ODE solver on demo segments.

Chen et al., NeurIPS 2018; library torchdiffeq (docs/algorithms.md §5). The field is the same
tanh MLP as BC's policy (standardised state features → standardised velocity), so
dz/dt = (s_v / s_x) ⊙ net(z, cos φ, sin φ) + μ_v / s_x, integrated jointly with the canonical
oscillator dφ/dt = ω; with ``state="position"`` it is the autonomous field of the paper.
A segment may start from a perturbed state x_k + δ (the shared DART-style data); its targets are
then x_{k+j} + δ e^{-K t_j}, so the field learns to return to the demo.

Training integrates the field with ``torchdiffeq.odeint`` and matches the demos' states:

* **Segments, not the full horizon.** Integrating from x_1 over all N samples (the authors'
  baseline) stalls on long periodic horizons: early errors in phase make the loss flat in the
  field's parameters. As the lab's diffrax variant does, each step integrates a batch of random
  sub-segments x_k → x_{k+L} of the demos (never crossing a demo's end) from their true start
  states, all in one ``odeint`` call (autonomous, so every segment shares the time grid).
* **Curriculum over the segment length.** L grows linearly from `min_segment` to `max_segment`
  (fractions of the demo's N - 1 intervals; default 0.02 → 0.2) over the first
  `curriculum_fraction` of the steps, then stays at `max_segment`.
* **Fixed-step solver on the sample grid.** ``method="rk4"`` (torchdiffeq's 3/8 rule) with a step
  of `stride` sample intervals, compared with the demo at every solver step; adaptive ``dopri5``
  (the baseline) costs several times more for no gain on these smooth fields. Rollouts use the
  same RK4 with the demo's Δt = 1 / (N - 1), clipped to the box like every learner's.
* **Loss.** Mean squared error of the standardised positions over every solver step of every
  segment (the start state, exact by construction, excluded).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, Literal

import torch
from numpy.typing import ArrayLike
from torch import nn
from torchdiffeq import odeint

from bt_pipeline.evaluate.learners.common import (
    DemoData,
    TrainConfig,
    TrainedLearner,
    make_mlp,
    prepare_demos,
)
from bt_pipeline.evaluate.learners.policy import make_policy
from bt_pipeline.evaluate.learners.training import fit, sample_rows, torch_session
from bt_pipeline.exceptions import ConfigError

_ONE_THIRD = 1 / 3  # torchdiffeq's constants (rk_common.py), for bit-identical steps

Solver = Literal["rk4", "midpoint", "euler"]
"""torchdiffeq fixed-grid methods a NODE may be trained with."""


@dataclass(frozen=True)
class NODEConfig(TrainConfig):
    """Neural-ODE settings (full preset by default; :meth:`quick` for CI)."""

    steps: int = 300
    """Optimiser steps."""
    lr: float = 5e-3
    """Initial Adam learning rate."""
    batch_size: int = 64
    """Segments per step; 0 = every segment start."""
    min_segment: float = 0.02
    """Segment length at the start of the curriculum, fraction of the demo's N - 1 intervals."""
    max_segment: float = 0.2
    """Segment length at the end of the curriculum, fraction of the demo's N - 1 intervals."""
    curriculum_fraction: float = 0.5
    """Fraction of the steps over which the segment length grows."""
    stride: int = 4
    """Solver step in sample intervals (the step is `stride` × Δt)."""
    solver: Solver = "rk4"
    """torchdiffeq fixed-grid method used in training."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0.0 < self.min_segment <= self.max_segment <= 1.0:
            raise ConfigError(
                "need 0 < min_segment <= max_segment <= 1; got "
                f"min_segment={self.min_segment}, max_segment={self.max_segment}"
            )
        if not 0.0 <= self.curriculum_fraction <= 1.0:
            raise ConfigError(
                f"curriculum_fraction must be in [0, 1]; got {self.curriculum_fraction}"
            )
        if self.stride < 1:
            raise ConfigError(f"stride must be >= 1; got {self.stride}")
        if self.solver not in ("rk4", "midpoint", "euler"):
            raise ConfigError(f"solver must be one of rk4, midpoint, euler; got {self.solver!r}")

    @classmethod
    def quick(cls, **overrides: Any) -> NODEConfig:
        """The CI-sized preset."""
        return replace(cls(steps=160, lr=1e-2, max_segment=0.1), **overrides)

    def segment_steps(self, step: int, n_intervals: int) -> int:
        """Solver steps per segment at optimiser step `step` (the curriculum), >= 1."""
        longest = max(1, n_intervals // self.stride)
        low = min(longest, max(1, round(self.min_segment * n_intervals / self.stride)))
        high = min(longest, max(low, round(self.max_segment * n_intervals / self.stride)))
        warmup = self.curriculum_fraction * self.steps
        progress = 1.0 if warmup <= 0.0 else min(1.0, step / warmup)
        return round(low + (high - low) * progress)


class _Field(nn.Module):
    """d(z, φ)/dt = (ratio ⊙ net(features(z, φ)) + offset, ω) on y = (z, φ), shape (B, 3)."""

    def __init__(self, net: nn.Module, data: DemoData) -> None:
        super().__init__()
        self.net = net
        self.data = data
        self.register_buffer("ratio", data.velocity_ratio)
        self.register_buffer("offset", data.velocity_offset)
        self.cond: torch.Tensor | None = None  # The batch's standardised conditions (B, C).

    def forward(self, t: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        del t  # time enters through φ
        return self.rate(y)

    def rate(self, y: torch.Tensor) -> torch.Tensor:
        """d(z, φ)/dt at y (B, 3).

        The phase enters the net detached: dφ/dt = ω is constant, so no parameter's gradient
        passes through φ, and autograd need not carry the cos/sin branch back (the parameter
        gradients are bit for bit the same; tests/pipeline/evaluate/learners/test_learners.py).
        """
        features = self.data.features(y[:, :2], y[:, 2].detach(), self.cond)
        rate = self.net(features) * self.ratio + self.offset
        return torch.cat([rate, torch.full_like(y[:, 2:], self.data.omega)], dim=1)


def rk4_grid(
    rate: Callable[[torch.Tensor], torch.Tensor], y0: torch.Tensor, times: torch.Tensor
) -> torch.Tensor:
    """The states (T, B, D) of the autonomous ODE dy/dt = rate(y) at `times` (T,) from y0 (B, D):
    one RK4 step (3/8 rule) per interval of the grid.

    The same tensor operations, in the same order, as ``torchdiffeq.odeint(..., method="rk4")``
    on a grid without interpolation (``rk4_alt_step_func``), so the states and their gradients
    are bit for bit torchdiffeq's (tests/pipeline/evaluate/learners/test_learners.py checks it),
    without its per-call input checks, solver object and per-evaluation wrappers: a training
    calls it once per step, with up to 16 solver steps.
    """
    solution = torch.empty(len(times), *y0.shape, dtype=y0.dtype, device=y0.device)
    solution[0] = y0
    y = y0
    for j, dt in enumerate(times[1:] - times[:-1], start=1):
        k1 = rate(y)
        k2 = rate(y + dt * k1 * _ONE_THIRD)
        k3 = rate(y + dt * (k2 - k1 * _ONE_THIRD))
        k4 = rate(y + dt * (k1 - k2 + k3))
        y = y + (k1 + 3 * (k2 + k3) + k4) * dt * 0.125
        solution[j] = y
    return solution


def train_node(
    demos: ArrayLike, config: NODEConfig | None = None, preferences: ArrayLike | None = None
) -> TrainedLearner:
    """Train a Neural ODE on demos (M, N, 2) [m], uniform on t ∈ [0, 1].

    Args:
        demos: Task-coordinate positions, shape (M, N, 2), in [m]; never modified.
        config: Settings; default :class:`NODEConfig` ().
        preferences: Each demo's demonstrator preference (θ [deg], ρ), shape (M, 2): an input
            of the policy (a conditioned learner); None: unconditioned.

    Returns:
        The trained learner (RK4 policy, loss history, wall time).

    Raises:
        DemoError: The demos have the wrong shape, too few samples, or are not finite.
    """
    config = config or NODEConfig()
    data = prepare_demos(demos, config, config.stride + 2, preferences)
    n_intervals = int(data.remaining.max())  # the longest training sequence
    with torch_session(config.seed, config.threads) as generator:
        net = make_mlp(data.n_features, 2, config.hidden, config.depth)
        field = _Field(net, data)

        def loss_fn(step: int) -> torch.Tensor:
            n_steps = config.segment_steps(step, n_intervals)
            span = n_steps * config.stride  # samples covered by a segment
            starts = data.rows_with(span)
            while starts.numel() == 0:  # a demo shorter than the segment: shorten it
                n_steps = max(1, n_steps // 2)
                span = n_steps * config.stride
                starts = data.rows_with(span)
            rows = sample_rows(generator, starts, config.batch_size)
            z0, delta_z, _ = data.perturbed(rows, generator)
            offsets = torch.arange(1, n_steps + 1) * config.stride
            times = torch.arange(n_steps + 1, dtype=torch.float32) * (config.stride * data.dt)
            decay = torch.exp(-data.gain * times[1:])[None, :, None]
            targets = data.z[rows[:, None] + offsets] + delta_z[:, None] * decay  # (B, L, 2)
            y0 = torch.cat([z0, data.phase[rows, None]], dim=1)
            field.cond = data.cond[rows]
            if config.solver == "rk4":
                states = rk4_grid(field.rate, y0, times)
            else:
                states = odeint(field, y0, times, method=config.solver)
                assert isinstance(states, torch.Tensor)  # a tensor y0 gives a tensor
            return torch.mean((states[1:, :, :2].transpose(0, 1) - targets) ** 2)

        result = fit([{"params": list(net.parameters())}], loss_fn, config)
    return TrainedLearner(
        name="node",
        policy=make_policy(net, data, config, integrator="rk4"),
        config=config,
        loss_history=result.loss_history,
        seconds=result.seconds,
        skipped_steps=result.skipped_steps,
    )
