"""Rhythmic dynamic movement primitives fitted to one periodic demo (paper Sec. III-B step 2).

The rhythmic DMP of Ijspeert et al. (2013, Sec. 2; docs/algorithms.md §2), per dimension:

    τ ż = α_z (β_z (g − y) − z) + f(φ),    τ ẏ = z,    τ φ̇ = 1,

with anchor g (the centre of the loop), r = 1 and the forcing term
f(φ) = Σ_i ψ_i(φ) w_i / Σ_i ψ_i(φ) on von Mises bases ψ_i = exp(h (cos(φ − c_i) − 1)).

Time is the demo's normalised time t ∈ [0, 1] (docs/algorithms.md §7 row 1), so the period T
and τ = T / (2π) are fractions of the demo's duration. Written in the elapsed phase s = t / τ the
system no longer depends on τ: it is linear and time-invariant, driven by a 2π-periodic input.
A rollout is therefore computed exactly rather than integrated step by step (docs/algorithms.md
§8 trap 7): its unique periodic steady state (the limit cycle) follows from the Fourier series of
the forcing term, and the departure from it decays as the matrix exponential exp(A s) of the
linear part. Any number of rollouts costs one FFT plus a few array products.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bt_pipeline.clean.stage1.period import estimate_period, loop_size
from bt_pipeline.data.records import MIN_SAMPLES, FloatArray
from bt_pipeline.exceptions import ConfigError, DemoError

ComplexArray = NDArray[np.complex128]
TWO_PI = 2.0 * math.pi
_FORCING_SAMPLES = 2048  # Fewest forcing samples per period behind the limit cycle's spectrum.
_MIN_SIZE_M = 1e-9  # A demo whose bounding box is smaller than this does not move.


@dataclass(frozen=True)
class DmpConfig:
    """Settings of the periodic DMP and of how a demo's period is found."""

    n_basis: int = 400
    """N_b, von Mises basis functions. The weights are locally weighted averages (LWR), so the
    reproduction is the demo blurred by about one basis width: with 120 (the paper's range is
    silent; 100-150 was first chosen) the best demo's reproduction lay 0.6-0.8 mm from the true
    figure-eight against its own 0.2-0.3 mm, with 400 within 0.1 mm of the demo's averaged loop
    (docs/refinement.md)."""
    width_factor: float = 2.5
    """Basis width h = width_factor · N_b."""
    alpha_z: float = 25.0
    """α_z, gain of the transformation system."""
    beta_z: float = 6.25
    """β_z; α_z / 4 makes the linear part critically damped."""
    one_loop_gap: float = 0.1
    """A demo whose end lies within this fraction of its size from its start is one loop."""
    max_open_gap: float = 0.5
    """Largest closure gap (fraction of size) still fitted as one incomplete loop."""
    min_cycles: float = 1.25
    """Fewest cycles the spectrum must show for a demo that does not close to count as repeating."""

    def __post_init__(self) -> None:
        if self.n_basis < 4:
            raise ConfigError(f"n_basis must be at least 4; got {self.n_basis}")
        for name in ("width_factor", "alpha_z", "beta_z", "one_loop_gap", "max_open_gap"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"{name} must be a positive number; got {value}")
        if self.max_open_gap < self.one_loop_gap:
            raise ConfigError(
                f"max_open_gap ({self.max_open_gap}) must be at least one_loop_gap "
                f"({self.one_loop_gap})"
            )
        if not self.min_cycles > 1.0:
            raise ConfigError(f"min_cycles must be above 1; got {self.min_cycles}")


