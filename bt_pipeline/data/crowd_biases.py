"""The shared biases of a crowd set (:mod:`bt_pipeline.data.synth_crowd`): drawn, varied, applied.

Phases are fractions of the loop in [0, 1) (the loop's phase φ [rad] over 2π). A naive demo's
path is built in this order (the module doc of :mod:`~bt_pipeline.data.synth_crowd` says what
each bias is):

1. :func:`stop_short` (missing_part): the hand's progress along the loop stops short of the
   left-out interval and rests there while the intended path goes on;
2. :func:`apply_biases`, a function of the phase alone (so a bias falls on the same part of the
   loop in either direction of travel): the wrong lobe remaps the phase of the skipped lobe onto
   the kept one (kissing at the crossing), then the corner cut, the bulge and the undershoot
   shape the loop at that phase (their intervals are disjoint, each at least
   :data:`MARGIN` of the loop clear of the others and of the left-out interval);
3. :func:`drift_offsets`: the drift, growing with the part of the loop drawn so far.

The demonstrator's θ/ρ and the noise come after (:mod:`~bt_pipeline.data.synth_crowd`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np

from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.synth import DEMONSTRATORS

Loop = Callable[[FloatArray], FloatArray]
"""The set's loop in its canonical frame: phase [rad] (n,) to positions (n, 2) [m]."""

CrowdBias = Literal[
    "corner_cut",
    "undershoot",
    "hesitation",
    "backwards",
    "bulge",
    "drift",
    "wrong_lobe",
    "missing_part",
]
"""A bias the naive demos of a crowd set share."""
CROWD_BIASES: tuple[CrowdBias, ...] = get_args(CrowdBias)
MARGIN = 0.03
"""Phase kept clear between two bias intervals, fraction of the loop."""
MIN_LOBE = 0.2
"""Shortest lobe (phase between the two passes of a self-crossing) a wrong lobe needs."""
_CUT_CANDIDATES = 64  # Interval starts the corner cut is chosen among.
_EASE = 0.02  # The hand slows to its early stop over ±this much progress (fraction of the loop).
_BOX_POINTS = 1024  # Points the loop's size and the bulge's side are read on.
_CROSSING_POINTS = 512  # Segments a self-crossing is looked for on.
_TANGENT_STEP = 1e-5  # Phase step of the tangents [fraction of the loop].


@dataclass(frozen=True)
class CrowdBiases:
    """The biases of one crowd set (or one demo's variation of them); phases as loop fractions."""

    cut_start: float
    """Start of the corner-cut interval, fraction of the loop's phase in [0, 1)."""
    cut_width: float
    """Length of the corner-cut interval, fraction of the loop (0.10-0.20)."""
    cut_blend: float
    """Weight of the chord in the cut interval (0.6-1.0; 1: the straight chord)."""
    undershoot_start: float
    """Start of the undershoot interval, fraction of the loop's phase in [0, 1)."""
    undershoot_width: float
    """Length of the undershoot interval, fraction of the loop (0.15-0.25)."""
    undershoot_depth: float
    """Pull toward the loop's centre at the interval's middle, fraction (0.15-0.30)."""
    pause_phase: float
    """Where everyone pauses, fraction of the loop's phase in [0, 1)."""
    pause_s: float
    """Length of the pause [s] (0.3-1.0)."""
    backwards_teacher: str | None
    """Name of the demonstrator who draws backwards, or None (fewer than 3 naive ones)."""
    bulge_start: float
    """Start of the bulge interval, fraction of the loop's phase in [0, 1)."""
    bulge_width: float
    """Length of the bulge interval, fraction of the loop (0.15-0.25)."""
    bulge_m: float
    """Push along the normal at the interval's middle [m] (8-15 % of the loop's size)."""
    bulge_side: int
    """+1: the push is to the left of the loop's direction of increasing phase; -1: right
    (whichever is outward at the interval's middle)."""
    drift_m: float
    """Length of the drift when the hand stops [m] (3-8 % of the loop's size)."""
    drift_angle_deg: float
    """Direction of the drift in the loop's frame [deg], counter-clockwise from +x."""
    lobe_start: float | None
    """Phase where the skipped lobe begins (one pass of a self-crossing), fraction of the loop;
    None: the loop does not cross itself (no wrong lobe)."""
    lobe_width: float | None
    """Length of the skipped lobe, fraction of the loop (>= :data:`MIN_LOBE`), or None."""
    kiss_width: float
    """Half-length of the phase window the turn at the crossing is blended over, fraction of the
    loop (0.02-0.03)."""
    missing_start: float
    """Start of the interval every naive demo leaves out, fraction of the loop's phase."""
    missing_width: float
    """Length of the left-out interval, fraction of the loop (0.08-0.15)."""


