"""The task's loop, learned from its demos; the task's guide used only where the demos follow it.

The paper takes the canonical shape from the best demo and never assumes one (Sec. III-B). bt's
segmentation, θ/ρ estimate, shape gate and take checks need a loop to measure each demo
against before the best demo is known, so the loop is learned from every demo first:

1. **Each demo's own loop** (:func:`~bt_pipeline.clean.recurrence.own_loop`): one loop where
   its path returns to itself, 256 points uniform in arc length. Demos that close no loop (a
   part of a loop) do not take part.
2. **Alignment** in closed form (:mod:`bt_pipeline.clean.loop_align`): two loops z, w
   are compared over every start shift s and both directions; for each the best similarity
   a = ⟨z, w_s⟩ / ⟨w_s, w_s⟩ (rotation and scale at once) leaves a residual
   |z|² − |⟨z, w_s⟩|² / |w_s|², computed for all shifts at once by FFT. The distance is the
   root of the smallest residual over |z|²: a share of the loop's size.
3. **Consensus.** Only demos whose path holds 2 loops or more take part when there are two
   such (a single loop closes at one point, where an approach joining it may bring a piece of
   itself into the loop read). The medoid (the loop with the smallest median distance to the
   others; at most 40 demos are compared pairwise) is the first reference; every loop within 3 x the
   median distance of it (other tasks' loops, a lobe of an eight, fall out) is aligned to it
   and the point-wise median is taken; then once more against that median. The consensus is
   low-passed to 12 harmonics and centred on its bounding box.
4. **Guide or learned.** A task with a built-in guide keeps its guide when some demo's own
   loop lies within 4 % (RMS, of its RMS radius) of a similarity of the guide (of the guide
   turned and scaled by its stated θ/ρ, when it states them) and the
   consensus within 12 %: the demos follow it (every guide set of ``bench_clean_human.py`` keeps
   the guide, ``tests/pipeline/clean/test_clean_loops.py``; the foreign wiping oval, closest
   demo 9 % off, does not); or when some demo lies within 2 %, whatever the consensus (a traced
   guide must not be outvoted by a majority sharing one bias). Otherwise the learned loop is used.
   Selection checks a kept guide once more against the segmented demos and may set it aside
   (``use_guide=False``; :func:`bt_pipeline.clean.selection.off_guide`).
5. **Frame.** A learned loop's θ = 0, ρ = 1 is the set's: each demo's similarity to the
   consensus is read off its alignment, and the loop is turned and scaled so that these have
   circular-mean θ 0 and geometric-mean ρ 1; when demos state θ/ρ, so that theirs match the
   stated ones on average instead (θ/ρ written in a file are used as given, relative to the
   learned loop: the paper's x_i^aligned needs only θ_i − θ_best and ρ_i / ρ_best).
   θ of a loop with an n-fold symmetry (n > 2) is averaged modulo 360°/n; otherwise each turn
   counts as itself or its 180° twin, whichever lies on the side most turns lie (an oval, or
   an eight travelled the other way, is its own twin at 180°, and a plain mean of both sides
   lands 90° off); a demo aligned about as well (within 3 %) at several turns takes the
   smallest.
6. **The best demo's loop.** Selection then picks the best demo against that loop; its own
   loop, with its stated θ/ρ removed (the paper's x^g) or, when hidden, turned and scaled onto
   the consensus, replaces the consensus, and the demos are segmented and scored again against
   it (:mod:`bt_pipeline.clean.best_loop`), as the paper takes the canonical shape from the best
   demo. Its loop is read between its returns when its path holds 2 loops or more or is the
   loop alone (at most 1.1 loops of path: no approach); otherwise off its kept span, in the
   phase of its fit (:mod:`bt_pipeline.clean.span_loop`: a single loop with an approach closes
   at one point, where the approach may join it), and when that span holds under 0.95 of a
   loop, off the span found against its own returns' loop if that holds more (a consensus that
   leans to lopsided demos cut an expert's single loop to 0.7). A guide is replaced the same
   way when the best demo closes a loop of its own of which less than 0.9 was found on the
   guide (an arch whose return runs 5 mm from the guide's, θ/ρ given: half the expert's loop
   was cut, 99.6 x its raw error). The consensus of a set whose demos draw one loop each leans
   to its lopsided demos (a loop drawn bigger on one side still closes; a drifting or
   incomplete one does not): in a 20-demo single-loop wiping set of an oval (seed 0, θ/ρ
   given) its scale was 15 % off, the expert's own loop 0.4 %.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from bt_pipeline.clean.guide_fit import GuideFit
from bt_pipeline.clean.loop_align import (
    align,
    apply_alignment,
    arc_points,
    centred_complex,
    circular_mean,
    loop_signature,
    majority_turn,
    mirror_axis,
    stated_distance,
    symmetry_order,
)
from bt_pipeline.clean.recurrence import LOOP_POINTS, own_loop
from bt_pipeline.data.demo import Demo
from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.data.tasks import has_guide
from bt_pipeline.exceptions import DemoError

GUIDE_FOLLOWED = 0.04
"""The guide is used when some demo's own loop lies within this share of its RMS radius of a
similarity of the guide"""
GUIDE_MISFIT = 0.12
"""and the learned consensus within this share (a consensus of a few noisy demos is itself
several % off the shape they meant)."""
GUIDE_TRACED = 0.02
"""Or when some demo's own loop lies within this share of the guide, whatever the consensus: it
traced the guide (the loosest expert of shared-bias weaving crowds 0-9 lies 1.6 % off), and a
majority that shares one bias (the wrong lobe of an eight) must not outvote it."""
HARMONICS = 12  # Harmonics of a learned loop.
_MAX_PAIRWISE = 40  # Loops compared pairwise for the medoid.
_OUTLIER = 3.0  # Loops farther than this many median distances from the medoid are left out,
_OUTLIER_FLOOR = 0.05  # and never those within this share of the size.
REPEATS = 2.0  # A demo's own loop is read between its returns when its path holds this many.
TIE = 0.03  # Alignments this close to the best are ties: the one that turns least wins.

LoopSource = Literal["guide", "learned"]


@dataclass(frozen=True)
class TaskLoop:
    """The loop a task's demos are measured against, and where it came from."""

    loop: LoopShape
    """The template (the guide, or the learned loop in the frame of :attr:`frame`)."""
    source: LoopSource
    """``"guide"``: the task's built-in guide; ``"learned"``: learned from the demos."""
    guide_misfit: float
    """RMS distance of the learned consensus from the nearest similarity of the guide, as a
    share of its RMS radius (NaN for a task without a guide or when nothing was learned)."""
    used: tuple[str, ...]
    """Labels of the demos whose own loops built the consensus."""
    frame: str
    """What θ = 0, ρ = 1 mean for this loop."""
    notes: tuple[str, ...] = ()
    """Things a user should know (demos that close no loop, a guide that does not fit)."""
    best: str | None = None
    """The demo whose own loop the template is, once selection has picked it (step 6)."""
    own: dict[str, np.ndarray] = dataclasses.field(default_factory=dict, repr=False)
    """Each demo's own loop (256 points, arc length) by label, for the demos that close one."""
    repeats: dict[str, float] = dataclasses.field(default_factory=dict, repr=False)
    """Each such demo's path length in loops (:attr:`OwnLoop.loops`, approach included)."""
    traced: bool = False
    """A demo's own loop lies within :data:`GUIDE_TRACED` of the guide (the guide is kept)."""

    @functools.cached_property
    def symmetry_axis(self) -> tuple[float, float]:
        """L1's axis (Eq. 4) in this loop's frame: (its angle from the vertical [deg],
        counter-clockwise; how far the loop lies from its mirror image about it, a share of its
        RMS radius). A guide is drawn about the vertical axis; a learned loop's is its most
        nearly mirror-symmetric axis (:func:`~bt_pipeline.clean.loop_align.mirror_axis`), so
        a demo de-rotated by −(θ_i + angle) is mirrored about the axis of the shape it draws."""
        points = self.loop.points(1024)
        angle, asymmetry = mirror_axis(loop_signature(points))
        return (0.0 if self.source == "guide" else angle), asymmetry

    def attrs(self) -> dict[str, str | float | int]:
        """The cleaned file's ``/data`` attrs naming the loop the demos were measured against
        and how well the guide fitted them (docs/recording-format.md)."""
        return {
            "loop_source": self.source,
            "loop_guide_misfit": self.guide_misfit,
            "loop_frame": self.frame,
            "loop_demos": len(self.used),
            "loop_symmetry_axis_deg": self.symmetry_axis[0],
            "loop_asymmetry": self.symmetry_axis[1],
            "loop_placed": int(self.loop.anchored),
        }

    def hints(self) -> dict[str, GuideFit]:
        """Each demo's own loop aligned to this loop in closed form, as a fit to start the
        segmentation's from (a learned loop only: a guide set's fits stay as they were). A
        whole-loop alignment does not settle on one lobe of an eight, as a trimmed fit from a
        few starting turns can."""
        if self.source != "learned":
            return {}
        points = arc_points(self.loop.points(1024))
        z_mean = complex(points[:, 0].mean(), points[:, 1].mean())
        z = centred_complex(points)
        out = {}
        for label, loop in self.own.items():
            w_mean = complex(loop[:, 0].mean(), loop[:, 1].mean())
            a = align(z, centred_complex(loop), TIE)[0]  # template ≈ a · demo (centred)
            pref = 1.0 / a
            t = w_mean - pref * z_mean
            size = abs(pref) * self.loop.size_m
            theta = math.degrees(math.atan2(pref.imag, pref.real))
            out[label] = GuideFit(
                theta, abs(pref), np.array([t.real, t.imag]), 0.0, size, self.loop
            )
        return out


