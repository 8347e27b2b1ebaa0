"""Closed-form alignment of closed loops (elliptic Fourier descriptors in complex form).

Two loops z, w (256 complex points uniform in arc length, centred) are compared over every
start shift s and both directions: for each, the best similarity a = ⟨z, w_s⟩ / ⟨w_s, w_s⟩
(rotation and scale at once) leaves a residual |z|² − |⟨z, w_s⟩|² / |w_s|², computed for all
shifts at once by FFT; the distance is the root of the smallest residual over |z|², a share of
the loop's size. Used to learn a task's loop (:mod:`bt_pipeline.clean.loop_learn`) and by the
app's take checks. Also: the turn that frames a set of demos (:func:`majority_turn`) and a
loop's rotational symmetry (:func:`symmetry_order`) and its mirror axis (:func:`mirror_axis`).
"""

from __future__ import annotations

import math

import numpy as np

from bt_pipeline.clean.recurrence import LOOP_POINTS
from bt_pipeline.data.loop_shape import arc_length_resample

_SYMMETRY = 0.03  # A loop with an n-fold symmetry matches itself turned by 360°/n this well.


def align(
    reference: np.ndarray, other: np.ndarray, tie: float = 0.0
) -> tuple[complex, int, bool, float]:
    """Best similarity of `other` onto `reference`, over start shifts and directions (module doc).

    Args:
        reference: z, one loop as complex points, shape (P,), centred.
        other: w, another loop as complex points, shape (P,), centred.
        tie: Alignments within this distance of the best are ties, and the one that turns
            least wins: a nearly symmetric loop (an oval matches itself turned by 180°) keeps
            the turn its neighbours have.

    Returns:
        (a, shift, reversed, distance): ``a * roll(w', shift) ≈ z`` with w' = w or w reversed,
        and the RMS residual over the RMS of z.
    """
    zz = float(np.vdot(reference, reference).real)
    found = []
    for flipped, ww, corr in _correlations(reference, other):
        if ww <= 0.0 or zz <= 0.0:
            continue
        distance = np.sqrt(np.maximum(zz - np.abs(corr) ** 2 / ww, 0.0) / zz)
        found.append((corr / ww, distance, flipped))
    if not found:
        return 1.0 + 0j, 0, False, math.inf
    low = min(float(d.min()) for _, d, _ in found)
    best = (1.0 + 0j, 0, False, math.inf, math.inf)
    for a, distance, flipped in found:
        # Ties are distinct alignments (local minima over start shifts): the shifts next to
        # one also lie within the tie, and on a roundish loop a shift is nearly a turn, so
        # taking the least turn among them slid the turn toward 0 (a D shape's expert-like
        # demo aligned 8° off, at 6 x the distance of its best alignment).
        local = (distance <= np.roll(distance, 1)) & (distance <= np.roll(distance, -1))
        for s in np.flatnonzero(local & (distance <= low + tie)):
            turn = abs(float(np.angle(a[s])))
            key = turn if tie > 0.0 else float(distance[s])
            if key < best[4]:
                best = (complex(a[s]), int(s), flipped, float(distance[s]), key)
    return best[:4]


def apply_alignment(other: np.ndarray, a: complex, shift: int, flipped: bool) -> np.ndarray:
    w = other[::-1] if flipped else other
    return a * np.roll(w, shift)


def centred_complex(points: np.ndarray) -> np.ndarray:
    z = points[:, 0] + 1j * points[:, 1]
    return z - z.mean()


