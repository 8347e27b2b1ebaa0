"""What every imitation learner shares: the state, corrective (DART) data, the training config.

Data flow, one learner::

    demos (M, N, 2) [m], uniform on t ∈ [0, 1] ──► prepare_demos ──► DemoData, one row per sample:
        state "phase" (default): each demo resampled at uniform steps of its estimated phase
            (:mod:`~bt_pipeline.evaluate.learners.phase`); features (z, cos φ, sin φ)
        state "position" (the paper as written): the demo's own samples; features z
        z = (x - μ_x) / s_x, v = ((x_{k+1} - x_k) / Δt - μ_v) / s_v   (forward differences)
    ──► learner-specific loss on an MLP, with corrective data (below) ──► fit (Adam, cosine)
    ──► LearnedPolicy (:mod:`~bt_pipeline.evaluate.learners.policy`): rolled out from x_0 with
        φ̇ = ω, every state clipped to the padded box of the training positions.

**Corrective data (DART-style; Laskey et al., CoRL 2017).** Perfect demos never leave the loop,
so the field off the loop is unconstrained and a rollout keeps any offset it starts with. Every
learner therefore also trains on perturbed states x̃ = x_k + δ, δ ~ N(0, (`dart_noise` · size)²)
per axis (size = the demos' largest extent), for a share `dart_fraction` of every batch, labelled
with the action that returns to the demo at rate K = `dart_gain` / T: ã = a_k - K δ (the demo's
x_{k+j} + δ e^{-K j Δt} for the trajectory-level learners). Under this label an offset decays as
e^{-K t}, i.e. by e^{-dart_gain} per period. It is applied identically to every dataset: the
corrections point back to whatever the dataset's demos are. ``dart_fraction=0`` switches it off.

Actions are the paper's forward differences a_k = (x_{k+1} - x_k) / Δt with Δt = 1 / (N - 1);
the artificial last action a_N = 0 is dropped, and no wrap-around difference is used.
"""

from __future__ import annotations

import contextlib
import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Literal

import numpy as np
import torch
from numpy.typing import ArrayLike
from torch import nn
from torch.nn import functional

from bt_pipeline.data.records import MIN_SAMPLES, FloatArray
from bt_pipeline.evaluate.learners.conditioning import Conditioning
from bt_pipeline.evaluate.learners.phase import estimate_phases, phase_resample
from bt_pipeline.exceptions import ConfigError, DemoError

if TYPE_CHECKING:  # policy.py builds on this module
    from bt_pipeline.evaluate.learners.policy import LearnedPolicy

LearnerName = Literal["bc", "traj_bc", "ileed", "node"]
"""An imitation learner of the paper's evaluation (Sec. IV)."""
StateRep = Literal["phase", "position"]
"""A learner's state: position plus the phase of a canonical oscillator (bt), or the 2-D position
alone (the paper as written)."""
STATES: tuple[StateRep, ...] = ("phase", "position")


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
    state: StateRep = "phase"
    """The policy's state (module doc)."""
    dart_noise: float = 0.08
    """Std of the corrective perturbation per axis, as a fraction of the demos' largest extent."""
    dart_fraction: float = 0.5
    """Share of every batch that is perturbed (0 switches corrective data off)."""
    dart_gain: float = 8.0
    """Decay of an offset per canonical period under the corrective labels (K = gain / T)."""

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
        if self.state not in STATES:
            raise ConfigError(f"state must be one of {', '.join(STATES)}; got {self.state!r}")
        if self.dart_noise < 0.0 or self.dart_gain < 0.0:
            raise ConfigError(
                f"dart_noise and dart_gain must be >= 0; got {self.dart_noise}, {self.dart_gain}"
            )
        if not 0.0 <= self.dart_fraction <= 1.0:
            raise ConfigError(f"dart_fraction must be in [0, 1]; got {self.dart_fraction}")


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


class MLP(nn.Module):
    """Tanh MLP with orthogonal weights and zero biases; the output layer is scaled down (gain 0.1)
    so an untrained field is small.

    The forward pass calls ``F.linear`` on the layers' weights directly rather than the layer
    modules, through a tuple of (weight, bias) pairs made once: on these tiny nets the per-module
    call and attribute look-up overhead is a large part of a step.
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
        self._linear = self._pairs()

    def _pairs(self) -> tuple[tuple[torch.Tensor, torch.Tensor], ...]:
        pairs = []
        for layer in self.layers:
            assert isinstance(layer, nn.Linear)
            pairs.append((layer.weight, layer.bias))
        return tuple(pairs)

    def _apply(self, fn, recurse: bool = True):  # nn.Module's signature
        """``.to()``, ``.double()`` etc. may replace the parameters: refresh the cached pairs."""
        out = super()._apply(fn, recurse)
        self._linear = self._pairs()
        return out

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Outputs, shape (B, n_out), of inputs (B, n_in)."""
        *hidden, (weight, bias) = self._linear
        for w, b in hidden:
            x = torch.tanh(functional.linear(x, w, b))
        return functional.linear(x, weight, bias)


