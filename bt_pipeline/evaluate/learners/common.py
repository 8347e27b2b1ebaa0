"""What every imitation learner shares: data preparation, the vector-field policy, training.

Data flow, one learner::

    demos (M, N, 2) [m], uniform on t ∈ [0, 1]  ──► prepare_demos ──► DemoData:
        z = (x - μ_x) / s_x                      standardised positions, (M, N, 2)
        v = ((x_{k+1} - x_k) / Δt - μ_v) / s_v   standardised forward-difference velocities,
                                                 (M, N - 1, 2): the paper's a_k without a_N = 0
        box = [min x - p·extent, max x + p·extent]
    ──► learner-specific loss on an MLP net(z) ──► fit (Adam, cosine annealing, gradient clipping)
    ──► VectorFieldPolicy: ẋ = s_v ⊙ net((x - μ_x) / s_x) + μ_v, rolled out from x_0 by Euler
        (or RK4), every state clipped to the box.

Choices (docs/algorithms.md §5, §7 rows 1 and 20):

* **Actions.** Velocity targets are the paper's forward differences a_k = (x_{k+1} - x_k) / Δt
  with Δt = 1 / (N - 1). The artificial last action a_N = 0 is dropped rather than learned (it
  would teach the policy to stop at the loop's end point), and no periodic wrap-around difference
  is used (a demo's two ends need not meet). Forward differences are exactly the steps an Euler
  rollout with the same Δt takes, so a policy that matches them reproduces the demo.
* **Standardisation.** Positions and velocities are standardised per axis over all demos; the
  network sees and predicts O(1) numbers whatever the task's size and speed.
* **Bounded rollouts.** Every rolled-out state, the initial one included, is clipped to the box of
  the training positions padded by `box_padding` × the largest extent on every side. The MLP is
  finite on a bounded input, so rollouts are finite and bounded for any initial state.
"""

from __future__ import annotations

import contextlib
import itertools
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, fields
from typing import Literal, Protocol

import numpy as np
import torch
from numpy.typing import ArrayLike
from torch import nn
from torch.nn import functional

from bt_pipeline.data.records import MIN_SAMPLES, FloatArray
from bt_pipeline.exceptions import ConfigError, DemoError

LearnerName = Literal["bc", "traj_bc", "ileed", "node"]
"""An imitation learner of the paper's evaluation (Sec. IV)."""
Integrator = Literal["euler", "rk4"]
"""How a policy is rolled out: explicit Euler (BC, Traj-BC, ILEED) or RK4 (NODE, 3/8 rule)."""


@dataclass(frozen=True)
class TrainConfig:
    """Settings every learner shares (each learner's config adds its own)."""

    steps: int = 2000
    """Optimiser steps."""
    lr: float = 3e-3
    """Initial Adam learning rate, annealed to `lr` × `final_lr_ratio` by a cosine schedule."""
    final_lr_ratio: float = 0.01
    """Final learning rate as a fraction of `lr`."""
    hidden: int = 64
    """Width of every hidden layer of the MLPs."""
    depth: int = 3
    """Number of hidden layers of the MLPs (tanh)."""
    batch_size: int = 1024
    """Samples (or windows) per step; 0 means the full batch."""
    grad_clip: float = 1.0
    """Maximum global gradient norm."""
    seed: int = 0
    """Seed of the initial weights and of the mini-batch draws."""
    threads: int = 1
    """Torch threads while training and rolling out (1 is fastest for these small nets)."""
    box_padding: float = 0.25
    """Rollout box padding, as a fraction of the largest extent of the training positions."""

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type in ("int", int) and (isinstance(value, bool) or not isinstance(value, int)):
                raise ConfigError(f"{f.name} must be an integer; got {value!r}")
            if f.type in ("float", float) and not (
                isinstance(value, int | float) and math.isfinite(value)
            ):
                raise ConfigError(f"{f.name} must be a finite number; got {value!r}")
        _positive = {"steps": self.steps, "hidden": self.hidden, "depth": self.depth}
        _positive |= {"lr": self.lr, "grad_clip": self.grad_clip, "threads": self.threads}
        for name, value in _positive.items():
            if value <= 0:
                raise ConfigError(f"{name} must be > 0; got {value!r}")
        if self.batch_size < 0:
            raise ConfigError(f"batch_size must be >= 0 (0 = full batch); got {self.batch_size}")
        if not 0.0 <= self.final_lr_ratio <= 1.0:
            raise ConfigError(f"final_lr_ratio must be in [0, 1]; got {self.final_lr_ratio}")
        if self.seed < 0:
            raise ConfigError(f"seed must be >= 0; got {self.seed}")
        if self.box_padding < 0.0:
            raise ConfigError(f"box_padding must be >= 0; got {self.box_padding}")


