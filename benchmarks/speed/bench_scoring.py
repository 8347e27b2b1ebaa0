"""Benchmark of the demo utility score: KSG mutual information and scoring a D2-like set.

Run: ``python benchmarks/speed/bench_scoring.py [--repeats 15]``. Prints a Markdown table of medians
over `--repeats` runs, each against a baseline timed in the same process (ratios are robust to a
busy machine, absolute times are not):

* ``mutual_information`` (cKDTree KSG-1) at N = 300 and N = 2000 with 2-D states and 2-D actions,
  against the O(N²) brute-force reference of the same estimator;
* the same on 1-D data with standardisation and jitter off, against scikit-learn's
  ``_compute_mi_cc`` (the two return the same value);
* ``score_demos`` on 20 demos × 300 samples (4 demonstrators × 5 demos, each with its own rotation,
  scale and noise level), the size of the paper's D2.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repo root: benchmarks.common

import numpy as np
from sklearn.feature_selection._mutual_info import _compute_mi_cc

from benchmarks.common.timing import median_ms
from bt_pipeline.data.demo import Demo
from bt_pipeline.data.tasks import default_plane
from bt_pipeline.score.mi import _mutual_information_bruteforce, mutual_information
from bt_pipeline.score.utility import score_demos

N_SAMPLES = 300


def gaussian_pairs(n: int, dims: int, r: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """S, A of shape (n, dims) with corr(s_j, a_j) = r."""
    rng = np.random.default_rng(seed)
    s = rng.standard_normal((n, dims))
    return s, r * s + math.sqrt(1.0 - r**2) * rng.standard_normal((n, dims))


def d2_like_demos(seed: int = 0) -> list[Demo]:
    """20 noisy closed figure-8 loops: 4 demonstrators (θ, ρ, noise) × 5 demos."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, N_SAMPLES)
    shape = np.column_stack([0.1 * np.sin(2 * np.pi * t), 0.05 * np.sin(4 * np.pi * t)])
    demonstrators = [
        (5.0, 1.0, 0.0005),
        (-5.0, 1.1, 0.002),
        (10.0, 1.2, 0.004),
        (-10.0, 1.3, 0.008),
    ]
    demos = []
    for i, (theta_deg, rho, noise) in enumerate(demonstrators):
        a = math.radians(theta_deg)
        rotation = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        for j in range(5):
            drift = np.outer(t, rng.normal(0.0, 0.01, 2))  # an open end for some demos
            positions = rho * shape @ rotation.T + drift + rng.normal(0.0, noise, shape.shape)
            demos.append(
                Demo(
                    positions=positions,
                    task="wiping",
                    file="",
                    name=f"demo_{5 * i + j}",
                    demonstrator=f"instructor_{i}",
                    theta_deg=theta_deg,
                    rho=rho,
                    plane=default_plane("wiping"),
                )
            )
    return demos


def main() -> None:
    parser = argparse.ArgumentParser(description="Benchmark the demo utility score.")
    parser.add_argument("--repeats", type=int, default=15, help="timed runs per case (median)")
    repeats = parser.parse_args().repeats

    rows: list[tuple[str, float, str, float]] = []
    for n in (300, 2000):
        s, a = gaussian_pairs(n, 2, 0.5, seed=n)
        rows.append(
            (
                f"KSG-1, N = {n}, 2 + 2 dims",
                median_ms(lambda s=s, a=a: mutual_information(s, a), repeats),
                "brute-force O(N²) KSG-1",
                median_ms(lambda s=s, a=a: _mutual_information_bruteforce(s, a), repeats),
            )
        )
    for n in (300, 2000):
        s, a = gaussian_pairs(n, 1, 0.5, seed=n + 1)
        x, y = s[:, 0], a[:, 0]
        mine = mutual_information(x, y, standardise=False, jitter=0.0)
        assert mine == _compute_mi_cc(x, y, 3)  # same estimate, so the timing compares like work
        rows.append(
            (
                f"KSG-1, N = {n}, 1 + 1 dims, no jitter",
                median_ms(
                    lambda x=x, y=y: mutual_information(x, y, standardise=False, jitter=0.0),
                    repeats,
                ),
                "sklearn `_compute_mi_cc`",
                median_ms(lambda x=x, y=y: _compute_mi_cc(x, y, 3), repeats),
            )
        )

    demos = d2_like_demos()
    score_ms = median_ms(lambda: score_demos(demos), repeats)
    ksg_ms = median_ms(lambda: [mutual_information(d.positions, d.actions) for d in demos], repeats)
    best = score_demos(demos).best

    print(f"Median of {repeats} runs (shared machine: compare ratios, not absolute times).\n")
    print("| case | bt [ms] | baseline | baseline [ms] | baseline / bt |")
    print("|---|---|---|---|---|")
    for case, ours, baseline, theirs in rows:
        print(f"| {case} | {ours:.2f} | {baseline} | {theirs:.2f} | {theirs / ours:.2f} |")
    print(
        f"| score_demos, 20 demos × {N_SAMPLES} | {score_ms:.1f} | KSG-1 alone on the 20 demos "
        f"| {ksg_ms:.1f} | {ksg_ms / score_ms:.2f} |"
    )
    print(
        f"\nBest demo of the D2-like set: {best.demo.name} ({best.demo.demonstrator}), "
        f"Ũ = {best.utility:.3f}."
    )


if __name__ == "__main__":
    main()
