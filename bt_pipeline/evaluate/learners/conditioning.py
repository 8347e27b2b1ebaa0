"""A conditioned learner's input: the demonstrator's preference (θ, ρ), standardised.

Every learner (:mod:`bt_pipeline.evaluate.learners`) can take each demo's demonstrator preference
as an input, so one policy draws each demonstrator's own loop instead of their mean.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError


@dataclass(frozen=True)
class Conditioning:
    """What a conditioned learner sees of a demonstrator: c = ((θ, log ρ) − mean) / scale.

    A demonstrator's preference (θ [deg], ρ) is an input of every conditioned learner, so one
    policy draws each demonstrator's own loop (docs/evaluation.md). Standardised over the
    training demos; an input that does not vary gets scale 1 (it then carries no information,
    and a rollout asked for another value sees how far it lies from the training one).
    """

    mean: FloatArray
    """Mean of (θ [deg], log ρ) over the training demos, shape (2,)."""
    scale: FloatArray
    """Standard deviation of each (1 where it does not vary), shape (2,)."""

    @classmethod
    def fit(cls, preferences: ArrayLike) -> Conditioning:
        """The standardisation of the training demos' preferences (M, 2): (θ [deg], ρ).

        Raises:
            ConfigError: Wrong shape, non-finite values or ρ ≤ 0.
        """
        raw = cls.raw(preferences)
        std = raw.std(axis=0)
        return cls(mean=raw.mean(axis=0), scale=np.where(std > 1e-9, std, 1.0))

    @staticmethod
    def raw(preferences: ArrayLike) -> FloatArray:
        """(θ [deg], log ρ) of preferences (B, 2) given as (θ [deg], ρ)."""
        p = np.atleast_2d(np.asarray(preferences, dtype=np.float64))
        if p.ndim != 2 or p.shape[1] != 2:
            raise ConfigError(f"preferences must have shape (M, 2): (θ [deg], ρ); got {p.shape}")
        if not (np.all(np.isfinite(p)) and np.all(p[:, 1] > 0.0)):
            raise ConfigError("preferences must be finite, with ρ > 0")
        return np.column_stack([p[:, 0], np.log(p[:, 1])])

    def __call__(self, preferences: ArrayLike) -> FloatArray:
        """Standardised conditions (B, 2) of preferences (B, 2): (θ [deg], ρ)."""
        return (self.raw(preferences) - self.mean) / self.scale


__all__ = ["Conditioning"]
