"""Demonstrator preferences and phase alignment (paper Sec. III-B steps 4-6, Eq. 9).

Conventions (docs/algorithms.md §7 rows 13, 14, 19):

* R(θ) rotates counter-clockwise; θ is in degrees. A demonstrator draws ρ R(θ) x^g + c, with
  x^g the global shape (centred at the origin, θ = 0, ρ = 1) and c the centre shared by every
  reference (the centre of the best demo's loop, see bt_pipeline.clean.stage1.extract).
* A reference is a closed loop sampled at t_k = k/(N − 1): reference[N − 1] = reference[0], so
  its N − 1 distinct samples U_0 .. U_{N−2} repeat with period P = N − 1. A demo's start phase
  and direction are arbitrary: it is matched to the reference shifted by s samples, forward
  (aligned[k] = U[(k + s) mod P]) or reversed (aligned[k] = U[(s − k) mod P]), for all N of its
  samples.
* L4 (Eq. 9, per demo) = (1/N) min over s and direction of Σ_k ‖aligned[k] − x(t_k)‖₂. The
  paper's stray (1/M) Σ_i is dropped and the sum over k becomes a mean (§7 row 14).

The similarity fit reads the best pairing for every shift off one circular cross-correlation
(FFT). The phase alignment minimises the exact sum of Euclidean distances: evaluated every 8th
shift and at the best shift by squared distance (from the correlation), then a descent in windows
of ±8 shifts from the best two, per direction. It found the brute-force minimum over all
2 × (N − 1) pairings on all 144 demos of synthetic D1/D2 sets tried (3 tasks × 2 seeds), at about
a third of the brute-force cost; the squared-distance optimum alone missed it on 35 of 120.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import KDTree

from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError, DemoError

ComplexArray = NDArray[np.complex128]
_COARSE_STRIDE = 8  # Phase search: exact cost every 8th shift, then descent in windows of ±8.
_DESCENTS = 2  # Descents per direction, from the best coarse shifts.


class PreferenceEstimate(NamedTuple):
    """A similarity fit x ≈ ρ R(θ) x^g + t of a demo to the global shape."""

    theta_deg: float
    """Rotation θ [deg], counter-clockwise, in (−180, 180]."""
    rho: float
    """Scale ρ."""
    translation: FloatArray
    """Translation t, shape (2,), in [m]: where the demo puts the origin of x^g."""


class PhaseAlignment(NamedTuple):
    """How a closed reference is matched to a demo sample by sample."""

    shift: int
    """s*, in samples of the reference's period N − 1."""
    reversed: bool
    """True when the reference runs the other way round."""
    aligned: FloatArray
    """The reference reordered so aligned[k] is the target of demo[k], shape (N, 2), in [m]."""
    loss: float
    """L4 = mean_k ‖aligned[k] − demo[k]‖₂ [m] (Eq. 9 per demo)."""


def rotation_matrix(theta_deg: float) -> FloatArray:
    """R(θ), counter-clockwise rotation by θ [deg], shape (2, 2)."""
    t = math.radians(theta_deg)
    return np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])


def remove_preference(
    x_d: ArrayLike, theta_deg: float, rho: float, centre: ArrayLike
) -> FloatArray:
    """x^g = R(−θ_best) (x^d − c) / ρ_best: the shape without the best demonstrator's bias.

    Args:
        x_d: Canonical reference x^d, shape (N, 2), in [m].
        theta_deg: θ_best [deg].
        rho: ρ_best (> 0).
        centre: c, shape (2,), in [m].

    Returns:
        x^g, shape (N, 2), in [m], about the origin.
    """
    _check_rho(rho)
    x = np.asarray(x_d, dtype=np.float64) - np.asarray(centre, dtype=np.float64)
    return x @ rotation_matrix(-theta_deg).T / rho


def apply_preference(x_g: ArrayLike, theta_deg: float, rho: float, centre: ArrayLike) -> FloatArray:
    """x^aligned = ρ R(θ) x^g + c: the global shape as demonstrator (θ, ρ) draws it at c.

    Args:
        x_g: Global shape x^g, shape (..., 2), in [m], about the origin.
        theta_deg: θ [deg].
        rho: ρ (> 0).
        centre: c, shape (2,), in [m].

    Returns:
        Transformed points, shape (..., 2), in [m].
    """
    _check_rho(rho)
    x = np.asarray(x_g, dtype=np.float64)
    return rho * x @ rotation_matrix(theta_deg).T + np.asarray(centre, dtype=np.float64)


