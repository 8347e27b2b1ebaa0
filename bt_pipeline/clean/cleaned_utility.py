"""Ũ and displacement of the cleaned demos, on the raw demos' scale (issue 37, "one Ũ").

A cleaned demo is read as ``bt score`` reads a raw one: its span, on its raw sample times, gives
the ranking metrics (:func:`bt_pipeline.clean.selection.ranked_metrics`), and its Ũ is Eq. (8)
against the raw set's frozen normaliser (:func:`bt_pipeline.score.utility.utilities_against`),
the function every view calls. So "Ũ raw" and "Ũ cleaned" of ``bt clean`` are on one scale, and
"Ũ raw" is ``bt score``'s. Stage 2 maximises its own objective (L1-L4 on the N samples, its
normalisers, each demo's β), and the default variant pulls each sample towards the demo's
aligned reference; where that costs Ũ (the reference reads less symmetric or smooth along the
path than the demo did, or its MI falls), :func:`cleaned_utilities` says so in a note naming
the terms. How far cleaning moved a demo is measured against its raw samples at the same times
(:func:`moved_from_raw`), beside L4, which is measured against the reference the cleaned demo
was pulled to.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from bt_pipeline.clean.periodic import output_on_raw_times
from bt_pipeline.clean.segment import Segment
from bt_pipeline.clean.selection import ranked_metrics
from bt_pipeline.data.demo import Demo
from bt_pipeline.data.records import FloatArray
from bt_pipeline.score.utility import (
    RawMetrics,
    ScoreConfig,
    TaskScores,
    utilities_against,
    utility_terms,
)


def on_raw_times(demo: Demo, cleaned: FloatArray, passed: bool) -> tuple[FloatArray, FloatArray]:
    """A span's cleaned samples (N, 2) at its raw sample times: (times (K,) [s], (K, 2) [m]);
    its raw samples as they are when it was `passed` through unrefined."""
    if passed:
        positions, times = demo.raw_samples()
        return times, positions
    return output_on_raw_times(demo, cleaned)


def moved_from_raw(demo: Demo, cleaned_on_raw: FloatArray) -> tuple[float, float]:
    """(mean, max) distance [m] of a span's raw samples from its cleaned ones at the same times."""
    raw, _ = demo.raw_samples()
    distances = np.linalg.norm(np.asarray(cleaned_on_raw) - raw, axis=1)
    return float(np.mean(distances)), float(np.max(distances))


def cleaned_span(demo: Demo, cleaned: FloatArray, passed: bool) -> Demo:
    """The span demo `demo` with its cleaned samples: N of them, shape (N, 2) [m], and the same
    at its raw sample times (what the ranking metrics read), θ/ρ as used."""
    times, on_raw = on_raw_times(demo, cleaned, passed)
    return dataclasses.replace(
        demo, positions=np.asarray(cleaned), raw_positions=on_raw, raw_times_s=times
    )


def cleaned_utilities(
    demos: Sequence[Demo],
    cleaned: FloatArray,
    passed: int | None,
    segments: Sequence[Segment],
    scores: TaskScores,
    config: ScoreConfig,
    axis_deg: float,
) -> tuple[FloatArray, list[str]]:
    """Ũ of each cleaned demo against the raw set's normaliser, and a note per lowered Ũ.

    Args:
        demos: The raw span demos, as selection scored them.
        cleaned: Their cleaned N samples, shape (M, N, 2) [m].
        passed: Index of the demo passed through unrefined (its raw samples kept), or None.
        segments: Each demo's segment (its loops).
        scores: Selection's scores of the raw spans (their Ũ and the set's normaliser).
        config: The score settings selection used.
        axis_deg: L1's axis in the task loop's frame (selection's).

    Returns:
        Ũ per cleaned demo, shape (M,), and the notes of :func:`utility_notes`.
    """
    ranked = []
    for i, demo in enumerate(demos):
        span = cleaned_span(demo, cleaned[i], i == passed)
        ranked.append(ranked_metrics(span, segments[i], config, axis_deg)[1])
    utility = utilities_against(scores.normaliser, ranked, config)
    return utility, utility_notes(demos, scores, ranked, config)


_TERMS = ("I(S; A)", "L1 symmetry", "L2 closure", "L3 smoothness")
"""Names of Ũ's terms, in :func:`~bt_pipeline.score.utility.utility_terms` order."""


def utility_notes(
    demos: Sequence[Demo],
    scores: TaskScores,
    cleaned: Sequence[RawMetrics],
    config: ScoreConfig,
) -> list[str]:
    """One line per demo whose Ũ cleaning lowered (by 0.0005 or more): by how much and which of
    Ũ's terms cost it. Stage 2 optimises its own objective (with L4, the pull to the demo's
    aligned reference, and the demo's final β); Ũ reads the span as the ranking does, so a
    demo pulled onto its reference can lose Ũ where the reference is less smooth or symmetric
    than the demo was, or where its MI falls."""
    raw = [s.raw for s in scores.scores]
    before = utility_terms(scores.normaliser, raw, config)
    after = utility_terms(scores.normaliser, cleaned, config)
    notes = []
    for i, demo in enumerate(demos):
        change = float(after[i].sum() - before[i].sum())
        if change > -5e-4:
            continue
        deltas = after[i] - before[i]
        worst = [k for k in np.argsort(deltas) if deltas[k] < -5e-4][:2]
        costs = ", ".join(f"{_TERMS[k]} {deltas[k]:+.3f}" for k in worst)
        notes.append(
            f"{demo.label}: cleaning lowered its Ũ from {before[i].sum():.3f} to "
            f"{after[i].sum():.3f} ({costs}); Stage 2 optimises its own objective (with L4, "
            "the pull to its aligned reference), and the cleaned path is read as bt score "
            "reads the raw ones"
        )
    return notes
