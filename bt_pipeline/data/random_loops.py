"""Intended loops drawn at random: shapes bt was not built around (``bt synth --shape``).

The synthetic generators draw the task's guide unless given another loop. These are drawn as a
:class:`~bt_pipeline.data.loop_shape.LoopShape` centred on its bounding-box centre, the larger
side of the box drawn in [0.15, 0.30] m, labelled with its family (parameters drawn per loop):

* ``oval``: an ellipse of aspect 0.25-1; half of them eggs (width skewed 15-35 % to one end);
* ``rounded_polygon``: a rounded triangle, square or pentagon, squashed to aspect 0.75-1;
* ``d_shape``: a disc cut flat at 0-50 % of its radius from the centre, aspect 0.6-1;
* ``figure_eight``: a lemniscate with unequal lobes (one 0.6-0.9× the other), aspect 0.3-0.8;
  the only family that crosses itself (once);
* ``arch``: like pick_and_place's, an outbound arch over the top and a shallower return, with
  height and return depth drawn; kept upright and travelled as the guide is;
* ``stroke``: a thin back-and-forth stroke, an ellipse of aspect 0.04-0.12;
* ``asymmetric``: random Fourier (:func:`random_loop`).

All but the arch get a random orientation and direction. Every loop is re-parametrised to a
speed along it close to even (the generators' speed profiles do the timing) and stored with
:data:`HARMONICS` harmonics. A loop is redrawn until its smallest radius of curvature is at
least :data:`MIN_RADIUS_FRACTION` of its size (ovals: 3 %, an ellipse's ends being aspect²/2 of
it; strokes: as thin as drawn) and, but for the figure-eight, it does not cross itself.
:func:`varied_guide` draws bt's own guides as a lab would vary them; :func:`draw_loop`
dispatches on a :data:`LoopKind`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal, get_args

import numpy as np

from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.shapes import SHAPE_SIZE
from bt_pipeline.data.tasks import TASKS
from bt_pipeline.exceptions import ConfigError, UnknownTaskError

LoopFamily = Literal[
    "oval", "rounded_polygon", "d_shape", "figure_eight", "arch", "stroke", "asymmetric"
]
"""A family of random loops (module doc)."""
LoopKind = Literal["guide", "varied", "random", LoopFamily]
"""What a synthetic set draws: the task's guide, a varied guide, a random family or a family."""
LOOP_FAMILIES: tuple[LoopFamily, ...] = get_args(LoopFamily)
LOOP_KINDS: tuple[LoopKind, ...] = get_args(LoopKind)

SIZE_RANGE_M = (0.15, 0.30)
"""Range of the larger bounding-box side of a random loop [m]."""
MIN_RADIUS_FRACTION = 0.04
"""Smallest radius of curvature of a random loop, as a fraction of its size."""
HARMONICS = 32
"""K of every loop drawn here (2K + 1 coefficients)."""
CHECK_POINTS = 400
"""Points the self-intersection check reads a loop on."""

_DENSE = 4096  # Samples of a family's base curve, for its speed.
_WARP_HARMONICS = 6  # The phase warp that evens the speed is this smooth.
_WARP_CLIP = (0.6, 2.5)  # Relative speeds the warp evens out: beyond, it only goes part way.
_FIT_POINTS = 1024  # Points at even phase the stored harmonics are fitted to.
_CURVATURE_POINTS = 2048
_BOX_POINTS = 1024  # As LoopShape.size_m and .centre read it.
_MAX_DRAWS = 500
_SET_STREAM = 0x5EED  # The set's loop is drawn from [seed, this], apart from its demos' streams.

Curve = Callable[[FloatArray], np.ndarray]
"""A base curve: phases t [rad], shape (n,), to complex positions x + iy, shape (n,)."""


def random_loop(rng: np.random.Generator) -> LoopShape:
    """A smooth closed loop from random Fourier coefficients (the ``asymmetric`` family).

    A unit circle (harmonic 1) plus harmonics ±2..±K (K in 2-5) of amplitude 0.25-0.6 × U(0.2,
    1) / k^p (p in 1.2-2.5) at random phases; one axis squashed by 0.3-1 (the aspect), a random
    orientation and direction. Redrawn until it does not cross itself and its smallest radius
    of curvature is at least :data:`MIN_RADIUS_FRACTION` of its size.
    """
    return _drawn("asymmetric", rng, _asymmetric, turn=True, crossings=0)


