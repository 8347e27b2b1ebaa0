"""Stage 2 of a large task in chunks of at most K demos, each with its own network (issue 14).

One batch of M demos holds M LSTM sequences, their autograd graph and k-NN searches in memory at
once, so a task's Stage 2 memory grows with M. Here the task's demos are split, in input order,
into ceil(M / K) contiguous chunks of near-equal size (at most K each). What the chunks share is
computed once over the whole task and frozen:

    Stage 1 (whole task): V_E, x^d, c, θ_i/ρ_i, x_i^aligned ───┐
    frozen normalisers (Eq. 7, whole raw set): L1..L4 min/max ─┼─▶ ChunkJob c (its demos only)
    TaskScales (whole raw set): input centre/scale, pull RMS,  │   ──refine_chunk──▶ result c
        I_KL min/max ──────────────────────────────────────────┘
    RefineResult 0..C-1 ──merge_results──▶ one RefineResult, demos in input order

Each chunk trains its own refinement network, seeded from the task's seed (chunk 0 with the seed
itself, so a task of M ≤ K demos is refined exactly as one batch). The best demo belongs to the
chunk its index falls in, and is passed through there (or refined, in the paper variant); the
other chunks do not hold it: they see it only through what Stage 1 built from it (V_E, the
aligned references) and through the frozen normalisers, as every demo does. A demo's Ũ (Eq. 8)
and β update depend only on its own path and these frozen values, so what chunking changes is the
network each demo's correction comes from (it is fitted to its chunk's demos) and the number of
demos each Adam step averages over (docs/scale.md measures the effect on quality).

A chunk job carries its own demos and the O(1) part of Stage 1 (V_E's grid, the best demo's frame),
not the task's whole Stage 1 result: about 0.12 MB plus 10 kB per demo of 300 samples, pickled.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from bt_pipeline.clean.stage1.alignment import rotation_matrix
from bt_pipeline.clean.stage1.extract import Stage1Result
from bt_pipeline.clean.stage1.value_map import ValueMap
from bt_pipeline.clean.stage2.config import EpochStats, RefineConfig, RefineResult, TaskScales
from bt_pipeline.clean.stage2.scales import task_scales
from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError, DemoError
from bt_pipeline.execute import ExecutorConfig, run_jobs
from bt_pipeline.score.utility import Normaliser

DEFAULT_CHUNK_SIZE = 256
"""K, most demos refined by one network (``bt clean --chunk-size``)."""


def chunk_sizes(m: int, chunk_size: int) -> tuple[int, ...]:
    """Sizes of the ceil(m / K) contiguous chunks of m demos, near-equal, in input order."""
    if chunk_size < 1:
        raise ConfigError(f"--chunk-size must be ≥ 1; got {chunk_size}")
    if m < 1:
        raise DemoError("no demos to refine")
    n = -(-m // chunk_size)
    return tuple(m // n + (1 if c < m % n else 0) for c in range(n))


def chunk_seed(seed: int, chunk: int) -> int:
    """The network seed of chunk `chunk` of a task seeded with `seed` (chunk 0: the seed)."""
    if chunk == 0:
        return seed
    return int(np.random.SeedSequence([seed, chunk]).generate_state(1, np.uint32)[0])


@dataclass(frozen=True, eq=False)
class BestFrameRewards:
    """R̄_i (Eq. 11) of a chunk's demos: each path mapped into the best demo's frame, then V_E.

    The map of :meth:`Stage1Result.to_best_frame`, x ↦ c + ρ_best R(θ_best) R(−θ_i) (x − c) / ρ_i,
    holding only what a chunk needs instead of the task's M aligned references.
    """

    value_map: ValueMap
    """V_E, in the best demo's frame."""
    centre: FloatArray
    """c, shape (2,), in [m]."""
    theta_best: float
    """θ of the best demo [deg]."""
    rho_best: float
    """ρ of the best demo."""
    thetas: FloatArray
    """θ_i of the chunk's demos, shape (k,), in [deg]."""
    rhos: FloatArray
    """ρ_i of the chunk's demos, shape (k,)."""
    l1_thetas: FloatArray
    """The turns L1 de-rotates the chunk's demos by, shape (k,), in [deg]
    (:meth:`Stage1Result.l1_thetas`)."""

    @classmethod
    def of(cls, stage1: Stage1Result, start: int, stop: int) -> BestFrameRewards:
        """The rewards of demos start..stop-1 of `stage1`'s task."""
        b = stage1.best_index
        return cls(
            stage1.value_map,
            stage1.centre,
            stage1.thetas[b],
            stage1.rhos[b],
            stage1.thetas[start:stop],
            stage1.rhos[start:stop],
            stage1.l1_thetas()[start:stop],
        )

    def __call__(self, positions: FloatArray) -> FloatArray:
        """R̄ per path, paths (k, N, 2) [m] -> (k,) in [0, 1]."""
        p = np.asarray(positions, dtype=np.float64)
        if p.ndim != 3 or p.shape[0] != self.thetas.shape[0]:
            raise ConfigError(f"positions must have shape ({self.thetas.shape[0]}, N, 2)")
        mapped = np.empty_like(p)
        for i in range(p.shape[0]):
            scale = self.rho_best / self.rhos[i]
            rotation = rotation_matrix(float(self.theta_best - self.thetas[i]))
            mapped[i] = self.centre + scale * (p[i] - self.centre) @ rotation.T
        return self.value_map.mean_rewards(mapped)