def learn_task_loop(
    demos: Sequence[Demo], *, use_guide: bool = True, known: TaskLoop | None = None
) -> TaskLoop:
    """The loop one task's demos are measured against (module doc).

    Args:
        demos: The task's demos (their raw samples are read).
        use_guide: Whether the task's guide may be chosen (step 4); False when selection found
            that the demos do not follow it after all (:mod:`bt_pipeline.clean.selection`).
        known: An earlier result for the same demos: their own loops are taken from it
            instead of being found again (step 1).

    Raises:
        DemoError: A task without a guide none of whose demos closes a loop.
    """
    task = demos[0].task
    guided = has_guide(task)
    loops: list[np.ndarray] = []
    used: list[int] = []
    own: dict[str, np.ndarray] = {}
    repeats: dict[str, float] = {}
    for i, demo in enumerate(demos):
        if known is not None:
            loop, count = known.own.get(demo.label), known.repeats.get(demo.label, 0.0)
        else:
            found = own_loop(*demo.raw_samples(), demo.label)
            loop = found.loop if found.closes else None
            count = found.loops
        if loop is not None:
            loops.append(centred_complex(loop))
            used.append(i)
            own[demo.label] = loop
            repeats[demo.label] = count
    notes: list[str] = []
    if not loops:
        names = ", ".join(d.label for d in demos)
        if guided:
            return TaskLoop(
                LoopShape.guide(task),
                "guide",
                math.nan,
                (),
                f"the {task} guide's frame",
                (f"no demo of {task} closes a loop of its own ({names}): its guide is used",),
            )
        raise DemoError(
            f"no demo of task {task!r} closes a loop of its own, so its loop cannot be learned "
            f"({names})"
        )
    # Loops from demos that repeat them (two or more) are read between two returns, inside the
    # periodic part; a single loop closes at one point, where an approach may join it and
    # bring a piece of itself along. The repeated ones build the consensus when there are two.
    repeated = [k for k, i in enumerate(used) if repeats[demos[i].label] >= REPEATS]
    pool = repeated if len(repeated) >= 2 else list(range(len(loops)))
    consensus, chosen = _consensus([loops[k] for k in pool])
    members = [pool[k] for k in chosen]
    outliers = [k for k in pool if k not in members]
    kept = [used[m] for m in members]
    left_out = [demos[used[k]].label for k in outliers]
    if left_out:
        notes.append(
            f"{', '.join(left_out)}: their loops differ from the other {task} demos' and were "
            "left out of the task's learned loop"
        )
    points = np.stack([np.real(consensus), np.imag(consensus)], axis=1)
    learned = LoopShape.from_points(points, HARMONICS, f"{task} loop learned from {len(kept)}")
    learned = learned.transformed(translation=-learned.centre)
    misfit = math.nan
    if guided:
        guide = LoopShape.guide(task)
        drawn = loop_signature(guide.points(1024))
        misfit = align(centred_complex(learned.points(LOOP_POINTS)), drawn)[3]
        # A demo that states θ/ρ follows the guide only in that frame (a guide turned or
        # scaled to fit it would read its stated preference against another shape).
        gaps = [
            _guide_distance(loop, guide, drawn, demos[i])
            for loop, i in zip(loops, used, strict=True)
        ]
        closest = min(gaps)
        if use_guide and closest <= GUIDE_TRACED and misfit > GUIDE_MISFIT:
            tracers = [used[k] for k, g in enumerate(gaps) if g <= GUIDE_FOLLOWED]
            return TaskLoop(
                guide,
                "guide",
                misfit,
                _labels(demos, tracers),
                f"the {task} guide's frame",
                (
                    f"{_labels(demos, tracers)[0]} traces the {task} guide within "
                    f"{100 * closest:.1f} % of its size, though the other demos' consensus lies "
                    f"{100 * misfit:.0f} % off it: the guide is used",
                ),
                own=own,
                repeats=repeats,
                traced=True,
            )
        if use_guide and closest <= GUIDE_FOLLOWED and misfit <= GUIDE_MISFIT:
            return TaskLoop(
                guide,
                "guide",
                misfit,
                _labels(demos, kept),
                f"the {task} guide's frame",
                own=own,
                repeats=repeats,
                traced=closest <= GUIDE_TRACED,
            )
        if use_guide:
            notes.append(
                f"the {task} demos do not follow the task's guide (the closest is "
                f"{100 * closest:.1f} % of its size off, the consensus {100 * misfit:.1f} %): "
                f"their own loop, learned from {len(kept)} demos, is used"
            )
    framing = [k for k in range(len(used)) if k not in outliers]
    framed, frame = _frame(learned, [demos[used[k]] for k in framing], [loops[k] for k in framing])
    return TaskLoop(
        framed,
        "learned",
        misfit,
        _labels(demos, kept),
        frame,
        tuple(notes),
        own=own,
        repeats=repeats,
    )