def estimate_preference(
    positions: ArrayLike,
    shape: ArrayLike,
    allow_reversal: bool = True,
    refine: bool = True,
    max_iterations: int = 50,
) -> PreferenceEstimate:
    """Similarity fit x ≈ ρ R(θ) x^g + t of a demo to the global shape (§7 row 19).

    1. Procrustes over phase: for every circular shift and direction of `shape`, the
       least-squares a = ρ e^{iθ} and t (points as complex numbers) follow from one correlation;
       the pairing with the smallest residual wins. Among pairings that tie to round-off (a
       shape with rotational symmetry) the one with the smallest |θ| is kept.
    2. Refinement (`refine`), an iterative-closest-point similarity fit: each demo sample is
       paired with the nearest point of the shape (densely resampled) under the current fit, and
       a and t are refitted, until the pairs no longer change. Sample-by-sample pairing assumes
       the demo runs once round the loop at even speed; nearest-point pairing does not, so
       incomplete loops, pauses and uneven speed no longer bias ρ and θ.

    On a shape with rotational symmetry (an ellipse) θ is only defined up to that symmetry;
    every such θ gives the same aligned reference.

    Args:
        positions: The demo, shape (N, 2), in [m].
        shape: The global shape x^g, closed, shape (N, 2), in [m].
        allow_reversal: Also try the shape run backwards.
        refine: Run the nearest-point refinement after the phase search.
        max_iterations: Most refinement iterations.

    Returns:
        θ [deg], ρ and the translation [m].
    """
    demo, ref = _check_pair(positions, shape)
    z = demo[:, 0] + 1j * demo[:, 1]
    w = ref[:-1, 0] + 1j * ref[:-1, 1]
    p = w.size
    zc, wc = z[:p] - z[:p].mean(), w - w.mean()
    directions = (False, True) if allow_reversal else (False,)
    corr = np.stack([_correlation(wc, zc, rev) for rev in directions])  # (directions, P)
    # Residual of the best a for each pairing: Σ|zc|² − |corr|² / Σ|wc|². Among pairings that
    # tie to round-off (a symmetric shape), take the one with the smallest |θ| = |arg corr|.
    fit = np.abs(corr) ** 2
    ties = np.flatnonzero(fit.ravel() >= fit.max() * (1 - 1e-9))
    pick = int(ties[np.argmin(np.abs(np.angle(corr.ravel()[ties])))])
    rev, s = directions[pick // p], pick % p
    a, t = _similarity_fit(z, _aligned(w, s, rev, z.size))
    if refine:
        dense = _densify(w, 8)
        tree = KDTree(np.stack([dense.real, dense.imag], axis=1))
        previous = np.empty(0, dtype=np.intp)
        for _ in range(max_iterations):
            u = (z - t) / a  # The demo in the shape's frame.
            _, nearest = tree.query(np.stack([u.real, u.imag], axis=1))
            if np.array_equal(nearest, previous):
                break  # Same pairs, same fit: converged.
            a, t = _similarity_fit(z, dense[nearest])
            previous = nearest
    return PreferenceEstimate(
        theta_deg=math.degrees(math.atan2(a.imag, a.real)),
        rho=abs(a),
        translation=np.array([t.real, t.imag]),
    )


def phase_align(
    reference: ArrayLike, demo: ArrayLike, allow_reversal: bool = True, name: str = "demo"
) -> PhaseAlignment:
    """Match a closed reference to a demo over circular shift and direction (module doc).

    Args:
        reference: x_i^aligned, closed, shape (N, 2), in [m].
        demo: x_i, shape (N, 2), in [m].
        allow_reversal: Also try the reference run backwards.
        name: The demo's label for error messages.

    Returns:
        s*, the direction, the reordered reference and L4 [m].

    Raises:
        DemoError: Non-finite costs (naming the demo); the descent is bounded by P steps.
    """
    x, ref = _check_pair(demo, reference)
    z = x[:, 0] + 1j * x[:, 1]
    w = ref[:-1, 0] + 1j * ref[:-1, 1]
    p, n = w.size, z.size
    # Row s of a sliding window over the loop repeated is w[(s + k) mod P], k = 0 .. N − 1; the
    # reversed pairing w[(s − k) mod P] is row (P − s) mod P of the same over v_j = w[(−j) mod P].
    repeats = n // p + 2
    windows = {
        rev: sliding_window_view(np.tile(np.roll(w[::-1], 1) if rev else w, repeats), n)
        for rev in (False, True)
    }

    def cost(shifts: NDArray[np.intp], rev: bool) -> FloatArray:
        rows = (p - shifts) % p if rev else shifts
        return np.abs(windows[rev][rows] - z).mean(axis=1)

    best: tuple[float, int, bool] = (math.inf, 0, False)
    for rev in (False, True) if allow_reversal else (False,):
        # Σ_k |w_{k+s} − z_k|² over the first P samples = const − 2 Re corr(s).
        by_squares = int(np.argmax(_correlation(w, z[:p], rev).real))
        coarse = np.union1d(np.arange(0, p, _COARSE_STRIDE), [by_squares])
        for start in coarse[np.argsort(cost(coarse, rev))[:_DESCENTS]]:
            s = int(start)
            j, losses = _COARSE_STRIDE, np.full(2 * _COARSE_STRIDE + 1, math.inf)
            # Descend on the exact cost until s is the best of its neighbourhood. Each step
            # lowers the cost strictly, so at most P steps; NaN or flat costs stop at once.
            for _ in range(p + 1):
                window = (s + np.arange(-_COARSE_STRIDE, _COARSE_STRIDE + 1)) % p
                losses = cost(window, rev)
                if not np.all(np.isfinite(losses)):
                    raise DemoError(
                        f"{name}: the phase alignment's cost is not finite (NaN or infinite "
                        "positions, or a degenerate reference)"
                    )
                j = int(np.argmin(losses))
                if j == _COARSE_STRIDE or not losses[j] < losses[_COARSE_STRIDE]:
                    j = _COARSE_STRIDE
                    break
                s = int(window[j])
            if losses[j] < best[0]:
                best = (float(losses[j]), s, rev)
    loss, s, rev = best
    aligned = _aligned(w, s, rev, n)
    return PhaseAlignment(s, rev, np.stack([aligned.real, aligned.imag], axis=1), loss)


def shape_loss(demo: ArrayLike, reference: ArrayLike, allow_reversal: bool = True) -> float:
    """L4 of one demo against its closed reference x_i^aligned, in [m] (Eq. 9, module doc)."""
    return phase_align(reference, demo, allow_reversal).loss


def _correlation(w: ComplexArray, z: ComplexArray, reverse: bool) -> ComplexArray:
    """corr(s) = Σ_k conj(target_k(s)) z_k for every shift s = 0 .. P − 1 (z has P samples).

    target_k(s) = w[(k + s) mod P] forward and w[(s − k) mod P] reversed (see _aligned).
    """
    p = w.size
    if reverse:
        # v_j = w[(−j) mod P], so v[(k + s) mod P] = w[(−s − k) mod P]: shift s of v is −s.
        w = np.roll(w[::-1], 1)
    corr = np.conj(np.fft.ifft(np.fft.fft(w) * np.conj(np.fft.fft(z))))
    return corr[(-np.arange(p)) % p] if reverse else corr


def _similarity_fit(z: ComplexArray, w: ComplexArray) -> tuple[complex, complex]:
    """Least-squares a, t of z ≈ a·w + t over paired samples."""
    zc, wc = z - z.mean(), w - w.mean()
    a = complex(np.vdot(wc, zc) / np.vdot(wc, wc).real)
    return a, complex(z.mean() - a * w.mean())


def _densify(w: ComplexArray, factor: int) -> ComplexArray:
    """The closed polyline through w with `factor` points per segment."""
    step = np.roll(w, -1) - w
    fractions = np.arange(factor) / factor
    return (w[:, None] + fractions * step[:, None]).ravel()


def _aligned(w: ComplexArray, shift: int, reverse: bool, n: int) -> ComplexArray:
    """The N targets: w[(k + s) mod P], or w[(s − k) mod P] when reversed."""
    k = np.arange(n)
    return w[(shift - k) % w.size] if reverse else w[(shift + k) % w.size]


def _check_pair(demo: ArrayLike, reference: ArrayLike) -> tuple[FloatArray, FloatArray]:
    x = np.asarray(demo, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 2 or ref.shape != x.shape or x.shape[0] < 3:
        raise ConfigError(
            f"demo and reference must both have shape (N >= 3, 2); got {x.shape} and {ref.shape}"
        )
    size = float(np.max(np.ptp(ref, axis=0)))
    if np.linalg.norm(ref[-1] - ref[0]) > 1e-9 * max(size, 1.0):
        raise ConfigError(
            "the reference must be a closed loop with reference[-1] == reference[0] (as "
            "canonical_reference returns it)"
        )
    return x, ref


def _check_rho(rho: float) -> None:
    if not (math.isfinite(rho) and rho > 0):
        raise ConfigError(f"scale rho must be a positive number; got {rho}")