def draw_biases(loop: Loop, naive_teachers: list[int], rng: np.random.Generator) -> CrowdBiases:
    """The set-level biases (the module doc of :mod:`~bt_pipeline.data.synth_crowd`).

    The corner cut falls on a real corner; the undershoot, bulge and left-out intervals follow
    it round the loop in a random order, with the phase to spare split at random between the
    gaps (each at least :data:`MARGIN`). The pause falls 20-80 % of the way along the drawn part.

    Args:
        loop: The set's loop in its canonical frame, phase [rad] (n,) to positions (n, 2) [m].
        naive_teachers: Indices into DEMONSTRATORS of the demonstrators with naive demos.
        rng: The set's random generator.
    """
    points = loop(2.0 * np.pi * np.arange(_BOX_POINTS) / _BOX_POINTS)
    size = float(np.max(np.ptp(points, axis=0)))
    cut_width = float(rng.uniform(0.10, 0.20))
    starts = np.arange(_CUT_CANDIDATES) / _CUT_CANDIDATES
    sags = np.array([_chord_sag(loop, float(s), cut_width) for s in starts])
    deep = np.flatnonzero(sags >= 0.6 * sags.max())
    cut_start = float(starts[rng.choice(deep)] + rng.uniform(0.0, 1.0 / _CUT_CANDIDATES)) % 1.0
    widths = {
        "undershoot": float(rng.uniform(0.15, 0.25)),
        "bulge": float(rng.uniform(0.15, 0.25)),
        "missing": float(rng.uniform(0.08, 0.15)),
    }
    names = [list(widths)[i] for i in rng.permutation(len(widths))]
    spare = 1.0 - cut_width - sum(widths.values()) - (len(widths) + 1) * MARGIN
    gaps = spare * rng.dirichlet(np.ones(len(widths) + 1))
    at, placed = cut_start + cut_width, {}
    for name, gap in zip(names, gaps[:-1], strict=True):
        placed[name] = float(at + MARGIN + gap) % 1.0
        at += MARGIN + gap + widths[name]
    bulge_middle = placed["bulge"] + 0.5 * widths["bulge"]
    crossing = self_crossing(loop)
    skip_second = bool(rng.integers(2))
    lobe_start = lobe_width = None
    if crossing is not None:
        a, b = crossing
        lobe_start, lobe_width = (b, 1.0 - (b - a)) if skip_second else (a, b - a)
    missing_end = placed["missing"] + widths["missing"]
    backwards = None
    if len(naive_teachers) >= 3:
        backwards = DEMONSTRATORS[int(rng.choice(naive_teachers))].name
    return CrowdBiases(
        cut_start=cut_start,
        cut_width=cut_width,
        cut_blend=float(rng.uniform(0.6, 1.0)),
        undershoot_start=placed["undershoot"],
        undershoot_width=widths["undershoot"],
        undershoot_depth=float(rng.uniform(0.15, 0.30)),
        pause_phase=(missing_end + float(rng.uniform(0.2, 0.8)) * (1.0 - widths["missing"])) % 1,
        pause_s=float(rng.uniform(0.3, 1.0)),
        backwards_teacher=backwards,
        bulge_start=placed["bulge"],
        bulge_width=widths["bulge"],
        bulge_m=float(rng.uniform(0.08, 0.15)) * size,
        bulge_side=_outward_side(loop, bulge_middle, points),
        drift_m=float(rng.uniform(0.03, 0.08)) * size,
        drift_angle_deg=float(rng.uniform(0.0, 360.0)),
        lobe_start=lobe_start,
        lobe_width=lobe_width,
        kiss_width=float(rng.uniform(0.02, 0.03)),
        missing_start=placed["missing"],
        missing_width=widths["missing"],
    )


