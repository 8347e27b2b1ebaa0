"""Eq. (7): the raw metrics of a demo and their frozen min-max map over a set of raw demos.

The refinement stage reuses a :class:`Normaliser` fitted on the raw demos, so its map stays
fixed and affine (docs/algorithms.md §7 row 7); :mod:`bt_pipeline.score.utility` builds Eq. (8)
on it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bt_pipeline.exceptions import ConfigError, DemoError

FloatArray = NDArray[np.float64]

METRIC_NAMES: tuple[str, ...] = ("mutual_information", "symmetry", "closure", "smoothness")
"""Raw metrics in the column order of :meth:`RawMetrics.as_array` and the default normaliser."""


@dataclass(frozen=True, slots=True)  # one per take in the app's library: no __dict__
class RawMetrics:
    """Unnormalised metrics of one demo."""

    mutual_information: float
    """I(S; A) by KSG-1 [nats] (Eq. 1); higher is better."""
    symmetry: float
    """L1 [m] (Eq. 4); lower is better."""
    closure: float
    """L2 [m] (Eq. 5); lower is better."""
    smoothness: float
    """L3 [m²] (Eq. 6); lower is better."""

    def as_array(self) -> FloatArray:
        """The metrics in :data:`METRIC_NAMES` order, shape (4,)."""
        return np.array([self.mutual_information, self.symmetry, self.closure, self.smoothness])


@dataclass(frozen=True)
class Normaliser:
    """Frozen per-metric min-max maps (Eq. 7), fitted on a set of raw demos.

    The refinement stage keeps the (min, max) of the raw set, so the map is fixed and affine:
    ``normalised = (value - min) * scale`` with ``scale = 1 / (max - min)``, or 0 where
    max - min ≤ δ (docs/algorithms.md §7 row 7).
    """

    names: tuple[str, ...]
    """Metric names, one per column."""
    min: FloatArray
    """Minimum of each metric over the fitting set, shape (K,)."""
    max: FloatArray
    """Maximum of each metric over the fitting set, shape (K,)."""
    delta: float = 1e-12
    """δ of Eq. (7)."""

    def __post_init__(self) -> None:
        lo = np.array(self.min, dtype=np.float64)
        hi = np.array(self.max, dtype=np.float64)
        names = tuple(self.names)
        if lo.shape != (len(names),) or hi.shape != (len(names),):
            raise ConfigError(
                f"normaliser needs min and max of shape ({len(names)},) for metrics {names}; got "
                f"{lo.shape} and {hi.shape}"
            )
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi >= lo)):
            raise ConfigError(f"normaliser needs finite min ≤ max; got {lo} and {hi}")
        if not (math.isfinite(self.delta) and self.delta >= 0.0):
            raise ConfigError(f"delta must be finite and ≥ 0; got {self.delta!r}")
        lo.setflags(write=False)
        hi.setflags(write=False)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "min", lo)
        object.__setattr__(self, "max", hi)

    @classmethod
    def from_values(
        cls, values: ArrayLike, names: Sequence[str] = METRIC_NAMES, delta: float = 1e-12
    ) -> Normaliser:
        """Fit on raw metric values, shape (M, K), one row per demo, columns named `names`."""
        v = metric_values(values, "values")
        if v.ndim != 2 or v.shape[0] == 0 or v.shape[1] != len(names):
            raise ConfigError(
                f"values must have shape (M, {len(names)}) with M ≥ 1 for metrics "
                f"{tuple(names)}; got {v.shape}"
            )
        return cls(names=tuple(names), min=np.min(v, axis=0), max=np.max(v, axis=0), delta=delta)

    @classmethod
    def from_raw_metrics(cls, metrics: Sequence[RawMetrics], delta: float = 1e-12) -> Normaliser:
        """Fit on the raw metrics of M ≥ 1 demos (columns :data:`METRIC_NAMES`)."""
        if not metrics:
            raise DemoError("a normaliser needs the metrics of at least one demo")
        return cls.from_values(np.stack([m.as_array() for m in metrics]), METRIC_NAMES, delta)

    @property
    def scale(self) -> FloatArray:
        """1 / (max - min) per metric, 0 where max - min ≤ δ, shape (K,)."""
        span = self.max - self.min
        ok = span > self.delta
        return np.where(ok, 1.0 / np.where(ok, span, 1.0), 0.0)

    def index(self, name: str) -> int:
        """Column of metric `name`."""
        if name not in self.names:
            raise ConfigError(f"unknown metric {name!r}; this normaliser has {self.names}")
        return self.names.index(name)

    def affine(self, name: str) -> tuple[float, float]:
        """(offset, scale) of metric `name`: normalised = (value - offset) * scale.

        Plain floats, so the map also applies to torch tensors.
        """
        j = self.index(name)
        return float(self.min[j]), float(self.scale[j])

    def normalise(self, values: ArrayLike, clip: bool = False) -> FloatArray:
        """Normalise raw values of all metrics, shape (..., K), by the frozen (min, max).

        Args:
            values: Raw metrics, last axis in :attr:`names` order.
            clip: Clip to [0, 1] (new values may fall outside the fitting range).

        Returns:
            Normalised values, same shape; 0 in columns whose range is ≤ δ.
        """
        v = metric_values(values, "values")
        if v.ndim == 0 or v.shape[-1] != len(self.names):
            raise ConfigError(
                f"values must have shape (..., {len(self.names)}) for metrics {self.names}; "
                f"got {v.shape}"
            )
        out = normalise_values(v, self.min, self.max, self.delta)
        return np.clip(out, 0.0, 1.0) if clip else out

    def normalise_metric(self, name: str, values: ArrayLike, clip: bool = False) -> FloatArray:
        """Normalise raw values of the one metric `name`, any shape."""
        j = self.index(name)
        out = normalise_values(
            metric_values(values, "values"), self.min[j], self.max[j], self.delta
        )
        return np.clip(out, 0.0, 1.0) if clip else out


def minmax_normalise(values: ArrayLike, delta: float = 1e-12) -> FloatArray:
    """Min-max normalisation with a δ guard (Eq. 7).

    Args:
        values: One metric of M demos, shape (M,).
        delta: Ranges max - min ≤ δ give all zeros.

    Returns:
        (v - min) / (max - min) in [0, 1], shape (M,); zeros when the range is ≤ δ.
    """
    v = metric_values(values, "values")
    if v.ndim != 1:
        raise ConfigError(f"minmax_normalise takes one metric of shape (M,); got {v.shape}")
    return normalise_values(v, np.min(v), np.max(v), delta)  # Eq. (7)


def normalise_values(values: FloatArray, lo: ArrayLike, hi: ArrayLike, delta: float) -> FloatArray:
    """(values - lo) / (hi - lo) where hi - lo > δ, else 0 (Eq. 7); broadcasts on the last axis."""
    lo = np.asarray(lo, dtype=np.float64)
    span = np.asarray(hi, dtype=np.float64) - lo
    ok = span > delta
    return np.where(ok, (values - lo) / np.where(ok, span, 1.0), 0.0)


def metric_values(values: ArrayLike, name: str) -> FloatArray:
    """`values` as a float array; DemoError when any is NaN or infinite."""
    v = np.asarray(values, dtype=np.float64)
    if not np.all(np.isfinite(v)):
        raise DemoError(f"{name} contain NaN or infinite metric values")
    return v
