"""A closed loop as a complex Fourier series: the template a demo is measured against.

A loop is x(φ), φ ∈ [0, 2π), written as z(φ) = x + i y = Σ_{k=-K..K} c_k e^{ikφ} in task
coordinates [m] (elliptic Fourier descriptors in complex form). A similarity transform is
closed-form on the coefficients: rotating by θ and scaling by ρ multiplies every c_k by
ρ e^{iθ}, a translation adds to c_0, starting at phase φ0 multiplies c_k by e^{ikφ0}, and
travelling the other way swaps c_k and c_{-k}.

A task's loop is either its **guide** (the shape the app draws, :mod:`bt_pipeline.data.shapes`,
evaluated exactly as drawn) or a loop **learned** from the demos themselves
(:mod:`bt_pipeline.clean.loop_learn`). Segmentation, the θ/ρ estimate, the shape gate and the
take checks measure a demo against a :class:`LoopShape`, whichever it is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError

_GUIDE_HARMONICS = 8  # The guides are trigonometric polynomials of degree ≤ 3: exact with 8.
_SIZE_POINTS = 1024  # Points the bounding box is read on.


@dataclass(frozen=True, eq=False)
class LoopShape:
    """A closed loop z(φ) = Σ_{k=-K..K} c_k e^{ikφ} (module doc)."""

    coefficients: np.ndarray
    """c_k for k = −K..K, shape (2K + 1,), complex, in [m]."""
    label: str
    """What the loop is, for notes and attrs: ``"wiping guide"``, ``"learned"``."""
    guide_task: str | None = None
    """The task whose guide this is (evaluated exactly as the app draws it), or None."""
    placed: bool = False
    """Whether the loop sits where a demo drew it, turned and scaled about the plane's origin
    (a best demo's loop, :mod:`bt_pipeline.clean.best_loop`), rather than on its box's centre."""
    near_guide: bool = False
    """Whether this placed loop replaced the task's guide because the best demo draws a loop
    near it (within 4 %) steadily: the demos follow it as they follow a guide, and fits may be
    held at the origin as against one (:mod:`bt_pipeline.clean.guide_consensus`, step 5)."""

    def __post_init__(self) -> None:
        c = np.asarray(self.coefficients)
        if c.ndim != 1 or c.size % 2 != 1 or c.size < 3:
            raise ConfigError(f"a loop needs 2K + 1 >= 3 coefficients; got shape {c.shape}")
        if not np.all(np.isfinite(c)):
            raise ConfigError(f"{self.label}: loop coefficients must be finite")
        object.__setattr__(self, "coefficients", c.astype(np.complex128))

    @property
    def harmonics(self) -> int:
        """K, the highest harmonic."""
        return (self.coefficients.size - 1) // 2

    @property
    def is_guide(self) -> bool:
        """Whether this is a task's built-in guide (drawn centred on the task plane's origin)."""
        return self.guide_task is not None

    @property
    def anchored(self) -> bool:
        """Whether the plane's origin is the point demos turn and scale this loop about: a
        guide (the app draws it there) or a loop :attr:`placed` where its demo drew it."""
        return self.guide_task is not None or self.placed

    def at(self, phase: ArrayLike) -> FloatArray:
        """Positions at the given phases [rad] (any shape): that shape plus a last axis of 2 [m]."""
        phi = np.asarray(phase, dtype=np.float64)
        if self.guide_task is not None:
            from bt_pipeline.data.shapes import canonical_shape

            return canonical_shape(self.guide_task, phi)
        k = np.arange(-self.harmonics, self.harmonics + 1)
        z = np.exp(1j * phi[..., None] * k) @ self.coefficients
        return np.stack([np.real(z), np.imag(z)], axis=-1)

    def points(self, n: int) -> FloatArray:
        """`n` points at uniform phase 2πj/n, j = 0..n−1 (endpoint excluded), shape (n, 2) [m]."""
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 3:
            raise ConfigError(f"a loop needs an integer n >= 3 points; got {n!r}")
        return self.at(2.0 * np.pi * np.arange(int(n)) / int(n))

    @property
    def size_m(self) -> float:
        """The larger side of the loop's bounding box [m]."""
        return float(np.max(np.ptp(self.points(_SIZE_POINTS), axis=0)))

    @property
    def centre(self) -> FloatArray:
        """The centre of the loop's bounding box, shape (2,) [m]."""
        p = self.points(_SIZE_POINTS)
        return 0.5 * (p.min(axis=0) + p.max(axis=0))

    def transformed(
        self, theta_deg: float = 0.0, rho: float = 1.0, translation: ArrayLike = (0.0, 0.0)
    ) -> LoopShape:
        """ρ R(θ) x(φ) + t, as a learned loop (no longer the guide as drawn)."""
        t = np.asarray(translation, dtype=np.float64)
        c = self.coefficients * (rho * np.exp(1j * math.radians(theta_deg)))
        c[self.harmonics] += complex(t[0], t[1])
        return LoopShape(c, self.label)

    def reversed(self) -> LoopShape:
        """The same loop travelled the other way: x(−φ), in the same place."""
        return LoopShape(
            self.coefficients[::-1].copy(),
            self.label,
            placed=self.placed,
            near_guide=self.near_guide,
        )

    def started_at(self, phase: float) -> LoopShape:
        """The same loop started at phase `phase` [rad]: x(φ + phase), in the same place."""
        k = np.arange(-self.harmonics, self.harmonics + 1)
        shifted = self.coefficients * np.exp(1j * k * phase)
        return LoopShape(shifted, self.label, placed=self.placed, near_guide=self.near_guide)

    @classmethod
    def from_points(cls, points: ArrayLike, harmonics: int, label: str = "learned") -> LoopShape:
        """The loop through `points` at uniform phase (endpoint excluded), low-passed to K.

        Args:
            points: One loop, shape (n, 2) with n > 2K, at phases 2πj/n [m].
            harmonics: K, the highest harmonic kept.
            label: What the loop is.
        """
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] <= 2 * harmonics or harmonics < 1:
            raise ConfigError(f"need points (n > 2K, 2) and K >= 1; got {p.shape}, K={harmonics}")
        spectrum = np.fft.fft(p[:, 0] + 1j * p[:, 1]) / p.shape[0]
        k = np.arange(-harmonics, harmonics + 1)
        return cls(spectrum[k % p.shape[0]], label)

    @classmethod
    def guide(cls, task: str) -> LoopShape:
        """The task's guide as the app draws it (raises UnknownTaskError for a task without one)."""
        from bt_pipeline.data.shapes import canonical_loop

        n = 4 * _GUIDE_HARMONICS
        drawn = canonical_loop(task, n)
        exact = cls.from_points(drawn, _GUIDE_HARMONICS)
        return cls(exact.coefficients, f"{task} guide", guide_task=task)


def as_loop(loop: LoopShape | str) -> LoopShape:
    """`loop` itself, or the guide of the task it names."""
    return loop if isinstance(loop, LoopShape) else LoopShape.guide(loop)


__all__ = ["LoopShape", "as_loop"]


def arc_length_resample(points: FloatArray, n: int) -> FloatArray:
    """`n` points evenly spaced by arc length along a polyline, shape (n, 2)."""
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(steps)])
    if s[-1] <= 0:
        return np.repeat(points[:1], n, axis=0)
    grid = np.linspace(0.0, s[-1], n)
    return np.stack([np.interp(grid, s, points[:, d]) for d in range(2)], axis=1)