def varied_biases(biases: CrowdBiases, rng: np.random.Generator) -> CrowdBiases:
    """One demo's take on the set's biases: interval edges and pause phase ±1 % of the loop,
    magnitudes (cut blend, undershoot depth, bulge, drift, kiss window) ±15 %, pause length
    ±20 %, drift direction ±10°."""

    def edge(phase: float) -> float:
        return (phase + float(rng.uniform(-0.01, 0.01))) % 1.0

    def scaled(value: float, spread: float = 0.15) -> float:
        return value * float(rng.uniform(1.0 - spread, 1.0 + spread))

    return dataclasses.replace(
        biases,
        cut_start=edge(biases.cut_start),
        cut_blend=min(1.0, scaled(biases.cut_blend)),
        undershoot_start=edge(biases.undershoot_start),
        undershoot_depth=scaled(biases.undershoot_depth),
        pause_phase=edge(biases.pause_phase),
        pause_s=scaled(biases.pause_s, 0.2),
        bulge_start=edge(biases.bulge_start),
        bulge_m=scaled(biases.bulge_m),
        drift_m=scaled(biases.drift_m),
        drift_angle_deg=biases.drift_angle_deg + float(rng.uniform(-10.0, 10.0)),
        kiss_width=scaled(biases.kiss_width),
        missing_start=edge(biases.missing_start),
    )


def stop_short(progress: FloatArray, biases: CrowdBiases) -> FloatArray:
    """How far along the loop the hand is, shape (T,): `progress` (T,) in [0, 1] until the hand
    stops short of the left-out interval at 1 - missing_width, where it rests to the end.

    The hand slows smoothly into the stop (a quadratic ease over ±2 % of the loop about it), so
    its speed has no jump.
    """
    stop = 1.0 - biases.missing_width
    p = np.asarray(progress, dtype=np.float64)
    x = np.clip(p - (stop - _EASE), 0.0, 2.0 * _EASE)
    return p - x * x / (4.0 * _EASE) - np.clip(p - (stop + _EASE), 0.0, None)


def drift_offsets(drawn: FloatArray, biases: CrowdBiases) -> FloatArray:
    """The drift at each sample, shape (T, 2) [m]: drift_m times the part of the drawn stretch
    done (`drawn` (T,), from :func:`stop_short`, over 1 - missing_width), in one direction."""
    done = np.clip(np.asarray(drawn) / (1.0 - biases.missing_width), 0.0, 1.0)
    angle = math.radians(biases.drift_angle_deg)
    return biases.drift_m * done[:, None] * np.array([math.cos(angle), math.sin(angle)])


def apply_biases(
    loop: Loop, phase: FloatArray, biases: CrowdBiases, centre: FloatArray
) -> FloatArray:
    """The loop at `phase` [rad] (T,) with the wrong lobe, the corner cut, the bulge and the
    undershoot, shape (T, 2) [m].

    All depend on the phase only, so they fall on the same part of the loop in either
    direction of travel. `centre` (2,) [m] is where the undershoot pulls toward.
    """
    u = (np.asarray(phase, dtype=np.float64) / (2.0 * np.pi)) % 1.0
    first, second, weight = _lobe_phases(u, biases)
    out = _shaped(loop, first, biases, centre)
    blended = weight > 0.0
    if blended.any():
        w = weight[blended, None]
        other = _shaped(loop, second[blended], biases, centre)
        out[blended] = (1.0 - w) * out[blended] + w * other
    return out