@dataclass(frozen=True, eq=False)
class PeriodicDmp:
    """A fitted 2-D rhythmic DMP: one shared phase, one transformation system per axis."""

    weights: FloatArray
    """Forcing weights w_i per axis, shape (N_b, 2)."""
    anchor: FloatArray
    """Anchor g, the centre of the loop, shape (2,), in [m]."""
    tau: float
    """τ = T / (2π), in normalised time per radian."""
    centres: FloatArray
    """Basis centres c_i, evenly spaced on [0, 2π), shape (N_b,), in [rad]."""
    h: float
    """Basis width h."""
    alpha_z: float = 25.0
    """α_z."""
    beta_z: float = 6.25
    """β_z."""

    def __post_init__(self) -> None:
        weights = np.array(self.weights, dtype=np.float64)
        anchor = np.array(self.anchor, dtype=np.float64)
        centres = np.array(self.centres, dtype=np.float64)
        if weights.ndim != 2 or weights.shape[1] != 2 or centres.shape != (weights.shape[0],):
            raise ConfigError(
                f"weights must have shape (N_b, 2) and centres (N_b,); got {weights.shape} and "
                f"{centres.shape}"
            )
        if anchor.shape != (2,):
            raise ConfigError(f"anchor must have shape (2,); got {anchor.shape}")
        if not (self.tau > 0 and self.h > 0 and self.alpha_z > 0 and self.beta_z > 0):
            raise ConfigError("tau, h, alpha_z and beta_z must be positive")
        for name, array in (("weights", weights), ("anchor", anchor), ("centres", centres)):
            array.setflags(write=False)
            object.__setattr__(self, name, array)

    @property
    def period(self) -> float:
        """T = 2πτ, in normalised time."""
        return TWO_PI * self.tau

    def forcing(self, phase: ArrayLike) -> FloatArray:
        """f(φ) = Σ ψ_i(φ) w_i / Σ ψ_i(φ) (r = 1).

        Args:
            phase: Phases φ, any shape (...), in [rad].

        Returns:
            Forcing term per axis, shape (..., 2).
        """
        psi = _basis(np.asarray(phase, dtype=np.float64), self.centres, self.h)
        return (psi @ self.weights) / psi.sum(axis=-1, keepdims=True)

    def limit_cycle(
        self, samples_per_period: int, phase0: float = 0.0
    ) -> tuple[FloatArray, FloatArray]:
        """The periodic steady state at phases φ0 + 2πk / samples_per_period.

        Returns:
            Positions y, shape (samples_per_period, 2), in [m], and the scaled velocities z = τẏ,
            shape (samples_per_period, 2), in [m/rad].
        """
        e, z = self._steady_state(phase0, samples_per_period)
        return self.anchor + e, z

    def phase_of(self, point: ArrayLike, resolution: int = 4096) -> float:
        """Phase [rad] of the limit-cycle point nearest to `point` (shape (2,), [m])."""
        cycle, _ = self.limit_cycle(resolution)
        k = int(np.argmin(np.sum((cycle - np.asarray(point, dtype=np.float64)) ** 2, axis=1)))
        return TWO_PI * k / resolution

    def rollout(
        self,
        y0: ArrayLike,
        z0: ArrayLike | None = None,
        *,
        n_periods: int = 3,
        samples_per_period: int = 300,
        phase0: float = 0.0,
    ) -> FloatArray:
        """Roll the DMP out exactly from one or many initial states at once.

        The state at elapsed phase s is x_ss(φ0 + s) + exp(A s) (x0 − x_ss(φ0)): the limit cycle
        plus the decaying response of the linear part A = [[0, 1], [−α_z β_z, −α_z]].

        Args:
            y0: Initial positions, shape (..., 2), in [m].
            z0: Initial scaled velocities z = τẏ, shape (..., 2), in [m/rad]; None starts with the
                limit cycle's z at phase0 (only the position is perturbed).
            n_periods: Periods to roll out.
            samples_per_period: Output samples per period.
            phase0: Phase at the start [rad].

        Returns:
            Positions at phases φ0 + 2πk / samples_per_period, k = 0 .. n_periods ·
            samples_per_period − 1, shape (..., n_periods · samples_per_period, 2), in [m].
        """
        if n_periods < 1 or samples_per_period < 1:
            raise ConfigError(
                f"n_periods and samples_per_period must be at least 1; got {n_periods} and "
                f"{samples_per_period}"
            )
        e_cycle, z_cycle = self._steady_state(phase0, samples_per_period)
        e0 = np.asarray(y0, dtype=np.float64) - self.anchor
        if e0.shape[-1:] != (2,):
            raise ConfigError(f"y0 must have shape (..., 2); got {e0.shape}")
        z0_arr = (
            np.broadcast_to(z_cycle[0], e0.shape)
            if z0 is None
            else np.broadcast_to(np.asarray(z0, dtype=np.float64), e0.shape)
        )
        n_samples = n_periods * samples_per_period
        s = TWO_PI * np.arange(n_samples) / samples_per_period
        phi = _expm_linear_part(self.alpha_z, self.beta_z, s)  # (K, 2, 2)
        # Position part of exp(A s) applied to the departure from the limit cycle, per axis.
        de, dz = (e0 - e_cycle[0])[..., None, :], (z0_arr - z_cycle[0])[..., None, :]
        transient = phi[:, 0, :1] * de + phi[:, 0, 1:] * dz  # (..., K, 2)
        return self.anchor + np.tile(e_cycle, (n_periods, 1)) + transient

    @cached_property
    def _cycle_spectrum(self) -> tuple[ComplexArray, ComplexArray]:
        """Fourier coefficients c_n, n = 0 .. M/2 − 1, of the limit cycle's e = y − g and z.

        f is sampled at M ≥ 2048 phases per period (it is smooth, so its spectrum decays fast);
        the Nyquist bin is dropped.
        """
        f = self._forcing_on_grid()
        m = f.shape[0]
        spectrum = np.fft.rfft(f, axis=0)[:-1] / m
        harmonic = np.arange(spectrum.shape[0])[:, None]
        # Mode e^{inφ}: (α_z β_z − n² + i α_z n) E_n = F_n and Z_n = i n E_n.
        e_spec = spectrum / (
            self.alpha_z * self.beta_z - harmonic**2 + 1j * self.alpha_z * harmonic
        )
        return e_spec, 1j * harmonic * e_spec

    def _forcing_on_grid(self) -> FloatArray:
        """f at M (even, ≥ 2048) phases 2πj/M, shape (M, 2).

        With the usual centres c_i = 2πi/N_b and M a multiple of N_b, the numerator and the
        denominator of f are circular convolutions of the von Mises kernel with the weights (and
        with ones) placed every M/N_b samples, done by FFT.
        """
        n_basis = self.centres.size
        per_basis = 2 * math.ceil(_FORCING_SAMPLES / (2 * n_basis))
        m = n_basis * per_basis
        if not np.allclose(self.centres, TWO_PI * np.arange(n_basis) / n_basis, atol=1e-12):
            return self.forcing(TWO_PI * np.arange(m) / m)
        kernel = np.fft.rfft(np.exp(self.h * (np.cos(TWO_PI * np.arange(m) / m) - 1.0)))
        combs = np.zeros((m, 3))
        combs[::per_basis, :2] = self.weights
        combs[::per_basis, 2] = 1.0
        conv = np.fft.irfft(kernel[:, None] * np.fft.rfft(combs, axis=0), m, axis=0)
        return conv[:, :2] / conv[:, 2:]

    def _steady_state(self, phase0: float, n: int) -> tuple[FloatArray, FloatArray]:
        """Limit cycle e = y − g and z at phases φ0 + 2πk/n, each shape (n, 2).

        The series Σ_n c_n e^{in(φ0 + 2πk/n)} is folded onto n bins (harmonics equal mod n) and
        summed by one inverse FFT, so it is exact at any n and φ0.
        """
        e_spec, z_spec = self._cycle_spectrum
        harmonic = np.arange(e_spec.shape[0])
        shift = np.exp(1j * harmonic * phase0)[:, None]
        out = []
        for spec in (e_spec, z_spec):
            coeffs = np.concatenate([spec * shift, np.conj(spec[1:] * shift[1:])], axis=0)
            bins = np.concatenate([harmonic, -harmonic[1:]]) % n
            folded = np.stack(
                [
                    np.bincount(bins, weights=np.real(coeffs[:, d]), minlength=n)
                    + 1j * np.bincount(bins, weights=np.imag(coeffs[:, d]), minlength=n)
                    for d in range(2)
                ],
                axis=1,
            )
            out.append(n * np.fft.ifft(folded, axis=0).real)
        return out[0], out[1]