def guide_distance(loop: np.ndarray, demo: Demo) -> float:
    """How far a demo's own loop (256 points, arc length) lies from its task's guide, as a
    share of its RMS radius (:func:`_guide_distance`)."""
    guide = LoopShape.guide(demo.task)
    drawn = loop_signature(guide.points(1024))
    return _guide_distance(centred_complex(loop), guide, drawn, demo)


def _guide_distance(loop: np.ndarray, guide: LoopShape, drawn: np.ndarray, demo: Demo) -> float:
    """How far a demo's own loop (centred complex) lies from the guide (step 4): from its
    best similarity of the guide (`drawn`, its signature), or from the guide turned and scaled
    by the demo's stated θ/ρ when it states them."""
    if demo.theta_deg is None or demo.rho is None:
        return align(loop, drawn)[3]
    stated = loop_signature(guide.transformed(demo.theta_deg, demo.rho).points(1024))
    return stated_distance(loop, stated)


def _labels(demos: Sequence[Demo], kept: Sequence[int]) -> tuple[str, ...]:
    return tuple(demos[i].label for i in kept)


def _consensus(loops: list[np.ndarray]) -> tuple[np.ndarray, list[int]]:
    """The point-wise median of the loops aligned to their medoid, and the loops kept."""
    m = len(loops)
    if m == 1:
        return loops[0], [0]
    pool = list(range(m)) if m <= _MAX_PAIRWISE else list(np.linspace(0, m - 1, _MAX_PAIRWISE))
    pool = [int(i) for i in pool]
    distance = np.zeros((len(pool), len(pool)))
    for a, i in enumerate(pool):
        for b, j in enumerate(pool):
            if b > a:
                d = 0.5 * (align(loops[i], loops[j])[3] + align(loops[j], loops[i])[3])
                distance[a, b] = distance[b, a] = d
    spread = np.nanmedian(np.where(np.eye(len(pool), dtype=bool), np.nan, distance), axis=1)
    reference = loops[pool[int(np.argmin(spread))]]
    members: list[int] = []
    for _ in range(2):
        fits = [align(reference, z, TIE) for z in loops]
        d = np.array([f[3] for f in fits])
        cut = max(_OUTLIER * float(np.median(d)), _OUTLIER_FLOOR)
        members = [k for k in range(m) if d[k] <= cut] or [int(np.argmin(d))]
        stack = np.stack([apply_alignment(loops[k], *fits[k][:3]) for k in members])
        reference = np.median(np.real(stack), axis=0) + 1j * np.median(np.imag(stack), axis=0)
        reference = reference - reference.mean()
    return reference, members