def family_loop(family: LoopFamily, rng: np.random.Generator) -> LoopShape:
    """A loop of `family` (module doc), drawn from `rng`."""
    if family not in LOOP_FAMILIES:
        raise ConfigError(f"unknown loop family {family!r}; valid: {', '.join(LOOP_FAMILIES)}")
    if family == "asymmetric":
        return random_loop(rng)
    build, radius_fraction = _FAMILIES[family]
    return _drawn(
        family,
        rng,
        build,
        turn=family != "arch",
        crossings=1 if family == "figure_eight" else 0,
        radius_fraction=radius_fraction,
    )


def varied_guide(task: str, rng: np.random.Generator) -> LoopShape:
    """bt's guide of `task` as a lab would draw it, re-parametrised to even speed.

    * wiping: the rounded rectangle's aspect ×0.7-1.3 (its width kept) and a squareness in
      0-0.11 (the guide's is 0.1; 0 is an ellipse, above 1/9 the sides cave in);
    * pick_and_place: the arch's height above the places and the return's depth below them
      each ×0.6-1.4 (the width kept; the return still bottoms out flat midway);
    * weaving: one lobe 0.7-1.3× the other and the whole ×0.75-1.25.

    Raises:
        UnknownTaskError: `task` is not one of the three tasks with a guide.
    """
    if task not in TASKS:
        raise UnknownTaskError(f"no guide to vary for task {task!r}; valid: {', '.join(TASKS)}")
    half_w, half_h = (s / 2.0 for s in SHAPE_SIZE[task])
    if task == "wiping":
        aspect, square = float(rng.uniform(0.7, 1.3)), float(rng.uniform(0.0, 0.11))

        def wiping(t: FloatArray) -> np.ndarray:
            x = half_w * (np.cos(t) - square * np.cos(3 * t))
            y = aspect * half_h * (np.sin(t) + square * np.sin(3 * t))
            return (x + 1j * y) / (1.0 - square)

        curve: Curve = wiping

    elif task == "pick_and_place":
        # The guide's y = a s + b s² (s = sin φ) is 3/4 of its height above the places and 1/4
        # below, with a flat bottom midway on the return: _arch keeps that with a cubic term.
        height = 1.5 * half_h * float(rng.uniform(0.6, 1.4))
        depth = 0.5 * half_h * float(rng.uniform(0.6, 1.4))
        curve = _arch(half_w, height, depth)
    else:
        ratio, scale = float(rng.uniform(0.7, 1.3)), float(rng.uniform(0.75, 1.25))
        curve = _eight(scale * half_w, scale * half_h, ratio)
    shape = _even_speed(curve, f"varied {task} guide")
    centre = _bounding_box(shape)[1]
    return shape.transformed(translation=(-centre.real, -centre.imag))


def draw_loop(kind: LoopKind, rng: np.random.Generator, task: str | None = None) -> LoopShape:
    """The loop a synthetic set draws, by kind.

    Args:
        kind: ``"guide"`` (the task's guide as the app draws it), ``"varied"``
            (:func:`varied_guide`), ``"random"`` (a family drawn uniformly, then a loop of it)
            or a family name (:data:`LoopFamily`).
        rng: The generator the loop is drawn from.
        task: The task; needed by ``"guide"`` and ``"varied"``.

    Raises:
        ConfigError: Unknown kind.
        UnknownTaskError: ``"guide"`` or ``"varied"`` without one of the three tasks.
    """
    if kind in ("guide", "varied"):
        if task not in TASKS:
            raise UnknownTaskError(
                f"shape {kind!r} needs a task with a guide ({', '.join(TASKS)}); got {task!r}"
            )
        return LoopShape.guide(task) if kind == "guide" else varied_guide(task, rng)
    if kind == "random":
        return family_loop(LOOP_FAMILIES[int(rng.integers(len(LOOP_FAMILIES)))], rng)
    if kind not in LOOP_FAMILIES:
        raise ConfigError(f"unknown loop kind {kind!r}; valid: {', '.join(LOOP_KINDS)}")
    return family_loop(kind, rng)


def draw_set_loop(kind: LoopKind, seed: int, task: str | None = None) -> LoopShape:
    """The one intended loop of a synthetic set: :func:`draw_loop` from a stream of `seed`'s
    own, apart from the streams the set's demos are drawn from."""
    return draw_loop(kind, np.random.default_rng([int(seed), _SET_STREAM]), task)


def min_radius(shape: LoopShape, n: int = _CURVATURE_POINTS) -> float:
    """The smallest radius of curvature of `shape` over `n` even phases [m] (0 at a cusp)."""
    k = np.arange(-shape.harmonics, shape.harmonics + 1)
    velocity = _evaluate(1j * k * shape.coefficients, n)
    acceleration = _evaluate(-(k**2) * shape.coefficients, n)
    turn = np.abs(np.imag(np.conj(velocity) * acceleration))
    return float(np.min(np.abs(velocity) ** 3 / np.maximum(turn, 1e-300)))