@dataclass(frozen=True)
class Standardiser:
    """Per-axis affine map y = (x - mean) / scale."""

    mean: FloatArray
    """Per-axis mean, shape (2,)."""
    scale: FloatArray
    """Per-axis scale (standard deviation, floored), shape (2,), > 0."""

    @classmethod
    def fit(cls, values: FloatArray, what: str) -> Standardiser:
        """Mean and standard deviation of `values` (n, 2); an axis with ~zero spread gets the
        other axis' scale × 1e-3 so it stays invertible.

        Raises:
            DemoError: `values` do not vary at all.
        """
        mean, std = values.mean(axis=0), values.std(axis=0)
        if not float(std.max()) > 1e-12:
            raise DemoError(f"the demos' {what} do not vary; a learner needs a moving demo")
        return cls(mean=mean, scale=np.maximum(std, 1e-3 * float(std.max())))


class Policy(Protocol):
    """A learned policy ẋ = π(x) on task coordinates, rolled out by integration."""

    def velocity(self, positions: ArrayLike) -> FloatArray:
        """Velocities [m per unit normalised time], shape (B, 2), at positions (B, 2) [m]."""
        ...

    def rollout(self, x0: ArrayLike, n_samples: int, dt: float | None = None) -> FloatArray:
        """States (R, n_samples, 2) [m] from initial states (R, 2), n_samples - 1 steps of dt."""
        ...