def self_crossing(loop: Loop) -> tuple[float, float] | None:
    """The two phases (fractions a < b of the loop) where the loop crosses itself, or None.

    Crossings are looked for between the loop's segments at even phase and refined by Newton's
    method on loop(a) = loop(b). Of several, the one that splits the loop most evenly; a crossing
    with a lobe shorter than :data:`MIN_LOBE` of the loop (a small knot, not a lobe) is not one.
    """
    n = _CROSSING_POINTS
    u = (np.arange(n) + 0.5) / n  # off the guides' symmetric phases, so no vertex is a crossing
    z = loop(2.0 * np.pi * u)
    d = np.roll(z, -1, axis=0) - z
    w = z[None, :, :] - z[:, None, :]  # from segment i's start to segment j's

    def cross(p: FloatArray, q: FloatArray) -> FloatArray:
        return p[..., 0] * q[..., 1] - p[..., 1] * q[..., 0]

    with np.errstate(divide="ignore", invalid="ignore"):
        denom = cross(d[:, None, :], d[None, :, :])
        s = cross(w, d[None, :, :]) / denom
        t = cross(w, d[:, None, :]) / denom
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    apart = (j - i >= 2) & ~((i == 0) & (j == n - 1))
    hits = np.flatnonzero(apart & (s >= 0) & (s < 1) & (t >= 0) & (t < 1))
    best = None
    for hit in hits:
        a, b = _refined(loop, u[i.flat[hit]] + s.flat[hit] / n, u[j.flat[hit]] + t.flat[hit] / n)
        a, b = sorted((float(a) % 1.0, float(b) % 1.0))
        if min(b - a, 1.0 - (b - a)) >= MIN_LOBE and (
            best is None or abs(b - a - 0.5) < abs(best[1] - best[0] - 0.5)
        ):
            best = (a, b)
    return best


def _refined(loop: Loop, a: float, b: float) -> tuple[float, float]:
    """(a, b) refined so that loop(a) = loop(b) (phases as fractions of the loop)."""
    for _ in range(4):
        gap = loop(2.0 * np.pi * np.array([a]))[0] - loop(2.0 * np.pi * np.array([b]))[0]
        jacobian = np.column_stack([_tangent(loop, np.array([a]))[0], -_tangent(loop, [b])[0]])
        if abs(np.linalg.det(jacobian)) < 1e-12:
            break
        da, db = np.linalg.solve(jacobian, -gap)
        a, b = a + float(da), b + float(db)
    return a, b


def _tangent(loop: Loop, u: FloatArray | list[float]) -> FloatArray:
    """d loop / d u at phases `u` (fractions, (n,)), shape (n, 2) [m per loop]."""
    u = np.asarray(u, dtype=np.float64)
    h = _TANGENT_STEP
    return (loop(2.0 * np.pi * (u + h)) - loop(2.0 * np.pi * (u - h))) / (2.0 * h)


def _left_normal(loop: Loop, u: FloatArray) -> FloatArray:
    """Unit normals to the left of the direction of increasing phase at `u`, shape (n, 2)."""
    t = _tangent(loop, u)
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12)
    return np.stack([-t[:, 1], t[:, 0]], axis=1)


def _outward_side(loop: Loop, u: float, points: FloatArray) -> int:
    """+1 if the loop's outside is to the left of its direction of increasing phase at `u`."""
    p = loop(2.0 * np.pi * np.array([u]))[0]
    normal = _left_normal(loop, np.array([u]))[0]
    step = 1e-3 * float(np.max(np.ptp(points, axis=0)))
    left, right = (abs(_winding(points, p + sign * step * normal)) for sign in (1.0, -1.0))
    return 1 if left <= right else -1


def _winding(points: FloatArray, q: FloatArray) -> int:
    """How many times the closed polygon `points` (n, 2) winds round the point `q` (2,)."""
    angles: FloatArray = np.arctan2(points[:, 1] - q[1], points[:, 0] - q[0])
    turns = np.roll(angles, -1) - angles
    wrapped = (turns + np.pi) % (2.0 * np.pi) - np.pi
    return round(float(np.sum(wrapped)) / (2.0 * np.pi))