def fit_periodic_dmp(
    positions: ArrayLike,
    period: float | None = None,
    config: DmpConfig | None = None,
    name: str = "demo",
) -> PeriodicDmp:
    """Fit a rhythmic DMP to one demo by locally weighted regression.

    How the period is found (docs/algorithms.md §2.4, §7 row 11), with size the larger side of
    the bounding box and gap the distance from the last sample to the first:

    * gap ≤ one_loop_gap · size: the demo is one loop, T = 1. Its closure gap is spread linearly
      over the demo (x_k − k/(N−1) · gap vector) so the loop closes exactly, the last sample
      (now equal to the first) is dropped and the N − 1 others sit at phases 2πk/(N − 1);
      derivatives are periodic central differences.
    * otherwise the spectrum is read (:func:`estimate_period`): at least min_cycles cycles make
      a repeating demo, fitted with T from the spectrum over all its samples (derivatives by
      np.gradient); the LWR averages the cycles.
    * otherwise, with gap ≤ max_open_gap · size, it is one incomplete loop, fitted as above.
    * otherwise the motion is not periodic (it neither closes nor repeats, e.g. a straight
      stroke) and DemoError is raised. A closed motion along a line (there and back) is periodic
      and is fitted.

    Args:
        positions: Demo positions uniform in normalised time t ∈ [0, 1], shape (N, 2), in [m].
        period: T in normalised time, to skip the rules above (T ≥ 1 fits one loop).
        config: DMP settings; defaults to DmpConfig().
        name: The demo's name, for error messages.

    Raises:
        DemoError: Fewer than 16 samples, non-finite values, no motion, or a non-periodic motion.
    """
    config = config or DmpConfig()
    x = _validated_positions(positions, name)
    n = x.shape[0]
    size = loop_size(x)
    gap = float(np.linalg.norm(x[-1] - x[0]))
    if period is None:
        if gap <= config.one_loop_gap * size:
            period = 1.0
        else:
            period = estimate_period(x, name)
            if 1.0 / period < config.min_cycles:
                if gap > config.max_open_gap * size:
                    raise DemoError(
                        f"{name} is not periodic: it ends {gap:.3g} m from its start "
                        f"({gap / size:.0%} of its size {size:.3g} m) and repeats "
                        f"{1.0 / period:.2f} times; a periodic demo closes (gap ≤ "
                        f"{config.max_open_gap:.0%} of its size) or repeats (≥ "
                        f"{config.min_cycles} cycles)"
                    )
                period = 1.0
    elif not (math.isfinite(period) and period > 0):
        raise ConfigError(f"period must be a positive number; got {period}")
    if period >= 1.0:
        closed = x - np.linspace(0.0, 1.0, n)[:, None] * (x[-1] - x[0])
        y = closed[:-1]
        d_phi = TWO_PI / (n - 1)
        phases = d_phi * np.arange(n - 1)
        dy = (np.roll(y, -1, axis=0) - np.roll(y, 1, axis=0)) / (2 * d_phi)
        ddy = (np.roll(y, -1, axis=0) - 2 * y + np.roll(y, 1, axis=0)) / d_phi**2
        anchor = y.mean(axis=0)
        tau = 1.0 / TWO_PI
    else:
        y = x
        d_phi = TWO_PI / ((n - 1) * period)
        phases = d_phi * np.arange(n)
        dy = np.gradient(y, d_phi, axis=0, edge_order=2)
        ddy = np.gradient(dy, d_phi, axis=0, edge_order=2)
        whole = int(np.floor(1.0 / period + 1e-9)) * period  # Whole periods in the demo.
        anchor = y[: max(2, round(whole * (n - 1)))].mean(axis=0)
        tau = period / TWO_PI
    a, b = config.alpha_z, config.beta_z
    f_target = ddy - a * (b * (anchor - y) - dy)  # In phase units: τ² ÿ = y'' and τ ẏ = y'.
    centres = TWO_PI * np.arange(config.n_basis) / config.n_basis
    h = config.width_factor * config.n_basis
    psi = _basis(phases, centres, h)  # (K, N_b)
    weights = (psi.T @ f_target) / (psi.sum(axis=0)[:, None] + 1e-12)
    return PeriodicDmp(weights, anchor, tau, centres, h, alpha_z=a, beta_z=b)