def _frame(
    learned: LoopShape, demos: Sequence[Demo], loops: Sequence[np.ndarray]
) -> tuple[LoopShape, str]:
    """The learned loop turned and scaled into the set's frame (step 5)."""
    z = centred_complex(learned.points(LOOP_POINTS))
    thetas, log_rhos, given = [], [], []
    for demo, loop in zip(demos, loops, strict=True):
        a = align(z, loop, TIE)[0]  # a * demo ≈ learned: the demo is learned / a.
        pref = 1.0 / a
        thetas.append(math.degrees(math.atan2(pref.imag, pref.real)))
        log_rhos.append(math.log(abs(pref)))
        given.append(demo.theta_deg is not None and demo.rho is not None)
    thetas_a, log_a, given_a = np.array(thetas), np.array(log_rhos), np.array(given)
    if given_a.any():
        stated = [d for d, g in zip(demos, given, strict=True) if g]
        theta_off = thetas_a[given_a] - np.array([d.theta_deg for d in stated], dtype=float)
        rho_off = log_a[given_a] - np.log(np.array([d.rho for d in stated], dtype=float))
        frame = "the θ/ρ the demos state"
    else:
        theta_off, rho_off = thetas_a, log_a
        frame = "the set's: circular-mean θ = 0 and geometric-mean ρ = 1 over its demos"
    order = symmetry_order(z)
    # n-fold symmetric (n > 2): modulo 360°/n; else each turn or its 180° twin.
    mean_theta = circular_mean(theta_off * order) / order if order > 2 else majority_turn(theta_off)
    scale = math.exp(float(np.median(rho_off)))
    return learned.transformed(mean_theta, scale), frame


__all__ = [
    "GUIDE_FOLLOWED",
    "GUIDE_MISFIT",
    "HARMONICS",
    "REPEATS",
    "TIE",
    "LoopSource",
    "TaskLoop",
    "arc_points",
    "guide_distance",
    "learn_task_loop",
    "loop_signature",
]