def make_mlp(n_in: int, n_out: int, hidden: int, depth: int) -> MLP:
    """A tanh :class:`MLP` with `depth` hidden layers of `hidden` units."""
    return MLP(n_in, n_out, hidden, depth)


@dataclass(frozen=True, eq=False)
class DemoData:
    """Demos prepared for training: every sample a row, float32 tensors in standardised units."""

    z: torch.Tensor
    """Standardised positions of every row, shape (R, 2)."""
    phase: torch.Tensor
    """Phase of every row [rad], shape (R,) (zeros for the position state)."""
    v: torch.Tensor
    """Standardised forward-difference velocity of every row, shape (R, 2) (zero on a demo's
    last row, which has no next sample and is never drawn as a pair)."""
    remaining: torch.Tensor
    """Rows after this one in its demo, int64, shape (R,)."""
    positions: Standardiser
    """Position standardiser (units [m])."""
    velocities: Standardiser
    """Velocity standardiser (units [m per unit normalised time])."""
    box: FloatArray
    """Rollout box [m], shape (2, 2): row 0 the lower corner, row 1 the upper corner."""
    dt: float
    """Step Δt = 1 / (N - 1) of the normalised time axis."""
    state: StateRep
    """The state the learner sees."""
    omega: float
    """ω, the canonical oscillator's rate [rad per unit normalised time] (0 for position)."""
    gain: float
    """K, the corrective decay rate [1 per unit normalised time]."""
    noise_m: float
    """Std of the corrective perturbation per axis [m]."""
    fraction: float
    """Share of a batch that is perturbed."""
    anchors: FloatArray
    """Training positions [m], shape (A, 2), and (column 2) their phases [rad]: where a
    rollout's initial phase is looked up; shape (A, 3)."""
    cond: torch.Tensor
    """Standardised condition of every row (its demo's), shape (R, C); C = 0 unconditioned."""
    conditions: Conditioning | None = None
    """How a raw condition is standardised (None: unconditioned)."""
    anchor_cond: FloatArray | None = None
    """The anchors' standardised conditions, shape (A, C) (None: unconditioned)."""

    @property
    def n_features(self) -> int:
        """Inputs of the policy: 4 for (z, cos φ, sin φ), 2 for z, plus C condition inputs."""
        return (4 if self.state == "phase" else 2) + int(self.cond.shape[1])

    @property
    def velocity_ratio(self) -> torch.Tensor:
        """s_v / s_x, shape (2,): converts a standardised velocity into dz/dt."""
        return torch.as_tensor(self.velocities.scale / self.positions.scale, dtype=torch.float32)

    @property
    def velocity_offset(self) -> torch.Tensor:
        """μ_v / s_x, shape (2,): the constant part of dz/dt."""
        return torch.as_tensor(self.velocities.mean / self.positions.scale, dtype=torch.float32)

    def features(
        self, z: torch.Tensor, phase: torch.Tensor, cond: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Network inputs, shape (B, n_features), of positions z (B, 2), phases (B,) and
        standardised conditions (B, C) (the rows' own, :attr:`cond`; None when C = 0)."""
        return phase_features(z, phase, self.state, cond)

    def rows_with(self, span: int) -> torch.Tensor:
        """Rows followed by at least `span` rows of the same demo, shape (n,)."""
        return torch.nonzero(self.remaining >= span).squeeze(1)

    def perturbation(self, count: int, generator: torch.Generator) -> torch.Tensor:
        """Corrective offsets δ [m], shape (count, 2): N(0, noise_m²) on a `fraction` of rows,
        zero on the others."""
        delta = torch.randn((count, 2), generator=generator) * self.noise_m
        keep = torch.rand((count, 1), generator=generator) < self.fraction
        return delta * keep

    def perturbed(
        self, rows: torch.Tensor, generator: torch.Generator
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Perturbed standardised states (B, 2), their δ in standardised positions (B, 2), and the
        corrective standardised velocity labels (B, 2) of `rows` (module doc)."""
        delta_m = self.perturbation(rows.shape[0], generator)
        scale_x = torch.as_tensor(self.positions.scale, dtype=torch.float32)
        scale_v = torch.as_tensor(self.velocities.scale, dtype=torch.float32)
        delta_z = delta_m / scale_x
        labels = self.v[rows] - self.gain * delta_m / scale_v
        return self.z[rows] + delta_z, delta_z, labels


def phase_features(
    z: torch.Tensor, phase: torch.Tensor, state: StateRep, cond: torch.Tensor | None = None
) -> torch.Tensor:
    """(z, cos φ, sin φ) for the phase state, z for the position state; shape (B, 4) or (B, 2);
    followed by the standardised condition (B, C) when one is given."""
    parts = (
        [z] if state == "position" else [z, torch.cos(phase)[:, None], torch.sin(phase)[:, None]]
    )
    if cond is not None and cond.shape[1] > 0:
        parts.append(cond)
    return parts[0] if len(parts) == 1 else torch.cat(parts, dim=1)


def prepare_demos(
    demos: ArrayLike,
    config: TrainConfig,
    min_samples: int = MIN_SAMPLES,
    preferences: ArrayLike | None = None,
) -> DemoData:
    """Validate demos (M, N, 2) [m] (uniform on t ∈ [0, 1]), estimate phases and standardise.

    With `preferences` (M, 2): (θ [deg], ρ) of each demo's demonstrator, every row also carries
    its demo's standardised preference (:class:`Conditioning`), an input of the policy.

    Raises:
        DemoError: Wrong shape, fewer than `min_samples` samples, non-finite or motionless demos.
        ConfigError: `preferences` not one finite (θ, ρ > 0) per demo.
    """
    x = np.array(demos, dtype=np.float64)  # a copy: the caller's array is never touched
    if x.ndim != 3 or x.shape[0] < 1 or x.shape[2] != 2:
        raise DemoError(f"demos must have shape (M, N, 2) with M >= 1; got {x.shape}")
    if x.shape[1] < max(min_samples, 8):
        raise DemoError(
            f"demos have {x.shape[1]} samples; at least {max(min_samples, 8)} are needed"
        )
    if not np.all(np.isfinite(x)):
        raise DemoError("demos contain NaN or infinite positions")
    dt = 1.0 / (x.shape[1] - 1)
    flat = x.reshape(-1, 2)
    lo, hi = flat.min(axis=0), flat.max(axis=0)
    size = float((hi - lo).max())
    if not size > 1e-12:
        raise DemoError("the demos' positions do not vary; a learner needs a moving demo")
    if config.state == "phase":
        fit = estimate_phases(x)
        sequences = phase_resample(x, fit, dt)
        omega, period = fit.omega, fit.period
    else:
        sequences = [np.column_stack([d, np.zeros(len(d))]) for d in x]
        omega, period = 0.0, 1.0
    rows = np.concatenate(sequences)
    velocities = np.concatenate(
        [np.vstack([np.diff(q[:, :2], axis=0) / dt, np.zeros((1, 2))]) for q in sequences]
    )
    remaining = np.concatenate([np.arange(len(q))[::-1] for q in sequences])
    pos_std = Standardiser.fit(rows[:, :2], "positions")
    vel_std = Standardiser.fit(velocities[remaining > 0], "velocities")
    z = (rows[:, :2] - pos_std.mean) / pos_std.scale
    v = np.where(remaining[:, None] > 0, (velocities - vel_std.mean) / vel_std.scale, 0.0)
    pad = config.box_padding * size
    step = max(1, len(rows) // 4000)
    conditioning, cond = None, np.zeros((len(rows), 0))
    if preferences is not None:
        if np.shape(preferences)[:1] != (x.shape[0],):
            raise ConfigError(
                f"preferences must hold one (θ, ρ) per demo ({x.shape[0]}); got "
                f"{np.shape(preferences)}"
            )
        conditioning = Conditioning.fit(preferences)
        cond = np.repeat(conditioning(preferences), [len(q) for q in sequences], axis=0)
    return DemoData(
        z=torch.as_tensor(z, dtype=torch.float32),
        phase=torch.as_tensor(rows[:, 2], dtype=torch.float32),
        v=torch.as_tensor(v, dtype=torch.float32),
        remaining=torch.as_tensor(remaining, dtype=torch.int64),
        positions=pos_std,
        velocities=vel_std,
        box=np.stack([lo - pad, hi + pad]),
        dt=dt,
        state=config.state,
        omega=omega,
        gain=config.dart_gain / period,
        noise_m=config.dart_noise * size,
        fraction=config.dart_fraction,
        anchors=rows[::step].copy(),
        cond=torch.as_tensor(cond, dtype=torch.float32),
        conditions=conditioning,
        anchor_cond=None if conditioning is None else cond[::step].copy(),
    )


@dataclass(frozen=True, eq=False)
class TrainedLearner:
    """A trained learner: its policy and what training did."""

    name: LearnerName
    """Which learner."""
    policy: LearnedPolicy
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