def _validated_positions(positions: ArrayLike, name: str) -> FloatArray:
    x = np.asarray(positions, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 2:
        raise DemoError(f"{name}: positions must have shape (N, 2); got {x.shape}")
    if x.shape[0] < MIN_SAMPLES:
        raise DemoError(f"{name} has {x.shape[0]} samples; at least {MIN_SAMPLES} are needed")
    if not np.all(np.isfinite(x)):
        raise DemoError(f"{name} has NaN or infinite positions")
    if loop_size(x) < _MIN_SIZE_M:
        raise DemoError(
            f"{name} does not move: its bounding box is {loop_size(x):.3g} m across; a periodic "
            f"demo must span at least {_MIN_SIZE_M} m"
        )
    return x


def _basis(phase: FloatArray, centres: FloatArray, h: float) -> FloatArray:
    """Von Mises bases ψ_i(φ) = exp(h (cos(φ − c_i) − 1)), shape phase.shape + (N_b,)."""
    return np.exp(h * (np.cos(phase[..., None] - centres) - 1.0))


def _expm_linear_part(alpha: float, beta: float, s: FloatArray) -> FloatArray:
    """exp(A s) for A = [[0, 1], [−αβ, −α]], shape (K, 2, 2), in closed form.

    With μ = −α/2 and q² = μ² − αβ: exp(A s) = c(s) I + d(s) (A − μI), where
    c = e^{μs} cosh(qs) and d = e^{μs} sinh(qs)/q, both written with the stable exponents μ ± q;
    the critically damped case q = 0 is the limit d → s e^{μs}.
    """
    mu = -0.5 * alpha
    q = np.sqrt(complex(mu * mu - alpha * beta))
    if abs(q) * max(float(s.max(initial=0.0)), 1.0) < 1e-6:
        qs2 = (q * s) ** 2
        decay = np.exp(mu * s)
        c, sc = (decay * (1.0 + 0.5 * qs2)).real, (decay * s * (1.0 + qs2 / 6.0)).real
    else:
        fast, slow = np.exp((mu - q) * s), np.exp((mu + q) * s)
        c, sc = (0.5 * (slow + fast)).real, ((slow - fast) / (2.0 * q)).real
    out = np.empty((s.size, 2, 2))
    out[:, 0, 0] = c - mu * sc
    out[:, 0, 1] = sc
    out[:, 1, 0] = -alpha * beta * sc
    out[:, 1, 1] = c + (-alpha - mu) * sc
    return out
