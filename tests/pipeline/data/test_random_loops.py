"""Random intended loops: closed, smooth, bounded curvature, simple (but the figure-eight), varied
in aspect and symmetry, reproducible; varied guides vary the guides by the stated amounts."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from scipy.optimize import minimize_scalar
from scipy.spatial import KDTree

from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.data.random_loops import (
    HARMONICS,
    LOOP_FAMILIES,
    LOOP_KINDS,
    MIN_RADIUS_FRACTION,
    SIZE_RANGE_M,
    draw_loop,
    draw_set_loop,
    family_loop,
    min_radius,
    random_loop,
    self_crossings,
    varied_guide,
)
from bt_pipeline.exceptions import ConfigError, UnknownTaskError

SEEDS = range(6)


def _rng(seed: int) -> np.random.Generator:
    return np.random.default_rng([seed, 2026])


def _points(shape: LoopShape, n: int) -> np.ndarray:
    """shape.points(n) by one inverse FFT (the same sum; shape.at is slow for many points)."""
    spectrum = np.zeros(n, dtype=complex)
    spectrum[np.arange(-shape.harmonics, shape.harmonics + 1) % n] = shape.coefficients
    z = np.fft.ifft(spectrum) * n
    return np.stack([z.real, z.imag], axis=1)


def _size_and_centre(shape: LoopShape) -> tuple[float, np.ndarray]:
    p = _points(shape, 1024)
    return float(np.ptp(p, axis=0).max()), 0.5 * (p.min(axis=0) + p.max(axis=0))


def test_fast_points_are_the_loops_points() -> None:
    shape = _family("asymmetric", 0)
    np.testing.assert_allclose(_points(shape, 256), shape.points(256), atol=1e-12)
    size, centre = _size_and_centre(shape)
    assert size == pytest.approx(shape.size_m, abs=1e-12)
    np.testing.assert_allclose(centre, shape.centre, atol=1e-12)


@functools.cache
def _family(family: str, seed: int) -> LoopShape:
    return family_loop(family, _rng(seed))  # type: ignore[arg-type]


@functools.cache
def _random(seed: int) -> LoopShape:
    return random_loop(_rng(seed))


@functools.cache
def _varied(task: str, seed: int) -> LoopShape:
    return varied_guide(task, _rng(seed))


def _crossings(points: np.ndarray) -> list[np.ndarray]:
    """Where the closed polyline `points` (n, 2) crosses itself: solve every pair of segments
    p + s d = q + t e for s, t in (0, 1) (written apart from the module's sign test)."""
    d = np.roll(points, -1, axis=0) - points
    cross = d[:, None, 0] * d[None, :, 1] - d[:, None, 1] * d[None, :, 0]  # d_i × d_j
    w = points[None, :, :] - points[:, None, :]  # q_j - p_i
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (w[..., 0] * d[None, :, 1] - w[..., 1] * d[None, :, 0]) / cross
        t = (w[..., 0] * d[:, None, 1] - w[..., 1] * d[:, None, 0]) / cross
    hit = (s > 1e-9) & (s < 1 - 1e-9) & (t > 1e-9) & (t < 1 - 1e-9) & (np.abs(cross) > 0)
    i, j = np.nonzero(np.triu(hit, 2))
    return [points[a] + s[a, b] * d[a] for a, b in zip(i, j, strict=True)]


def _aspect(shape: LoopShape) -> float:
    """Minor / major principal axis of the loop's points (even speed: spread evenly)."""
    p = _points(shape, 1024)
    eig = np.linalg.eigvalsh(np.cov((p - p.mean(axis=0)).T))
    return float(np.sqrt(eig[0] / eig[1]))


def _mirror_asymmetry(shape: LoopShape) -> float:
    """Smallest Hausdorff distance, over every axis through the centroid, between the loop and
    its mirror image, as a fraction of its size (0 for a mirror-symmetric loop)."""
    p = _points(shape, 400)
    z = p[:, 0] + 1j * p[:, 1]
    z = z - z.mean()
    tree = KDTree(np.stack([z.real, z.imag], axis=1))

    def gap(angle: float) -> float:
        m = np.exp(2j * angle) * np.conj(z)
        return float(np.max(tree.query(np.stack([m.real, m.imag], axis=1))[0]))

    coarse = np.linspace(0.0, np.pi, 60, endpoint=False)
    best = coarse[int(np.argmin([gap(a) for a in coarse]))]
    step = coarse[1]
    fine = minimize_scalar(gap, bounds=(best - step, best + step), method="bounded")
    return min(float(fine.fun), gap(best)) / _size_and_centre(shape)[0]


@pytest.mark.parametrize("family", LOOP_FAMILIES)
def test_loops_are_closed_smooth_sized_and_centred(family) -> None:
    for seed in SEEDS:
        shape = _family(family, seed)
        assert shape.label == family and shape.harmonics == HARMONICS
        size, centre = _size_and_centre(shape)
        assert SIZE_RANGE_M[0] - 1e-9 <= size <= SIZE_RANGE_M[1] + 1e-9
        np.testing.assert_allclose(centre, 0.0, atol=1e-9)
        # Closed: the step from the last point back to the first is an ordinary step.
        p = _points(shape, 720)
        steps = np.linalg.norm(np.diff(np.vstack([p, p[:1]]), axis=0), axis=1)
        assert steps[-1] < 2.0 * np.median(steps)
        # Smooth: the series has died out well before its last harmonics.
        tail = np.abs(np.r_[shape.coefficients[:8], shape.coefficients[-8:]])
        assert tail.max() < 1e-4 * size, f"{family} seed {seed}"
        if family != "stroke":  # Close to even speed (a thin stroke slows in its turns).
            assert steps.max() < 2.0 * steps.min(), f"{family} seed {seed}"


def test_curvature_is_bounded() -> None:
    for seed in range(50):
        shape = _random(seed)
        assert min_radius(shape) >= MIN_RADIUS_FRACTION * _size_and_centre(shape)[0]
    for family in ("rounded_polygon", "d_shape", "figure_eight", "arch", "asymmetric"):
        for seed in SEEDS:
            shape = _family(family, seed)
            size = _size_and_centre(shape)[0]
            assert min_radius(shape) >= MIN_RADIUS_FRACTION * size, (family, seed)
    ovals = [_family("oval", seed) for seed in range(20)]
    assert min(min_radius(s) / _size_and_centre(s)[0] for s in ovals) >= 0.03


def test_min_radius_and_self_crossings_measure_what_they_say() -> None:
    # An ellipse with semi-axes a, b: radius b²/a at the ends of its long axis.
    a, b = 0.12, 0.05
    ellipse = LoopShape(np.array([(a - b) / 2, 0.0, (a + b) / 2]), "ellipse")
    assert min_radius(ellipse) == pytest.approx(b * b / a, rel=1e-6)
    assert self_crossings(ellipse) == 0
    assert self_crossings(LoopShape.guide("weaving")) == 1  # a lemniscate crosses once
    limacon = LoopShape(np.array([0.0, 0.0, 0.0, 0.05, 0.1]), "limaçon")  # an inner loop
    assert self_crossings(limacon) == 1 == len(_crossings(_points(limacon, 600)))


@pytest.mark.parametrize("family", LOOP_FAMILIES)
def test_only_the_figure_eight_crosses_itself(family) -> None:
    for seed in SEEDS:
        crossings = _crossings(_points(_family(family, seed), 400))
        assert len(crossings) == (1 if family == "figure_eight" else 0), (family, seed)


def test_aspect_and_symmetry_vary_across_seeds() -> None:
    loops = [_random(seed) for seed in range(50)]
    aspects = [_aspect(s) for s in loops]
    assert min(aspects) < 0.5 and max(aspects) > 0.9
    assert len({round(a, 4) for a in aspects}) == len(loops)  # no two alike
    # Mirror symmetry: the measure finds the axis of a symmetric loop (an oval, an egg, an
    # arch) to a few 0.1 % of its size; some random loops are 10 times farther from any.
    for shape in (_family("oval", 0), _family("oval", 1), _family("arch", 0)):
        assert _mirror_asymmetry(shape) < 0.004
    asymmetry = np.array([_mirror_asymmetry(s) for s in loops])
    assert np.count_nonzero(asymmetry > 0.04) >= 5, np.round(asymmetry, 3)
    assert np.count_nonzero(asymmetry < 0.01) >= 1, np.round(asymmetry, 3)  # and some are not


def test_loops_are_reproducible_for_a_seed() -> None:
    for kind in LOOP_KINDS:
        task = "weaving"
        a, b = draw_loop(kind, _rng(5), task), draw_loop(kind, _rng(5), task)
        np.testing.assert_array_equal(a.coefficients, b.coefficients)
        assert a.label == b.label
        if kind != "guide":
            c = draw_loop(kind, _rng(6), task)
            assert not np.allclose(_points(a, 64), _points(c, 64), atol=1e-3)
    np.testing.assert_array_equal(
        draw_set_loop("random", 3).coefficients, draw_set_loop("random", 3).coefficients
    )
    labels = {draw_set_loop("random", seed).label for seed in range(30)}
    assert labels == set(LOOP_FAMILIES)  # "random" draws every family


def test_bad_kinds_and_tasks_are_refused() -> None:
    with pytest.raises(ConfigError, match="valid: guide, varied, random, oval"):
        draw_loop("blob", _rng(0))  # type: ignore[arg-type]
    with pytest.raises(UnknownTaskError, match="needs a task with a guide"):
        draw_loop("varied", _rng(0), "stirring")
    with pytest.raises(UnknownTaskError, match="valid: wiping"):
        varied_guide("stirring", _rng(0))
    assert draw_loop("guide", _rng(0), "wiping").is_guide


def _extent(shape: LoopShape) -> np.ndarray:
    return np.ptp(_points(shape, 4096), axis=0)


def test_varied_wiping_keeps_its_width_and_varies_aspect_and_squareness() -> None:
    guide = LoopShape.guide("wiping")
    fill_guide = _fill(guide)
    heights, fills = [], []
    for seed in range(20):
        shape = _varied("wiping", seed)
        width, height = _extent(shape)
        assert width == pytest.approx(0.24, abs=1e-5)
        heights.append(height / 0.12)
        fills.append(_fill(shape))
        np.testing.assert_allclose(_size_and_centre(shape)[1], 0.0, atol=1e-9)
    assert 0.7 - 1e-4 <= min(heights) < 0.85 and 1.15 < max(heights) <= 1.3 + 1e-4
    # Squareness 0 (an ellipse fills π/4 of its box) to 0.11 (about the guide's 0.1).
    assert np.pi / 4 - 1e-3 < min(fills) < fill_guide - 0.02 and max(fills) > fill_guide - 0.005


def _fill(shape: LoopShape) -> float:
    """Area of the loop over the area of its bounding box."""
    p = _points(shape, 4096)
    area = 0.5 * abs(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))
    return float(area / np.prod(np.ptp(p, axis=0)))