class MLP(nn.Module):
    """Tanh MLP with orthogonal weights and zero biases; the output layer is scaled down (gain 0.1)
    so an untrained field is small.

    The forward pass calls ``F.linear`` on the layers' weights directly rather than the layer
    modules: on these tiny nets the per-module call overhead is a large part of a step.
    """

    def __init__(self, n_in: int, n_out: int, hidden: int, depth: int) -> None:
        super().__init__()
        widths = [n_in, *([hidden] * depth), n_out]
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in itertools.pairwise(widths))
        tanh_gain = nn.init.calculate_gain("tanh")
        for i, layer in enumerate(self.layers):
            assert isinstance(layer, nn.Linear)
            nn.init.orthogonal_(layer.weight, gain=0.1 if i == depth else tanh_gain)
            nn.init.zeros_(layer.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Outputs, shape (B, n_out), of inputs (B, n_in)."""
        *hidden, last = self.layers
        for layer in hidden:
            assert isinstance(layer, nn.Linear)
            x = torch.tanh(functional.linear(x, layer.weight, layer.bias))
        assert isinstance(last, nn.Linear)
        return functional.linear(x, last.weight, last.bias)


def make_mlp(n_in: int, n_out: int, hidden: int, depth: int) -> MLP:
    """A tanh :class:`MLP` with `depth` hidden layers of `hidden` units."""
    return MLP(n_in, n_out, hidden, depth)


@dataclass(frozen=True, eq=False)
class DemoData:
    """Demos prepared for training, as float32 tensors in standardised units."""

    z: torch.Tensor
    """Standardised positions, shape (M, N, 2)."""
    v: torch.Tensor
    """Standardised forward-difference velocities (a_N dropped), shape (M, N - 1, 2)."""
    positions: Standardiser
    """Position standardiser (units [m])."""
    velocities: Standardiser
    """Velocity standardiser (units [m per unit normalised time])."""
    box: FloatArray
    """Rollout box [m], shape (2, 2): row 0 the lower corner, row 1 the upper corner."""
    dt: float
    """Sample spacing Δt = 1 / (N - 1) of the normalised time axis."""

    @property
    def n_demos(self) -> int:
        """M."""
        return int(self.z.shape[0])

    @property
    def n_samples(self) -> int:
        """N."""
        return int(self.z.shape[1])

    @property
    def velocity_ratio(self) -> torch.Tensor:
        """s_v / s_x, shape (2,): converts a standardised velocity into dz/dt."""
        return torch.as_tensor(self.velocities.scale / self.positions.scale, dtype=torch.float32)

    @property
    def velocity_offset(self) -> torch.Tensor:
        """μ_v / s_x, shape (2,): the constant part of dz/dt."""
        return torch.as_tensor(self.velocities.mean / self.positions.scale, dtype=torch.float32)


def prepare_demos(demos: ArrayLike, box_padding: float, min_samples: int = MIN_SAMPLES) -> DemoData:
    """Validate demos (M, N, 2) [m] (uniform on t ∈ [0, 1]) and standardise them.

    Raises:
        DemoError: Wrong shape, fewer than `min_samples` samples, non-finite or motionless demos.
    """
    x = np.array(demos, dtype=np.float64)  # a copy: the caller's array is never touched
    if x.ndim != 3 or x.shape[0] < 1 or x.shape[2] != 2:
        raise DemoError(f"demos must have shape (M, N, 2) with M >= 1; got {x.shape}")
    if x.shape[1] < min_samples:
        raise DemoError(f"demos have {x.shape[1]} samples; at least {min_samples} are needed")
    if not np.all(np.isfinite(x)):
        raise DemoError("demos contain NaN or infinite positions")
    dt = 1.0 / (x.shape[1] - 1)
    velocities = np.diff(x, axis=1) / dt  # the paper's a_k, k = 1..N-1 (a_N = 0 dropped)
    pos_std = Standardiser.fit(x.reshape(-1, 2), "positions")
    vel_std = Standardiser.fit(velocities.reshape(-1, 2), "velocities")
    flat = x.reshape(-1, 2)
    lo, hi = flat.min(axis=0), flat.max(axis=0)
    pad = box_padding * float((hi - lo).max())
    return DemoData(
        z=torch.as_tensor((x - pos_std.mean) / pos_std.scale, dtype=torch.float32),
        v=torch.as_tensor((velocities - vel_std.mean) / vel_std.scale, dtype=torch.float32),
        positions=pos_std,
        velocities=vel_std,
        box=np.stack([lo - pad, hi + pad]),
        dt=dt,
    )


@dataclass(frozen=True, eq=False)
class VectorFieldPolicy:
    """ẋ = s_v ⊙ net((x - μ_x) / s_x) + μ_v on task coordinates [m], rolled out with clipping."""

    net: nn.Module
    """MLP from standardised position (B, 2) to standardised velocity (B, 2)."""
    positions: Standardiser
    """Position standardiser."""
    velocities: Standardiser
    """Velocity standardiser."""
    box: FloatArray
    """Rollout box [m], shape (2, 2) (lower corner, upper corner)."""
    dt: float
    """Default rollout step: the training demos' Δt = 1 / (N - 1)."""
    integrator: Integrator = "euler"
    """Rollout scheme."""
    threads: int = 1
    """Torch threads while rolling out."""

    def velocity(self, positions: ArrayLike) -> FloatArray:
        """π(x) [m per unit normalised time], shape (B, 2), at positions (B, 2) [m]."""
        x = _points(positions, "positions")
        with torch_threads(self.threads), torch.no_grad():
            z = torch.as_tensor(
                (x - self.positions.mean) / self.positions.scale, dtype=torch.float32
            )
            v = self.net(z).double().numpy()
        return v * self.velocities.scale + self.velocities.mean

    def rollout(self, x0: ArrayLike, n_samples: int, dt: float | None = None) -> FloatArray:
        """Roll out from every initial state at once, clipping each state to the box.

        Args:
            x0: Initial states, shape (R, 2) (or (2,) for one), in [m]; clipped to the box.
            n_samples: States per rollout, >= 1 (n_samples - 1 integration steps).
            dt: Step [unit normalised time]; default :attr:`dt` (N - 1 steps span one demo).

        Returns:
            States, shape (R, n_samples, 2), in [m]; ``[:, 0]`` is the clipped x0.

        Raises:
            ConfigError: Bad shapes, non-finite x0, n_samples < 1 or dt <= 0.
        """
        x = _points(np.atleast_2d(np.asarray(x0, dtype=np.float64)), "x0")
        if isinstance(n_samples, bool) or not isinstance(n_samples, int) or n_samples < 1:
            raise ConfigError(f"n_samples must be an integer >= 1; got {n_samples!r}")
        step = self.dt if dt is None else float(dt)
        if not (math.isfinite(step) and step > 0.0):
            raise ConfigError(f"dt must be a finite number > 0; got {dt!r}")
        mu, s = self.positions.mean, self.positions.scale
        lo = torch.as_tensor((self.box[0] - mu) / s, dtype=torch.float32)
        hi = torch.as_tensor((self.box[1] - mu) / s, dtype=torch.float32)
        ratio = torch.as_tensor(self.velocities.scale / s, dtype=torch.float32)
        offset = torch.as_tensor(self.velocities.mean / s, dtype=torch.float32)

        def rate(z: torch.Tensor) -> torch.Tensor:
            return self.net(z) * ratio + offset

        with torch_threads(self.threads), torch.no_grad():
            z = torch.as_tensor((x - mu) / s, dtype=torch.float32).clamp(lo, hi)
            states = [z]
            for _ in range(n_samples - 1):
                z = (z + step * _increment(rate, z, step, self.integrator)).clamp(lo, hi)
                states.append(z)
            out = torch.stack(states, dim=1).double().numpy()
        return np.clip(out * s + mu, self.box[0], self.box[1])  # float32 round-off at the walls


def _increment(
    rate: Callable[[torch.Tensor], torch.Tensor], z: torch.Tensor, h: float, integrator: Integrator
) -> torch.Tensor:
    """Mean slope of one explicit step of size h from z.

    ``"rk4"`` is the 3/8-rule RK4 that torchdiffeq's fixed-grid ``rk4`` takes, so a NODE is rolled
    out with exactly the scheme it was trained through.
    """
    k1 = rate(z)
    if integrator == "euler":
        return k1
    k2 = rate(z + h * k1 / 3.0)
    k3 = rate(z + h * (k2 - k1 / 3.0))
    k4 = rate(z + h * (k1 - k2 + k3))
    return (k1 + 3.0 * (k2 + k3) + k4) / 8.0


@dataclass(frozen=True, eq=False)
class TrainedLearner:
    """A trained learner: its policy and what training did."""

    name: LearnerName
    """Which learner."""
    policy: VectorFieldPolicy
    """The policy used at test time (ILEED: the shared policy's mean only)."""
    config: TrainConfig
    """The settings it was trained with."""
    loss_history: FloatArray
    """Training loss of every step, shape (steps,) (non-finite on skipped steps)."""
    seconds: float
    """Wall time of training [s]."""
    skipped_steps: int = 0
    """Steps skipped because the loss or a gradient was not finite."""
    expertise: dict[str, float] = field(default_factory=dict)
    """ILEED only: mean σ_i(s) over each demonstrator's own states, in (0, 1)."""


def _points(values: ArrayLike, what: str) -> FloatArray:
    x = np.asarray(values, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 2:
        raise ConfigError(f"{what} must have shape (B, 2); got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ConfigError(f"{what} has NaN or infinite values")
    return x


def make_policy(
    net: nn.Module, data: DemoData, config: TrainConfig, integrator: Integrator = "euler"
) -> VectorFieldPolicy:
    """The test-time policy around a trained `net` (put in eval mode, gradients off)."""
    net.eval()
    for p in net.parameters():
        p.requires_grad_(False)
    return VectorFieldPolicy(
        net=net,
        positions=data.positions,
        velocities=data.velocities,
        box=data.box,
        dt=data.dt,
        integrator=integrator,
        threads=config.threads,
    )


@contextlib.contextmanager
def torch_threads(threads: int) -> Iterator[None]:
    """Limit torch to `threads` threads inside the block, restoring the caller's count."""
    saved = torch.get_num_threads()
    if saved != threads:
        torch.set_num_threads(threads)
    try:
        yield
    finally:
        if torch.get_num_threads() != saved:
            torch.set_num_threads(saved)