def arc_points(points: np.ndarray) -> np.ndarray:
    """A closed loop (P, 2), endpoint excluded, resampled to 256 points uniform in arc length
    (endpoint excluded), as :func:`~bt_pipeline.clean.recurrence.own_loop` gives a demo's."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    return arc_length_resample(np.concatenate([p, p[:1]]), LOOP_POINTS + 1)[:-1]


def loop_signature(points: np.ndarray) -> np.ndarray:
    """A closed loop (P, 2) as :func:`align` compares loops: 256 complex points uniform in arc
    length, centred on their mean."""
    return centred_complex(arc_points(points))


def circular_mean(degrees: np.ndarray) -> float:
    angle = np.radians(degrees)
    return math.degrees(math.atan2(float(np.mean(np.sin(angle))), float(np.mean(np.cos(angle)))))


def _wrap(degrees: np.ndarray) -> np.ndarray:
    return (degrees + 180.0) % 360.0 - 180.0


def majority_turn(thetas: np.ndarray) -> float:
    """The circular mean of the turns, each taken as itself or its 180° twin, whichever lies on
    the side most of them lie: a loop nearly the same turned by 180° (an eight with its
    direction reversed, an oval) aligns some demos at their twin, and a plain mean of both
    sides lands 90° off."""
    base = circular_mean(2.0 * thetas) / 2.0
    near = np.abs(_wrap(thetas - base)) <= 90.0
    ref = base if 2 * int(near.sum()) >= thetas.size else base + 180.0
    folded = np.where(np.abs(_wrap(thetas - ref)) <= 90.0, thetas, thetas - 180.0)
    return circular_mean(folded)


def symmetry_order(z: np.ndarray) -> int:
    """The largest n ≤ 6 such that the loop matches itself turned by 360°/n (1: none)."""
    zz = float(np.vdot(z, z).real)
    fz = np.fft.fft(z)
    corr = np.fft.ifft(fz * np.conj(fz))  # corr[s] = Σ_j z_j conj(z_{j+s})
    for n in (6, 5, 4, 3, 2):
        turn = np.exp(2j * math.pi / n)
        residual = 2.0 * zz - 2.0 * np.real(np.conj(turn) * corr)
        if math.sqrt(max(float(residual.min()), 0.0) / max(zz, 1e-30)) <= _SYMMETRY:
            return n
    return 1


def mirror_axis(z: np.ndarray) -> tuple[float, float]:
    """The loop's mirror axis through its centroid nearest the vertical (L1's axis, Eq. 4).

    The loop mirrored about the vertical axis, w = −conj(z), is aligned to z over start shifts
    and directions; the turn a ≈ e^{2iβ} that maps it back says the axis lies β from the
    vertical. Of the alignments that are local minima over the start shift and lie within 0.03
    of the best (an oval has two axes, at right angles), the axis nearest the vertical wins, as
    on the guides: L1 about it still sees a side drawn bigger than the other.

    Args:
        z: One loop as complex points, shape (P,), centred (:func:`loop_signature`).

    Returns:
        (β [deg] counter-clockwise from the vertical, in (−90, 90]; the RMS distance of the
        loop from its mirror image about that axis, over its RMS: 0 for a mirror-symmetric loop).
    """
    zz = float(np.vdot(z, z).real)
    candidates: list[tuple[float, complex]] = []
    for _, ww, corr in _correlations(z, -np.conj(z)):
        if ww <= 0.0 or zz <= 0.0:
            continue
        d = np.sqrt(np.maximum(zz - np.abs(corr) ** 2 / ww, 0.0) / zz)
        minima = (d <= np.roll(d, 1)) & (d <= np.roll(d, -1))
        candidates += [(float(d[s]), complex(corr[s] / ww)) for s in np.flatnonzero(minima)]
    if not candidates:
        return 0.0, math.inf
    low = min(d for d, _ in candidates)
    near = [(abs(float(np.angle(a))), d, a) for d, a in candidates if d <= low + _SYMMETRY]
    _, distance, a = min(near, key=lambda c: c[0])
    return math.degrees(float(np.angle(a))) / 2.0, distance


def stated_distance(reference: np.ndarray, other: np.ndarray) -> float:
    """RMS distance of `other` from `reference` over start shifts and directions alone (no
    rotation or scale: `other` is already in the frame its demo states), over the RMS of
    `reference` (both centred complex loops of P points, as :func:`align` takes)."""
    zz = float(np.vdot(reference, reference).real)
    if zz <= 0.0:
        return math.inf
    low = min(
        float(np.min(zz + ww - 2.0 * np.real(corr)))
        for _, ww, corr in _correlations(reference, other)
    )
    return math.sqrt(max(low, 0.0) / zz)


def _correlations(reference: np.ndarray, other: np.ndarray) -> list[tuple[bool, float, np.ndarray]]:
    """For `other` as given and reversed: (reversed, |w|², corr) with corr[s] = Σ_j z_{j+s}
    conj(w_j) for every start shift s at once (FFT), so z ≈ a roll(w, s)."""
    fz = np.fft.fft(reference)
    out = []
    for flipped in (False, True):
        w = other[::-1] if flipped else other
        corr = np.fft.ifft(fz * np.conj(np.fft.fft(w)))
        out.append((flipped, float(np.vdot(w, w).real), corr))
    return out


__all__ = [
    "align",
    "apply_alignment",
    "arc_points",
    "centred_complex",
    "circular_mean",
    "loop_signature",
    "majority_turn",
    "mirror_axis",
    "stated_distance",
    "symmetry_order",
]
