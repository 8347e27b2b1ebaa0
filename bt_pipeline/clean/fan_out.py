"""The per-demo steps of one large task as jobs of the executor, a chunk of demos per job.

A task of more than K demos is cleaned by the ``bt clean`` process itself (its Stage 2 chunks go
out as jobs: bt_pipeline.clean.stage2.chunked). Most of what it does around Stage 2 is per demo,
with only small task-wide reductions in between, so that goes out as jobs too (issue 14)::

    demos ─chunks of ≤ K─▶ segment_demo each ─▶ segments          (jobs)
    pool θ/ρ per demonstrator, score, best demo, Stage 1 of the best demo   (here: reductions)
    (demo, θ/ρ, offset) ─chunks─▶ retime_reference each ─▶ x_i^aligned (jobs)
    Stage 2 in chunks                                                   (jobs)
    (x_i, x̂_i, x_i^aligned, θ_i) ─chunks─▶ demo_metrics each, raw and cleaned (jobs)

Each step is a pure function of one demo, so its results are those of the serial loop, bit for
bit, whichever executor runs the chunks (tested in tests/pipeline/clean/test_fan_out.py).
Chunks follow :func:`~bt_pipeline.clean.stage2.chunked.chunk_sizes` (contiguous, near-equal,
at most K).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import numpy as np

from bt_pipeline.clean.guide_fit import GuideFit, PreferenceRange
from bt_pipeline.clean.periodic import PreferenceEstimate, retime_reference, segment_all
from bt_pipeline.clean.segment import Segment
from bt_pipeline.clean.stage2.chunked import chunk_sizes
from bt_pipeline.data.demo import Demo
from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.data.records import FloatArray
from bt_pipeline.execute import ExecutorConfig, run_jobs
from bt_pipeline.score.losses import closure_loss, smoothness_loss, symmetry_loss
from bt_pipeline.score.mi import mutual_information

T = TypeVar("T")
S = TypeVar("S")
R = TypeVar("R")

PerChunk = Callable[[Sequence[T], S], list[R]]
"""A step over a chunk: (the chunk's per-demo items, what every demo shares) -> one result each."""


def per_demo(
    step: PerChunk[T, S, R],
    items: Sequence[T],
    shared: S,
    *,
    executor: ExecutorConfig | None,
    chunk_size: int,
    label: str = "",
) -> list[R]:
    """`step` over `items` in chunks of at most `chunk_size`, as jobs of `executor`.

    Args:
        step: A module-level function (it is pickled by reference for other processes).
        items: One item per demo, in input order.
        shared: What every chunk needs (pickled once per chunk).
        executor: Where the chunks run; None (or a single chunk): here, in one call.
        chunk_size: K, most demos per job.
        label: The task and step, for progress and error messages.

    Returns:
        One result per item, in input order.
    """
    sizes = chunk_sizes(len(items), chunk_size) if items else ()
    if executor is None or len(sizes) <= 1:
        return list(step(items, shared))
    jobs: list[tuple[PerChunk[T, S, R], Sequence[T], S, str]] = []
    start = 0
    for c, size in enumerate(sizes):
        name = f"{label} chunk {c + 1}/{len(sizes)} (demos {start}-{start + size - 1})"
        jobs.append((step, items[start : start + size], shared, name.strip()))
        start += size
    results = run_jobs(_run_chunk, jobs, executor, label=lambda job: job[3])
    return [r for chunk in results for r in chunk]


def _run_chunk(job: tuple[PerChunk[Any, Any, R], Sequence[Any], Any, str]) -> list[R]:
    step, items, shared, _ = job
    return list(step(items, shared))


def demo_metrics(
    positions: FloatArray,
    reference: FloatArray,
    theta_deg: float,
    k: int,
    alphas: tuple[float, float, float],
) -> tuple[float, float, float, float, float]:
    """Raw (MI, L1, L2, L3, L4) of one demo in task coordinates, shape (N, 2)."""
    times = np.linspace(0.0, 1.0, positions.shape[0])
    actions = np.zeros_like(positions)
    actions[:-1] = np.diff(positions, axis=0) / np.diff(times)[:, None]
    return (
        mutual_information(positions, actions, k=k),
        symmetry_loss(positions, theta_deg),
        closure_loss(positions),
        smoothness_loss(positions, alphas),
        float(np.mean(np.linalg.norm(positions - reference, axis=1))),  # Eq. (9), aligned.
    )


def segment_step(
    demos: Sequence[Demo],
    shared: tuple[PreferenceRange | None, LoopShape | None, dict[str, GuideFit] | None],
) -> list[Segment]:
    """The periodic span of each demo (:func:`~bt_pipeline.clean.periodic.segment_all`), from
    (the allowed θ/ρ, the task's loop: None for its guide, fits to start from by demo label)."""
    allowed, loop, hints = shared
    return list(segment_all(demos, allowed, loop, hints))


def retime_step(
    items: Sequence[tuple[Demo, PreferenceEstimate]],
    shared: tuple[FloatArray, FloatArray],
) -> list[FloatArray]:
    """x_i^aligned of each (demo, θ/ρ): x^d retimed to the demo, about c.

    `shared` is (x^d, c): the canonical motion, shape (N, 2), and the centre, shape (2,) [m].
    """
    global_shape, centre = shared
    return [retime_reference(global_shape, p.theta_deg, p.rho, centre, demo) for demo, p in items]


def metrics_step(
    items: Sequence[tuple[FloatArray, FloatArray, FloatArray, float]],
    shared: tuple[int, tuple[float, float, float]],
) -> list[tuple[tuple[float, ...], tuple[float, ...]]]:
    """(MI, L1, L2, L3, L4) of each (raw x_i, cleaned x̂_i, x_i^aligned, θ_i), raw and cleaned.

    `shared` is (k, alphas): the KSG neighbours and the smoothness weights of L3.
    """
    k, alphas = shared
    return [
        (
            demo_metrics(raw, reference, theta, k, alphas),
            demo_metrics(cleaned, reference, theta, k, alphas),
        )
        for raw, cleaned, reference, theta in items
    ]
