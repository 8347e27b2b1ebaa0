"""The test-time policy of every learner: a vector field or a chunk predictor, rolled out.

Two kinds (:attr:`LearnedPolicy.kind`):

* ``"field"`` (BC, ILEED, NODE): ẋ = s_v ⊙ net(features(z, φ)) + μ_v, integrated by Euler (BC,
  ILEED) or RK4 (NODE, torchdiffeq's 3/8 rule, the scheme it was trained through).
* ``"chunk"`` (Traj-BC): net(features(z, φ)) predicts the next H positions as mean velocities over
  1..H steps; the rollout executes the first `execute` of them, then predicts again (receding
  horizon, as in action chunking).

The phase starts at the phase of the training sample nearest to x_0 and advances at the canonical
rate, φ_{k+1} = φ_k + ω Δt (:mod:`~bt_pipeline.evaluate.learners.phase`); a position-state policy
ignores it. A conditioned policy (trained with demonstrators' preferences) is rolled out for a
preference (θ, ρ): the net sees it as an input at every step, and the initial phase is looked up
among the training samples of the nearest training preference. Every state, the initial one
included, is clipped to the padded box of the training positions, so rollouts are finite and
bounded for any x_0.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from numpy.typing import ArrayLike
from torch import nn

from bt_pipeline.data.records import FloatArray
from bt_pipeline.evaluate.learners.common import (
    DemoData,
    Standardiser,
    StateRep,
    TrainConfig,
    phase_features,
    torch_threads,
)
from bt_pipeline.evaluate.learners.conditioning import Conditioning
from bt_pipeline.evaluate.learners.phase import nearest_phase
from bt_pipeline.exceptions import ConfigError

Integrator = Literal["euler", "rk4"]
"""How a field policy is integrated: explicit Euler (BC, ILEED) or RK4 (NODE, 3/8 rule)."""
PolicyKind = Literal["field", "chunk"]
"""A vector field (BC, ILEED, NODE) or a predictor of the next H positions (Traj-BC)."""


@dataclass(frozen=True, eq=False)
class LearnedPolicy:
    """A trained policy on task coordinates [m] (module doc)."""

    net: nn.Module
    """MLP from features (B, 4 or 2) to a standardised velocity (B, 2) or chunk (B, 2H)."""
    positions: Standardiser
    """Position standardiser."""
    velocities: Standardiser
    """Velocity standardiser."""
    box: FloatArray
    """Rollout box [m], shape (2, 2) (lower corner, upper corner)."""
    dt: float
    """Rollout step: the training demos' Δt = 1 / (N - 1)."""
    state: StateRep = "phase"
    """The state the net sees."""
    omega: float = 0.0
    """ω [rad per unit normalised time]."""
    anchors: FloatArray | None = None
    """Training positions and phases, shape (A, 3): where the initial phase is looked up."""
    kind: PolicyKind = "field"
    """Vector field or chunk predictor."""
    integrator: Integrator = "euler"
    """Scheme of a field policy."""
    horizon: int = 1
    """H, positions per predicted chunk (chunk policies)."""
    execute: int = 1
    """Positions executed per chunk before predicting again (chunk policies)."""
    threads: int = 1
    """Torch threads while rolling out."""
    conditions: Conditioning | None = None
    """A conditioned policy's standardisation of (θ, ρ) (None: unconditioned)."""
    anchor_cond: FloatArray | None = None
    """The anchors' standardised conditions, shape (A, C) (conditioned policies)."""

    @property
    def conditioned(self) -> bool:
        """Whether the policy takes a demonstrator's preference (θ, ρ) as an input."""
        return self.conditions is not None

    def condition(self, preferences: ArrayLike | None, count: int) -> FloatArray | None:
        """Standardised conditions (count, C) of `preferences`, (θ [deg], ρ) as (2,) or
        (count, 2); None for an unconditioned policy.

        Raises:
            ConfigError: A conditioned policy without preferences, an unconditioned one with
                them, or preferences of the wrong shape.
        """
        if self.conditions is None:
            if preferences is not None:
                raise ConfigError("this policy was trained without preferences; give none")
            return None
        if preferences is None:
            raise ConfigError("a conditioned policy needs the preference (θ, ρ) it draws")
        c = self.conditions(preferences)
        if c.shape[0] == 1:
            c = np.repeat(c, count, axis=0)
        if c.shape[0] != count:
            raise ConfigError(f"give one preference or one per state ({count}); got {c.shape[0]}")
        return c

    def initial_phase(self, x0: ArrayLike, cond: FloatArray | None = None) -> FloatArray:
        """Phase [rad] at which a rollout from each x0 (R, 2) [m] starts, shape (R,); with
        standardised conditions `cond` (R, C), among the training samples of the nearest
        training preference."""
        x = _points(np.atleast_2d(np.asarray(x0, dtype=np.float64)), "x0")
        if self.state == "position" or self.anchors is None:
            return np.zeros(x.shape[0])
        x = np.clip(x, self.box[0], self.box[1])
        if cond is None or self.anchor_cond is None:
            return nearest_phase(x, self.anchors[:, :2], self.anchors[:, 2])
        out = np.empty(x.shape[0])
        for value in np.unique(cond, axis=0):
            rows = np.all(cond == value, axis=1)
            gap = np.linalg.norm(self.anchor_cond - value, axis=1)
            own = gap <= gap.min() + 1e-6
            out[rows] = nearest_phase(x[rows], self.anchors[own, :2], self.anchors[own, 2])
        return out

    def velocity(
        self,
        positions: ArrayLike,
        phases: ArrayLike | None = None,
        preferences: ArrayLike | None = None,
    ) -> FloatArray:
        """π(x, φ) [m per unit normalised time], shape (B, 2), at positions (B, 2) [m] and phases
        (B,) [rad] (default: each position's nearest training phase), for `preferences`
        (conditioned policies: (θ [deg], ρ), (2,) or (B, 2)). A chunk policy gives the mean
        velocity of its first step."""
        x = _points(positions, "positions")
        c = self.condition(preferences, x.shape[0])
        phi = self.initial_phase(x, c) if phases is None else np.asarray(phases, dtype=np.float64)
        cond = None if c is None else torch.as_tensor(c, dtype=torch.float32)
        with torch_threads(self.threads), torch.no_grad():
            z = torch.as_tensor(
                (x - self.positions.mean) / self.positions.scale, dtype=torch.float32
            )
            phase = torch.as_tensor(phi, dtype=torch.float32)
            out = self.net(phase_features(z, phase, self.state, cond))
            v = out[:, :2].double().numpy()
        return v * self.velocities.scale + self.velocities.mean

    def rollout(
        self,
        x0: ArrayLike,
        n_samples: int,
        dt: float | None = None,
        preferences: ArrayLike | None = None,
    ) -> FloatArray:
        """Roll out from every initial state at once, clipping each state to the box.

        Args:
            x0: Initial states, shape (R, 2) (or (2,) for one), in [m]; clipped to the box.
            n_samples: States per rollout, >= 1 (n_samples - 1 steps).
            dt: Step [unit normalised time]; default :attr:`dt`. A chunk policy only runs at the
                Δt it was trained with.
            preferences: A conditioned policy's demonstrator preference (θ [deg], ρ) to draw,
                shape (2,) for every rollout or (R, 2); None for an unconditioned policy.

        Returns:
            States, shape (R, n_samples, 2), in [m]; ``[:, 0]`` is the clipped x0.

        Raises:
            ConfigError: Bad shapes, non-finite x0, n_samples < 1, dt <= 0, another dt for a
                chunk policy, or preferences missing for a conditioned policy (or given to an
                unconditioned one).
        """
        x = _points(np.atleast_2d(np.asarray(x0, dtype=np.float64)), "x0")
        c = self.condition(preferences, x.shape[0])
        cond = None if c is None else torch.as_tensor(c, dtype=torch.float32)
        if isinstance(n_samples, bool) or not isinstance(n_samples, int) or n_samples < 1:
            raise ConfigError(f"n_samples must be an integer >= 1; got {n_samples!r}")
        step = self.dt if dt is None else float(dt)
        if not (math.isfinite(step) and step > 0.0):
            raise ConfigError(f"dt must be a finite number > 0; got {dt!r}")
        if self.kind == "chunk" and not math.isclose(step, self.dt):
            raise ConfigError(f"a chunk policy runs at its training dt {self.dt:.6g}; got {step}")
        mu, s = self.positions.mean, self.positions.scale
        lo = torch.as_tensor((self.box[0] - mu) / s, dtype=torch.float32)
        hi = torch.as_tensor((self.box[1] - mu) / s, dtype=torch.float32)
        ratio = torch.as_tensor(self.velocities.scale / s, dtype=torch.float32)
        offset = torch.as_tensor(self.velocities.mean / s, dtype=torch.float32)
        phi0 = torch.as_tensor(self.initial_phase(x, c), dtype=torch.float32)

        def rate(z: torch.Tensor, phase: torch.Tensor) -> torch.Tensor:
            return self.net(phase_features(z, phase, self.state, cond)) * ratio + offset

        with torch_threads(self.threads), torch.no_grad():
            z = torch.as_tensor((x - mu) / s, dtype=torch.float32).clamp(lo, hi)
            states = [z]
            k = 0
            while len(states) < n_samples:
                phase = phi0 + self.omega * step * k
                if self.kind == "chunk":
                    chunk = self._chunk(z, phase, ratio, offset, cond)
                    for j in range(min(self.execute, n_samples - len(states))):
                        states.append((z + chunk[:, j]).clamp(lo, hi))
                    z = states[-1]
                    k = len(states) - 1
                    continue
                z = (
                    z + step * _increment(rate, z, phase, step, self.omega, self.integrator)
                ).clamp(lo, hi)
                states.append(z)
                k += 1
            out = torch.stack(states, dim=1).double().numpy()
        return np.clip(out * s + mu, self.box[0], self.box[1])  # float32 round-off at the walls

    def _chunk(
        self,
        z: torch.Tensor,
        phase: torch.Tensor,
        ratio: torch.Tensor,
        offset: torch.Tensor,
        cond: torch.Tensor | None,
    ) -> torch.Tensor:
        """Displacements (B, H, 2) of the next H standardised positions from z."""
        features = phase_features(z, phase, self.state, cond)
        out = self.net(features).reshape(z.shape[0], self.horizon, 2)
        steps = torch.arange(1, self.horizon + 1, dtype=torch.float32)[None, :, None] * self.dt
        return (out * ratio + offset) * steps


