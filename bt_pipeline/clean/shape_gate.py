"""Which demos may be the best: those that follow the task's guide about as closely as any.

The paper picks the best demo by Ũ (Eq. 8) from MI and L1-L3 alone. Those losses are blind to a
slow wobble of the hand (a few mm over seconds: smooth, nearly closed, nearly symmetric), and
they move with the sample rate (a 15 Hz demo resampled to N samples has corners that L3 and MI
read). On sets drawn by a second, independent generator (steady and wobbly operators at
15-120 Hz, :mod:`bt_pipeline.testing.operator_sets`), Ũ put a wobbly demo first in 4 of 36
sets, and the steady demo, cleaned towards it, came out 8-25 x farther from its true shape.

The task's loop (its guide, or the loop learned from its demos:
:mod:`bt_pipeline.clean.loop_learn`) is the shape every demo means (under its demonstrator's
θ/ρ), so how closely a demo follows it is the project's fourth task loss, *shape*. Each demo's
kept raw samples are fitted to the loop under its θ/ρ (the given or pooled ones; only the
translation is free, no trimming of a misshapen side), and its *misfit* is the median distance
of the samples to that loop, as a share of its size. Against a loop learned from the demos,
θ and ρ are fitted too: that loop's frame is itself read off the demos, and a consensus that
leans to a lopsided majority is several % off in scale at the stated ρ, which held fixed made
the one demo drawn as meant the farthest (single-loop varied wiping, seed 2: the expert-like
demo 2.74 % off, the others 0.80-2.04 %; the set was cleaned towards a lopsided demo).
A demo is eligible when its misfit is at most 1.5 x the set's smallest plus 0.1 % of the size,
against a guide and a learned loop alike; the best is the eligible demo with the highest Ũ.
(Against a learned loop the gate once took 3 x: with θ/ρ held at the stated ones the
expert-like demo was not always the closest. Read with θ/ρ fitted it is the closest in all 96
random and varied sets of ``bench_clean_human.py``'s D1 and D2 seeds, and 3 x let a wobbly
demo with a higher Ũ in over the steady one in two sets of the second generator on loops
written apart, ``bench_operator_sets.py --shapes lab``: the steady demo then cleaned to
5-12 x its raw error.) Ranks list the eligible demos first, by Ũ, then the others, by
Ũ. Ũ itself, the scores and Stage 2's normaliser are unchanged; ``bt score`` ranks the same way
(:mod:`bt_pipeline.clean.selection`), and ``bt score --whole-demos`` as the paper does.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from bt_pipeline.clean.guide_fit import PreferenceRange, fit_guide
from bt_pipeline.clean.guide_track import nearest_distance
from bt_pipeline.clean.periodic import PreferenceEstimate
from bt_pipeline.clean.segment import Segment
from bt_pipeline.data.demo import Demo
from bt_pipeline.data.records import FloatArray
from bt_pipeline.score.utility import TaskScores

MISFIT_FACTOR = 1.5
"""A demo is eligible as the best when its misfit is at most this times the set's smallest"""
MISFIT_FLOOR = 0.001
"""plus this share of the guide's size."""
_GUIDE_POINTS = 2048  # Dense guide for the distances (< 0.3 mm spacing at ρ = 1).
_ANY_PREFERENCE = PreferenceRange(180.0, 0.05, 20.0)  # A learned loop's fit is not bounded.


def guide_misfit(demo: Demo, segment: Segment, preference: PreferenceEstimate) -> float:
    """Median distance of a span demo's raw samples to the guide under its θ/ρ [share of size];
    to a learned loop under the similarity that fits it best (module doc).

    Args:
        demo: The demo's kept span (:func:`~bt_pipeline.clean.periodic.span_demo`): its raw
            samples are the span's.
        segment: Its segment; the guide fit's translation is the starting point.
        preference: The θ/ρ the cleaner uses for it (held fixed against a guide; the
            translation is fitted).
    """
    positions, _ = demo.raw_samples()
    # A learned loop's frame is itself read off the demos: its shape alone is compared.
    learned = not segment.guide.loop.is_guide
    fit = fit_guide(
        positions,
        segment.guide.loop,
        demo.label,
        allowed=_ANY_PREFERENCE if learned else None,
        theta_deg=None if learned else preference.theta_deg,
        rho=None if learned else preference.rho,
        initial=segment.guide,
        consensus=False,
    )
    distances = nearest_distance(fit.guide(_GUIDE_POINTS), positions)
    return float(np.median(distances)) / fit.size_m


def eligible(misfits: FloatArray, factor: float = MISFIT_FACTOR) -> np.ndarray:
    """Which demos may be the best, from their misfits, shape (M,) (module doc)."""
    misfits = np.asarray(misfits, dtype=np.float64)
    return misfits <= factor * float(np.min(misfits)) + MISFIT_FLOOR


def gate_reason(first: str, best: str, misfit_first: float, misfit_best: float, loop: str) -> str:
    """Why `best` is the best demo though `first` has the highest Ũ: the one line ``bt score``,
    ``bt clean``, the Rerun summaries, ``bt view`` and the app's table show beside the ★.

    Args:
        first: The demo with the highest Ũ (a label or a name).
        best: The best demo.
        misfit_first: `first`'s misfit (:func:`guide_misfit`, a share of the loop's size).
        misfit_best: `best`'s misfit.
        loop: What the demos were measured against: ``"guide"`` or ``"learned"``.
    """
    return (
        f"{first} has the highest Ũ but follows the task's {loop} loop less closely "
        f"(median {100 * misfit_first:.2f} % of its size off, against "
        f"{100 * misfit_best:.2f} %): {best} is the best demo"
    )


def gate_best(
    scores: TaskScores, misfits: Sequence[float], factor: float = MISFIT_FACTOR
) -> TaskScores:
    """`scores` with the best demo and the ranks taken among the eligible demos first."""
    allowed = eligible(np.asarray(misfits, dtype=np.float64), factor)
    utility = np.array([s.utility for s in scores.scores])
    order = np.lexsort((-utility, ~allowed))  # Eligible first, then by Ũ; stable on ties.
    ranks = np.empty(len(order), dtype=np.int64)
    ranks[order] = np.arange(1, len(order) + 1)
    return dataclasses.replace(
        scores,
        scores=tuple(
            dataclasses.replace(s, rank=int(r)) for s, r in zip(scores.scores, ranks, strict=True)
        ),
        best_index=int(order[0]),
    )