@dataclass(frozen=True, eq=False)
class ChunkJob:
    """Everything one chunk's refinement needs (picklable: it may run in another process)."""

    label: str
    """Names the chunk in progress and error messages (task, chunk, demo range)."""
    positions: FloatArray
    """The chunk's raw demos, shape (k, N, 2), in [m]."""
    references: FloatArray
    """Their aligned references x_i^aligned, shape (k, N, 2), in [m]."""
    best_index: int | None
    """Index of the task's best demo inside the chunk; None when another chunk holds it."""
    rewards: BestFrameRewards
    """R̄ of the chunk's demos (their θ_i are ``rewards.thetas``)."""
    normaliser: Normaliser
    """The task's frozen raw-set normaliser (MI, L1..L4)."""
    scales: TaskScales
    """The task's frozen Stage 2 standardisation."""
    config: RefineConfig
    """Refinement settings, with the chunk's seed."""


def refine_chunk(
    job: ChunkJob, on_epoch: Callable[[EpochStats], None] | None = None
) -> RefineResult:
    """Refine one chunk with its own network (a job for :func:`bt_pipeline.execute.run_jobs`)."""
    # Imported here: the process that only drives chunks elsewhere never loads torch.
    from bt_pipeline.clean.stage2.refiner import refine_demos

    return refine_demos(
        job.positions,
        job.references,
        thetas_deg=job.rewards.l1_thetas,
        best_index=job.best_index,
        reward_fn=job.rewards,
        normaliser=job.normaliser,
        config=job.config,
        on_epoch=on_epoch,
        scales=job.scales,
    )


def chunk_jobs(
    positions: ArrayLike,
    stage1: Stage1Result,
    *,
    normaliser: Normaliser,
    config: RefineConfig,
    chunk_size: int,
    label: str = "",
    executor: ExecutorConfig | None = None,
) -> list[ChunkJob]:
    """Split a task's Stage 2 into chunk jobs sharing its Stage 1 and frozen normalisers.

    Args:
        positions: The task's raw demos x_i, shape (M, N, 2), in [m].
        stage1: The task's Stage 1 result (aligned references, V_E, θ_i/ρ_i, best demo).
        normaliser: Frozen raw-set normaliser with the shape column (``refine_normaliser``).
        config: Refinement settings; chunk c gets the seed ``chunk_seed(config.seed, c)``.
        chunk_size: K, most demos per chunk.
        label: The task's name, for progress and error messages.
        executor: Where the task scales' I_KL blocks run (None: here; see
            :func:`~bt_pipeline.clean.stage2.scales.task_scales`).

    Raises:
        DemoError: `positions` do not match Stage 1's aligned references.
    """
    x = np.asarray(positions, dtype=np.float64)
    if x.ndim != 3 or x.shape != stage1.aligned.shape:
        raise DemoError(
            f"positions must match Stage 1's aligned references {stage1.aligned.shape}; got "
            f"{x.shape}"
        )
    sizes = chunk_sizes(x.shape[0], chunk_size)
    scales = task_scales(
        x, stage1.aligned, block=chunk_size, threads=config.threads, executor=executor
    )
    jobs = []
    start = 0
    for c, size in enumerate(sizes):
        stop = start + size
        best = stage1.best_index - start if start <= stage1.best_index < stop else None
        jobs.append(
            ChunkJob(
                label=f"{label} chunk {c + 1}/{len(sizes)} (demos {start}-{stop - 1})".strip(),
                positions=x[start:stop],
                references=stage1.aligned[start:stop],
                best_index=best,
                rewards=BestFrameRewards.of(stage1, start, stop),
                normaliser=normaliser,
                scales=scales,
                config=dataclasses.replace(config, seed=chunk_seed(config.seed, c)),
            )
        )
        start = stop
    return jobs


