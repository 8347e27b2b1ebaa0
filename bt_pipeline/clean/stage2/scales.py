"""What Stage 2 freezes over a whole task before refining: the normaliser and the task scales.

Both are computed once over all of a task's raw demos and handed to every chunk
(bt_pipeline.clean.stage2.chunked). This module imports no torch at import time: the process that
drives a large task (``bt clean`` with ``--executor processes`` or ``ray``) computes these here
and sends the I_KL evaluations, the one part that needs torch, out as jobs, so it never loads
torch itself (about 140 MiB of private memory per process, docs/scale.md)::

    x (M, N, 2) ─blocks of K─▶ mi_kl_block (jobs, or here) ─▶ I_KL (M,) ─▶ min, max - min
    x, x^aligned ─────────────────────────────────────────────▶ centre, scale, pull RMS
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from bt_pipeline.clean.stage2.config import TaskScales
from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError, DemoError
from bt_pipeline.execute import ExecutorConfig, run_jobs
from bt_pipeline.score.utility import Normaliser


def refine_normaliser(normaliser: Normaliser, shape_losses: ArrayLike) -> Normaliser:
    """The selection stage's raw-set normaliser plus the shape loss L4 of the same raw demos.

    Args:
        normaliser: Raw-set normaliser of :mod:`bt_pipeline.score.utility` (MI, L1, L2, L3).
        shape_losses: L4 of each raw demo against its aligned reference, shape (M,), in [m].

    Returns:
        A normaliser with the extra column ``"shape"``.
    """
    if "shape" in normaliser.names:
        raise ConfigError(f"the normaliser already has a shape column: {normaliser.names}")
    values = np.asarray(shape_losses, dtype=np.float64)
    if values.ndim != 1 or values.size == 0 or not np.all(np.isfinite(values)):
        raise DemoError(f"shape_losses must be finite with shape (M,); got {values.shape}")
    return Normaliser(
        names=(*normaliser.names, "shape"),
        min=np.append(normaliser.min, values.min()),
        max=np.append(normaliser.max, values.max()),
        delta=normaliser.delta,
    )


def mi_kl_block(block: tuple[FloatArray, int]) -> np.ndarray:
    """I_KL of a block of demos (a job): (positions (B, N, 2) [m], torch threads) -> (B,) float32.

    The stand-in for I(S; A) of :func:`bt_pipeline.clean.stage2.losses.mi_kl`, evaluated in
    float32 without gradients, as the refiner does.
    """
    import torch  # here, not at import: only the process that evaluates I_KL loads torch

    from bt_pipeline.clean.stage2 import losses as tl

    positions, threads = block
    saved = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        with torch.no_grad():
            return tl.mi_kl(torch.as_tensor(positions, dtype=torch.float32)).numpy()
    finally:
        torch.set_num_threads(saved)


def task_scales(
    positions: ArrayLike,
    references: ArrayLike,
    *,
    block: int = 256,
    threads: int = 1,
    executor: ExecutorConfig | None = None,
) -> TaskScales:
    """Stage 2's standardisation over all of a task's raw demos, frozen for every chunk.

    Args:
        positions: Raw demos x_i, shape (M, N, 2), in [m].
        references: Their aligned references x_i^aligned, shape (M, N, 2), in [m].
        block: Demos per I_KL evaluation (bounds the memory it takes; values do not depend on it
            beyond float32 rounding).
        threads: Torch CPU threads for I_KL.
        executor: Where the I_KL blocks run when there are several (the same values, bit for
            bit); None: here.

    Returns:
        The centre, scale and pull RMS of the network input and the raw I_KL range (Eq. 7).
    """
    x = np.asarray(positions, dtype=np.float64)
    pull = np.asarray(references, dtype=np.float64) - x
    blocks: Sequence[tuple[FloatArray, int]] = [
        (x[i : i + block], threads) for i in range(0, x.shape[0], block)
    ]
    if executor is None or len(blocks) <= 1:
        values = [mi_kl_block(b) for b in blocks]
    else:
        values = run_jobs(mi_kl_block, blocks, executor, label=lambda b: f"I_KL of {len(b[0])}")
    mi = np.concatenate(values)  # float32, as the refiner's own I_KL
    return TaskScales(
        centre=x.reshape(-1, 2).mean(axis=0),
        scale=float(x.std()) or 1.0,
        # Unit RMS, so Adam's ~lr-sized first steps already move a sizeable part of the way.
        pull_rms=max(float(np.sqrt(np.mean(pull**2))), 1e-12),
        mi_low=float(mi.min()),
        mi_span=float(mi.max() - mi.min()),
    )
