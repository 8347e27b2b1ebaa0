"""Peak memory of Stage 2 as a task's M grows: one batch against chunks of at most K (issue 14).

For each M of ``--sizes``, a fresh child process refines M synthetic demos of 300 samples (noisy,
drifting figure-8s around known references, θ_i from ±10°) either as one batch (``refine_demos``,
as before chunking) or in chunks of at most K demos sharing the frozen task-wide scales
(``refine_demos`` per chunk with ``task_scales``, as ``bt clean``'s chunk jobs do), and reports
the child's peak RSS (``ru_maxrss``) and its growth over the RSS before refining (imports and
data). One epoch's autograd graph is freed before the next, so a few epochs (the first one with
the I_KL guard) show the peak.

    python benchmarks/scale/bench_chunk_memory.py --sizes 256,768,1536 --chunk-size 256 --epochs 2

The numbers in docs/scale.md come from this script; it is a benchmark, not a test.
"""

from __future__ import annotations

import argparse
import itertools
import resource
import subprocess
import sys

import numpy as np
import psutil

N = 300


def demo_set(m: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions and references, shape (m, N, 2) [m], and θ_i [deg], shape (m,)."""
    rng = np.random.default_rng(seed)
    phase = 2 * np.pi * np.arange(N) / N
    thetas = rng.uniform(-10.0, 10.0, m)
    a = np.radians(thetas)[:, None]
    u, v = 0.08 * np.sin(phase), 0.05 * np.sin(2 * phase)
    refs = np.stack([u * np.cos(a) - v * np.sin(a), u * np.sin(a) + v * np.cos(a)], axis=-1)
    drift = np.linspace(0.0, 1.0, N)[None, :, None] * rng.uniform(-0.015, 0.015, (m, 1, 2))
    positions = refs + rng.normal(0.0, 0.003, refs.shape) + drift
    return positions, refs, thetas


def child(mode: str, m: int, chunk_size: int, epochs: int) -> None:
    """Refine one set in this process and print 'peak_rss_bytes growth_bytes'."""
    from bt_pipeline.clean.stage2.chunked import chunk_sizes
    from bt_pipeline.clean.stage2.config import RefineConfig
    from bt_pipeline.clean.stage2.refiner import refine_demos
    from bt_pipeline.clean.stage2.scales import refine_normaliser, task_scales
    from bt_pipeline.score.losses import closure_loss, smoothness_loss, symmetry_loss
    from bt_pipeline.score.utility import Normaliser

    x, refs, thetas = demo_set(m)
    raw = np.array(
        [
            [0.0, symmetry_loss(p, t), closure_loss(p), smoothness_loss(p)]
            for p, t in zip(x, thetas, strict=True)
        ]
    )
    shape = np.linalg.norm(x - refs, axis=-1).mean(axis=1)
    normaliser = refine_normaliser(Normaliser.from_values(raw), shape)
    config = RefineConfig(epochs=epochs, patience=0)
    sizes = (m,) if mode == "batch" else chunk_sizes(m, chunk_size)
    spans = list(itertools.pairwise(int(e) for e in np.cumsum((0, *sizes))))
    scales = task_scales(x, refs, block=chunk_size)
    base = psutil.Process().memory_info().rss
    for a, b in spans:

        def rewards(paths: np.ndarray, refs: np.ndarray = refs[a:b]) -> np.ndarray:
            return np.exp(-np.sum((paths - refs) ** 2, axis=-1) / 2e-5).mean(axis=1)

        refine_demos(
            x[a:b],
            refs[a:b],
            thetas_deg=thetas[a:b],
            best_index=0 if a == 0 else None,
            reward_fn=rewards,
            normaliser=normaliser,
            config=config,
            scales=None if mode == "batch" else scales,
        )
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(peak, peak - base)


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--sizes", default="256,768,1536")
    parser.add_argument("--chunk-size", type=int, default=256)
    parser.add_argument("--epochs", type=int, default=2)
    parser.add_argument("--child", nargs=4, metavar=("MODE", "M", "K", "EPOCHS"))
    args = parser.parse_args()
    if args.child:
        mode, m, k, epochs = args.child
        child(mode, int(m), int(k), int(epochs))
        return
    print("| M | Stage 2 as | peak RSS [MiB] | growth while refining [MiB] |")
    print("|---|---|---|---|")
    for m in (int(s) for s in args.sizes.split(",")):
        for mode in ("batch", "chunks"):
            label = "one batch" if mode == "batch" else f"chunks of ≤ {args.chunk_size}"
            command = [sys.executable, __file__, "--child", mode, str(m)]
            command += [str(args.chunk_size), str(args.epochs)]
            out = subprocess.run(command, check=True, capture_output=True, text=True).stdout
            peak, growth = (int(v) for v in out.split())
            print(f"| {m} | {label} | {peak / 2**20:.0f} | {growth / 2**20:.0f} |", flush=True)


if __name__ == "__main__":
    main()