def _increment(
    rate: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    z: torch.Tensor,
    phase: torch.Tensor,
    h: float,
    omega: float,
    integrator: Integrator,
) -> torch.Tensor:
    """Mean slope of one explicit step of size h from (z, φ), φ advancing at ω.

    ``"rk4"`` is the 3/8-rule RK4 that torchdiffeq's fixed-grid ``rk4`` takes, so a NODE is rolled
    out with exactly the scheme it was trained through.
    """
    k1 = rate(z, phase)
    if integrator == "euler":
        return k1
    k2 = rate(z + h * k1 / 3.0, phase + omega * h / 3.0)
    k3 = rate(z + h * (k2 - k1 / 3.0), phase + omega * 2.0 * h / 3.0)
    k4 = rate(z + h * (k1 - k2 + k3), phase + omega * h)
    return (k1 + 3.0 * (k2 + k3) + k4) / 8.0


def _points(values: ArrayLike, what: str) -> FloatArray:
    x = np.asarray(values, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 2:
        raise ConfigError(f"{what} must have shape (B, 2); got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ConfigError(f"{what} has NaN or infinite values")
    return x


def make_policy(
    net: nn.Module,
    data: DemoData,
    config: TrainConfig,
    integrator: Integrator = "euler",
    kind: PolicyKind = "field",
    horizon: int = 1,
    execute: int = 1,
) -> LearnedPolicy:
    """The test-time policy around a trained `net` (put in eval mode, gradients off)."""
    net.eval()
    for p in net.parameters():
        p.requires_grad_(False)
    return LearnedPolicy(
        net=net,
        positions=data.positions,
        velocities=data.velocities,
        box=data.box,
        dt=data.dt,
        state=data.state,
        omega=data.omega,
        anchors=data.anchors,
        kind=kind,
        integrator=integrator,
        horizon=horizon,
        execute=execute,
        threads=config.threads,
        conditions=data.conditions,
        anchor_cond=data.anchor_cond,
    )