def refine_in_chunks(
    positions: ArrayLike,
    stage1: Stage1Result,
    *,
    normaliser: Normaliser,
    config: RefineConfig,
    chunk_size: int = DEFAULT_CHUNK_SIZE,
    executor: ExecutorConfig | None = None,
    on_epoch: Callable[[EpochStats], None] | None = None,
    progress: bool = False,
    label: str = "",
) -> RefineResult:
    """Stage 2 of one task in chunks of at most `chunk_size` demos (see the module docstring).

    Args:
        positions: The task's raw demos x_i, shape (M, N, 2), in [m].
        stage1: The task's Stage 1 result.
        normaliser: Frozen raw-set normaliser with the shape column.
        config: Refinement settings (seeded; the result is deterministic for a seed and K).
        chunk_size: K, most demos per chunk (M ≤ K: one batch, as :func:`refine_demos`).
        executor: Where the chunks run when there are several; None runs them here, in turn.
        on_epoch: Called after every epoch of a chunk refined in this process.
        progress: Show a bar over the chunks on stderr (with an executor).
        label: The task's name, for progress and error messages.

    Returns:
        The refined demos in input order; ``chunk_sizes`` and ``chunk_epochs`` say how.
    """
    jobs = chunk_jobs(
        positions,
        stage1,
        normaliser=normaliser,
        config=config,
        chunk_size=chunk_size,
        label=label,
        executor=executor,
    )
    if executor is None or len(jobs) == 1:
        results = [refine_chunk(job, on_epoch) for job in jobs]
    else:
        results = run_jobs(
            refine_chunk,
            jobs,
            executor,
            desc=f"clean {label} (chunks)".replace("  ", " "),
            progress=progress,
            label=lambda job: job.label,
        )
    settings = config.resolve()
    counts = [
        job.positions.shape[0] - (job.best_index is not None and not settings.refine_best)
        for job in jobs
    ]
    return merge_results(results, counts)


def merge_results(results: Sequence[RefineResult], refined_counts: Sequence[int]) -> RefineResult:
    """One task's RefineResult from its chunks' results, demos in chunk order.

    Histories have as many rows as the longest chunk ran epochs; a chunk that stopped earlier
    keeps its last β and R̄ (a chunk with nothing to refine: β₀ and NaN R̄). The loss is the task's
    -mean_i Ũ_i over all refined demos: the chunks' losses weighted by how many demos each refined
    (`refined_counts`). A single chunk's result is returned as it is.
    """
    if len(results) != len(refined_counts) or not results:
        raise DemoError(f"{len(results)} chunk results for {len(refined_counts)} chunks")
    sizes = tuple(r.refined.shape[0] for r in results)
    chunk_epochs = tuple(r.epochs for r in results)
    first = results[0]
    if len(results) == 1:
        return dataclasses.replace(first, chunk_sizes=sizes, chunk_epochs=chunk_epochs)
    epochs = max(chunk_epochs)
    weights = np.array(refined_counts, dtype=np.float64)
    loss = np.zeros(epochs)
    for r, weight in zip(results, weights, strict=True):
        if weight > 0:
            loss += weight * _pad(r.loss_history[:, None], epochs, np.zeros(1))[:, 0]
    loss /= max(float(weights.sum()), 1.0)
    return RefineResult(
        refined=np.concatenate([r.refined for r in results]),
        betas=np.concatenate([r.betas for r in results]),
        beta_history=np.concatenate([_pad(r.beta_history, epochs, r.betas) for r in results], 1),
        loss_history=loss,
        reward_history=np.concatenate(
            [_pad(r.reward_history, epochs, np.full(r.betas.shape, np.nan)) for r in results], 1
        ),
        variant=first.variant,
        epochs=epochs,
        settings=first.settings,
        chunk_sizes=sizes,
        chunk_epochs=chunk_epochs,
    )


def _pad(history: FloatArray, rows: int, empty: FloatArray) -> FloatArray:
    """`history` (E, k) extended to (rows, k) by repeating its last row (`empty` when E = 0)."""
    last = history[-1] if history.shape[0] else empty
    extra = np.repeat(last[None, :], rows - history.shape[0], axis=0)
    return np.concatenate([history, extra], axis=0)