def self_crossings(shape: LoopShape, n: int = CHECK_POINTS) -> int:
    """How many pairs of the `n` segments of `shape`, read at even phase, cross each other."""
    z = _evaluate(shape.coefficients, n)
    d = np.roll(z, -1) - z  # segment i runs from z[i] to z[i] + d[i]

    def side(q: np.ndarray) -> np.ndarray:
        # Sign of d_i × (q_j − z_i): which side of segment i's line point j lies on.
        return np.sign(np.imag(np.conj(d)[:, None] * (q[None, :] - z[:, None])))

    straddles = side(z) * side(np.roll(z, -1)) < 0  # segment i's line separates j's ends
    crossing = straddles & straddles.T
    return int(np.count_nonzero(np.triu(crossing, 1)))  # Neighbours share an end: never counted.


def _evaluate(coefficients: np.ndarray, n: int) -> np.ndarray:
    """Σ_k c_k e^{ikφ} at φ = 2πj/n, j = 0..n−1 (complex, shape (n,)), by one inverse FFT."""
    harmonics = (coefficients.size - 1) // 2
    spectrum = np.zeros(n, dtype=np.complex128)
    np.add.at(spectrum, np.arange(-harmonics, harmonics + 1) % n, coefficients)
    return np.fft.ifft(spectrum) * n


def _bounding_box(shape: LoopShape) -> tuple[float, complex]:
    """The larger side [m] and the centre (x + iy) of `shape`'s bounding box."""
    z = _evaluate(shape.coefficients, _BOX_POINTS)
    x, y = np.real(z), np.imag(z)
    low, high = complex(x.min(), y.min()), complex(x.max(), y.max())
    return max(high.real - low.real, high.imag - low.imag), 0.5 * (low + high)


def _drawn(
    family: LoopFamily,
    rng: np.random.Generator,
    build: Callable[[np.random.Generator], Curve],
    *,
    turn: bool,
    crossings: int,
    radius_fraction: float = MIN_RADIUS_FRACTION,
) -> LoopShape:
    """A loop of `build`, evened, turned and scaled; redrawn until it passes the checks."""
    for _ in range(_MAX_DRAWS):
        shape = _even_speed(build(rng), family)
        if turn:
            shape = shape.transformed(theta_deg=float(rng.uniform(0.0, 360.0)))
            if rng.random() < 0.5:
                shape = shape.reversed()
        size = float(rng.uniform(*SIZE_RANGE_M))
        side, centre = _bounding_box(shape)
        scale = size / side
        shape = shape.transformed(
            rho=scale, translation=(-scale * centre.real, -scale * centre.imag)
        )
        if min_radius(shape) >= radius_fraction * size and self_crossings(shape) == crossings:
            return shape
    raise ConfigError(f"no {family} loop passed the checks in {_MAX_DRAWS} draws")


def _even_speed(curve: Curve, label: str) -> LoopShape:
    """`curve` re-parametrised so its speed is close to even, as :data:`HARMONICS` harmonics.

    The new phase ψ(t) grows like the arc length, the relative speed clipped to
    :data:`_WARP_CLIP` and low-passed to :data:`_WARP_HARMONICS` harmonics, so the warp stays
    smooth (a thin stroke's turns are then still slower than its sides).
    """
    t = 2.0 * np.pi * np.arange(_DENSE) / _DENSE
    z = curve(t)
    k = np.fft.fftfreq(_DENSE, 1.0 / _DENSE)
    speed = np.abs(np.fft.ifft(np.fft.fft(z) * 1j * k))
    relative = np.clip(speed / speed.mean(), *_WARP_CLIP)
    spectrum = np.fft.rfft(relative)
    spectrum[_WARP_HARMONICS + 1 :] = 0.0
    relative = np.maximum(np.fft.irfft(spectrum, _DENSE), 0.05)
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (relative + np.roll(relative, -1)))])
    psi *= 2.0 * np.pi / psi[-1]
    even = 2.0 * np.pi * np.arange(_FIT_POINTS) / _FIT_POINTS
    t_even = np.interp(even, psi, np.append(t, 2.0 * np.pi))
    z_even = curve(t_even)
    return LoopShape.from_points(
        np.stack([np.real(z_even), np.imag(z_even)], axis=1), HARMONICS, label
    )


# The families' base curves (arbitrary size and orientation; _drawn scales and turns them).