def test_varied_pick_and_place_varies_height_and_return_depth_by_forty_percent() -> None:
    heights, depths = [], []
    for seed in range(20):
        p = _points(_varied("pick_and_place", seed), 4096)
        left, right = _place(p, -1.0), _place(p, 1.0)
        assert right[0] - left[0] == pytest.approx(0.30, abs=1e-5)
        assert left[1] == pytest.approx(right[1], abs=1e-5)
        heights.append((p[:, 1].max() - left[1]) / 0.1125)  # the guide's: 3/4 of 0.15 m
        depths.append((left[1] - p[:, 1].min()) / 0.0375)  # and 1/4
    for ratios in (heights, depths):
        assert 0.6 - 1e-3 <= min(ratios) < 0.8 and 1.2 < max(ratios) <= 1.4 + 1e-3, ratios


def _place(points: np.ndarray, side: float) -> np.ndarray:
    """The loop's leftmost (side −1) or rightmost (+1) point: the vertex of a parabola x(y)
    through the samples around the extreme sample (the loop runs up or down through it)."""
    i = int(np.argmax(side * points[:, 0]))
    near = points[np.arange(i - 4, i + 5) % len(points)]
    a, b, c = np.polyfit(near[:, 1], near[:, 0], 2)
    y = -b / (2 * a)
    return np.array([c - b * b / (4 * a), y])


def test_varied_weaving_has_unequal_lobes_and_another_size() -> None:
    ratios, sizes = [], []
    for seed in range(20):
        p = _points(_varied("weaving", seed), 600)
        (crossing,) = _crossings(p)
        ratios.append((p[:, 0].max() - crossing[0]) / (crossing[0] - p[:, 0].min()))
        sizes.append(np.ptp(p[:, 0]) / 0.30)
    assert 0.7 - 1e-3 <= min(ratios) < 0.85 and 1.15 < max(ratios) <= 1.3 + 1e-3, ratios
    assert 0.75 - 1e-3 <= min(sizes) < 0.9 and 1.1 < max(sizes) <= 1.25 + 1e-3, sizes