def _chord_sag(loop: Loop, start: float, width: float) -> float:
    """Largest distance [m] of the loop over [start, start + width] from its chord."""
    points = loop(2.0 * np.pi * (start + width * np.linspace(0.0, 1.0, 33)))
    a, b = points[0], points[-1]
    ab = b - a
    x = np.clip((points - a) @ ab / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return float(np.max(np.linalg.norm(points - a - x[:, None] * ab, axis=1)))


def _lobe_phases(u: FloatArray, biases: CrowdBiases) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Where on the loop the hand is at phases `u` (T,): two phases and the weight of the second.

    Without a wrong lobe, (u, u, 0). With one, the skipped lobe's phases map linearly onto the
    kept lobe (the hand goes round the lobe it came from again). Within kiss_width of either
    pass of the crossing the hand blends (smootherstep) from the branch it arrived on, continued
    across, to the branch of the kept lobe it leaves on: both sit on the crossing at its middle,
    so the path touches the crossing point and turns back instead of crossing over.
    """
    zeros = np.zeros_like(u)
    if biases.lobe_start is None or biases.lobe_width is None:
        return u, u, zeros
    start, skipped, h = biases.lobe_start, biases.lobe_width, biases.kiss_width
    ratio = (1.0 - skipped) / skipped  # kept lobe per skipped lobe
    x = (u - start) % 1.0
    mapped = np.where(x < skipped, start + skipped + x * ratio, u)
    first, second, weight = mapped.copy(), mapped.copy(), zeros
    entering = ((x + 0.5) % 1.0) - 0.5  # signed phase from the pass where the skipped lobe begins
    near = np.abs(entering) < h
    first[near] = u[near]
    second[near] = start + skipped + entering[near] * ratio
    weight = np.where(near, _smootherstep((entering + h) / (2.0 * h)), weight)
    leaving = x - skipped  # signed phase from the pass where it ends
    near = np.abs(leaving) < h
    first[near] = start + skipped + x[near] * ratio
    second[near] = u[near]
    weight = np.where(near, _smootherstep((leaving + h) / (2.0 * h)), weight)
    return first % 1.0, second % 1.0, weight


def _smootherstep(x: FloatArray) -> FloatArray:
    """6x⁵ - 15x⁴ + 10x³ on [0, 1] (0 and 1 outside): rises from 0 to 1, flat at both ends."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (10.0 - 15.0 * x + 6.0 * x * x)


def _shaped(loop: Loop, u: FloatArray, biases: CrowdBiases, centre: FloatArray) -> FloatArray:
    """The loop at phases `u` (fractions, (T,)) with the corner cut, bulge and undershoot [m]."""
    out = loop(2.0 * np.pi * u)
    x = ((u - biases.cut_start) % 1.0) / biases.cut_width
    cut = x < 1.0
    ends = loop(2.0 * np.pi * (biases.cut_start + np.array([0.0, biases.cut_width])))
    chord = ends[0] + x[cut, None] * (ends[1] - ends[0])
    out[cut] = (1.0 - biases.cut_blend) * out[cut] + biases.cut_blend * chord
    x = ((u - biases.bulge_start) % 1.0) / biases.bulge_width
    bulged = x < 1.0
    push = biases.bulge_side * biases.bulge_m * np.sin(np.pi * x[bulged]) ** 2
    out[bulged] += push[:, None] * _left_normal(loop, u[bulged])
    x = ((u - biases.undershoot_start) % 1.0) / biases.undershoot_width
    pull = biases.undershoot_depth * np.where(x < 1.0, np.sin(np.pi * x) ** 2, 0.0)
    return centre + (1.0 - pull)[:, None] * (out - centre)


__all__ = [
    "CROWD_BIASES",
    "MARGIN",
    "MIN_LOBE",
    "CrowdBias",
    "CrowdBiases",
    "Loop",
    "apply_biases",
    "draw_biases",
    "drift_offsets",
    "self_crossing",
    "stop_short",
    "varied_biases",
]