def _asymmetric(rng: np.random.Generator) -> Curve:
    top = int(rng.integers(2, 6))
    decay = float(rng.uniform(1.2, 2.5))
    strength = float(rng.uniform(0.25, 0.6))
    harmonics = [k for k in range(-top, top + 1) if abs(k) > 1]  # the squash sets the aspect
    coefficients = {
        k: strength * rng.uniform(0.2, 1.0) / abs(k) ** decay * np.exp(2j * np.pi * rng.random())
        for k in harmonics
    }
    squash = float(rng.uniform(0.3, 1.0))

    def curve(t: FloatArray) -> np.ndarray:
        z = np.exp(1j * t) + sum(c * np.exp(1j * k * t) for k, c in coefficients.items())
        return np.real(z) + 1j * squash * np.imag(z)

    return curve


def _oval(rng: np.random.Generator) -> Curve:
    aspect = float(rng.uniform(0.25, 1.0))
    egg = float(rng.uniform(0.15, 0.35)) if rng.random() < 0.5 else 0.0
    return lambda t: np.cos(t) + 1j * aspect * np.sin(t) * (1.0 + egg * np.cos(t))


def _rounded_polygon(rng: np.random.Generator) -> Curve:
    m = int(rng.integers(3, 6)) - 1  # corners - 1: a hypotrochoid e^{it} + a e^{-imt}
    roundness = float(rng.uniform(0.3, 0.85)) / m**2  # below 1/m² the sides stay convex
    squash = float(rng.uniform(0.75, 1.0))

    def curve(t: FloatArray) -> np.ndarray:
        z = np.exp(1j * t) + roundness * np.exp(-1j * m * t)
        return np.real(z) + 1j * squash * np.imag(z)

    return curve


def _d_shape(rng: np.random.Generator) -> Curve:
    cut = float(rng.uniform(0.0, 0.5))  # The flat side at x = -cut of a unit circle ...
    soft = 0.12  # ... joined to the arc by a softplus corner of this width.
    squash = float(rng.uniform(0.6, 1.0))

    def curve(t: FloatArray) -> np.ndarray:
        x = -cut + soft * np.logaddexp(0.0, (np.cos(t) + cut) / soft)
        return x + 1j * squash * np.sin(t)

    return curve


def _figure_eight(rng: np.random.Generator) -> Curve:
    return _eight(1.0, float(rng.uniform(0.3, 0.8)), float(rng.uniform(0.6, 0.9)))


def _arch_family(rng: np.random.Generator) -> Curve:
    height = float(rng.uniform(0.45, 1.1))
    return _arch(1.0, height, height * float(rng.uniform(1.0 / 7.0, 0.7)))


def _stroke(rng: np.random.Generator) -> Curve:
    aspect = float(rng.uniform(0.04, 0.12))
    return lambda t: np.cos(t) + 1j * aspect * np.sin(t)


def _eight(half_w: float, half_h: float, ratio: float) -> Curve:
    """A lemniscate of Gerono, its x > 0 lobe `ratio` times as large as the other."""
    e = (ratio - 1.0) / (ratio + 1.0)
    return lambda t: (1.0 + e * np.sin(t)) * (half_w * np.sin(t) + 1j * half_h * np.sin(2 * t))


def _arch(half_w: float, height: float, depth: float) -> Curve:
    """pick_and_place's closed arch: `height` above the places, `depth` below on the return.

    y = a s + b s² + c s³ (s = sin φ) with y(1) = height, y(−1) = −depth and y'(−1) = 0 (the
    return bottoms out flat midway, as the guide's does); c = 0 is the guide's own form.
    Monotone in s for height/depth in [1, 7].
    """
    b = 0.5 * (height - depth)
    c = 0.25 * (height - 3.0 * depth)
    a = 0.5 * (height + depth) - c

    def curve(t: FloatArray) -> np.ndarray:
        s = np.sin(t)
        return -half_w * np.cos(t) + 1j * (a * s + b * s * s + c * s**3)

    return curve


_FAMILIES: dict[LoopFamily, tuple[Callable[[np.random.Generator], Curve], float]] = {
    "oval": (_oval, 0.03),  # An ellipse's radius at its ends is aspect² / 2 of its size.
    "rounded_polygon": (_rounded_polygon, MIN_RADIUS_FRACTION),
    "d_shape": (_d_shape, MIN_RADIUS_FRACTION),
    "figure_eight": (_figure_eight, MIN_RADIUS_FRACTION),
    "arch": (_arch_family, MIN_RADIUS_FRACTION),
    "stroke": (_stroke, 0.0),  # As thin as drawn: its turns are sharp by design.
}


__all__ = [
    "HARMONICS",
    "LOOP_FAMILIES",
    "LOOP_KINDS",
    "MIN_RADIUS_FRACTION",
    "SIZE_RANGE_M",
    "LoopFamily",
    "LoopKind",
    "draw_loop",
    "draw_set_loop",
    "family_loop",
    "min_radius",
    "random_loop",
    "self_crossings",
    "varied_guide",
]
