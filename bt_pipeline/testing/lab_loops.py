"""Loops from curve families written apart from ``bt_pipeline.data.random_loops``.

The cleaner was developed on the random-loop families of ``data/random_loops.py`` (ellipses,
rounded polygons, D shapes, lemniscates, arches, strokes, random Fourier loops), each
re-parametrised to an even speed. A check on those alone would share their assumptions, so these
families are built another way, from closed-form curves at their own natural parameter (the
speed along the loop is then uneven, as a hand slows in a corner or a dimple):

* ``squircle``: a superellipse \\|x\\|^n + \\|y/b\\|^n = 1, n in 2.5-5, aspect b in 0.45-0.85;
* ``limacon``: r = 1 + a cos φ, a in 0.3-0.75 (dimpled beyond 0.5);
* ``lobed``: r = 1 + a cos kφ, k in 3-5 lobes, a in 0.06-0.16;
* ``peanut``: a Cassini oval with a waist, r² = c² cos 2φ + √(c⁴ cos² 2φ + 1 − c⁴), c in
  0.75-0.93;
* ``lissajous``: x = sin φ (1 + e sin φ), y = b sin 2φ, e in 0-0.35 (unequal lobes), b in
  0.25-0.5: a figure-eight that crosses itself once;
* ``kidney``: r = 1 + a cos φ + b cos 2φ + c sin 3φ, small random a, b, c.

Each loop gets a random orientation, direction and start, its larger bounding-box side in
[0.10, 0.22] m (the operators' ρ in 0.65-1.6 scales it), and is stored as a
:class:`~bt_pipeline.data.loop_shape.LoopShape` of :data:`HARMONICS` harmonics, so its points
are the truth exactly. A draw whose smallest radius of curvature is under 3 % of its size, or
that crosses itself (but the lissajous, once), is drawn again.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal, get_args

import numpy as np

from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.data.random_loops import min_radius, self_crossings
from bt_pipeline.exceptions import ConfigError

LabFamily = Literal["squircle", "limacon", "lobed", "peanut", "lissajous", "kidney"]
"""A family of :mod:`lab_loops` (module doc)."""
LAB_FAMILIES: tuple[LabFamily, ...] = get_args(LabFamily)

HARMONICS = 48
"""K of every loop drawn here."""
SIZE_RANGE_M = (0.10, 0.22)
"""Range of the larger bounding-box side of a loop [m]."""

_POINTS = 2048  # Samples at the curve's own parameter the harmonics are fitted to.
_MIN_RADIUS = 0.03  # Smallest radius of curvature, as a share of the size.
_MAX_DRAWS = 300
_STREAM = 0x1AB  # The set's loop is drawn from [seed, this]: apart from the demos' streams.

Curve = Callable[[np.ndarray], np.ndarray]


def _polar(radius: Callable[[np.ndarray], np.ndarray]) -> Curve:
    return lambda phi: radius(phi) * np.exp(1j * phi)


def _squircle(rng: np.random.Generator) -> Curve:
    n, b = rng.uniform(2.5, 5.0), rng.uniform(0.45, 0.85)
    return _polar(lambda p: (np.abs(np.cos(p)) ** n + np.abs(np.sin(p) / b) ** n) ** (-1.0 / n))


def _limacon(rng: np.random.Generator) -> Curve:
    a = rng.uniform(0.3, 0.75)
    return _polar(lambda p: 1.0 + a * np.cos(p))


def _lobed(rng: np.random.Generator) -> Curve:
    k, a = int(rng.integers(3, 6)), rng.uniform(0.06, 0.16)
    return _polar(lambda p: 1.0 + a * np.cos(k * p))


def _peanut(rng: np.random.Generator) -> Curve:
    c4 = rng.uniform(0.75, 0.93) ** 4
    return _polar(
        lambda p: np.sqrt(np.sqrt(c4) * np.cos(2 * p) + np.sqrt(c4 * np.cos(2 * p) ** 2 + 1.0 - c4))
    )


def _lissajous(rng: np.random.Generator) -> Curve:
    e, b = rng.uniform(0.0, 0.35), rng.uniform(0.25, 0.5)
    return lambda p: np.sin(p) * (1.0 + e * np.sin(p)) + 1j * b * np.sin(2 * p)


def _kidney(rng: np.random.Generator) -> Curve:
    a, b, c = rng.uniform(0.1, 0.35), rng.uniform(-0.2, 0.2), rng.uniform(-0.08, 0.08)
    return _polar(lambda p: 1.0 + a * np.cos(p) + b * np.cos(2 * p) + c * np.sin(3 * p))


_BUILDERS: dict[LabFamily, tuple[Callable[[np.random.Generator], Curve], int]] = {
    "squircle": (_squircle, 0),
    "limacon": (_limacon, 0),
    "lobed": (_lobed, 0),
    "peanut": (_peanut, 0),
    "lissajous": (_lissajous, 1),
    "kidney": (_kidney, 0),
}


def lab_loop(family: LabFamily, rng: np.random.Generator) -> LoopShape:
    """A loop of `family` (module doc), turned, sized and started at random.

    Raises:
        ConfigError: Unknown family, or no draw passed the checks.
    """
    if family not in _BUILDERS:
        raise ConfigError(f"unknown lab loop family {family!r}; valid: {', '.join(LAB_FAMILIES)}")
    build, crossings = _BUILDERS[family]
    phi = 2.0 * np.pi * np.arange(_POINTS) / _POINTS
    for _ in range(_MAX_DRAWS):
        z = build(rng)(phi) * np.exp(1j * rng.uniform(0.0, 2.0 * np.pi))
        if rng.random() < 0.5:
            z = np.conj(z)  # Mirrored: the other direction of travel.
        z = np.roll(z, int(rng.integers(_POINTS)))
        low = complex(z.real.min(), z.imag.min())
        high = complex(z.real.max(), z.imag.max())
        size = float(rng.uniform(*SIZE_RANGE_M))
        z = (z - 0.5 * (low + high)) * size / max(high.real - low.real, high.imag - low.imag)
        shape = LoopShape.from_points(np.stack([z.real, z.imag], axis=1), HARMONICS, family)
        if min_radius(shape) >= _MIN_RADIUS * size and self_crossings(shape) == crossings:
            return shape
    raise ConfigError(f"no {family} loop passed the checks in {_MAX_DRAWS} draws")


def lab_set_loop(seed: int) -> LoopShape:
    """The one loop of a set: a family drawn uniformly, then a loop of it, from `seed`'s stream."""
    rng = np.random.default_rng([int(seed), _STREAM])
    return lab_loop(LAB_FAMILIES[int(rng.integers(len(LAB_FAMILIES)))], rng)


__all__ = ["HARMONICS", "LAB_FAMILIES", "LabFamily", "lab_loop", "lab_set_loop"]
