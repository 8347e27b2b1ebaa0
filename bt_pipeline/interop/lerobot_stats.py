"""LeRobot's dataset statistics, computed the way lerobot 0.6.1 computes them.

A port of ``lerobot.datasets.compute_stats`` for numeric features (LeRobot itself cannot be
imported beside bt: it needs Python ≥ 3.12 and torch < 2.12). Per episode and feature: min, max,
mean, std (population), count and the quantiles q01, q10, q50, q90, q99 from a 5000-bin
histogram, exactly as ``RunningQuantileStats`` does for one batch; across episodes the
count-weighted merge of ``aggregate_feature_stats``. ``scripts/check_lerobot_export.py``
recomputes them with LeRobot's own code and compares.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
"""Quantiles LeRobot stores (keys ``q01`` ... ``q99``)."""
QUANTILE_BINS = 5000
"""Histogram bins of LeRobot's quantile estimate."""

Stats = dict[str, NDArray[np.floating]]
"""One feature's statistics: ``min``, ``max``, ``mean``, ``std``, ``count``, ``q01`` ... ``q99``."""


def quantile_key(q: float) -> str:
    """LeRobot's key of quantile `q`: 0.01 -> ``q01``."""
    return f"q{int(q * 100):02d}"


def feature_stats(values: NDArray[np.generic]) -> Stats:
    """Statistics of one feature over one episode (``get_feature_stats`` with axis 0).

    Args:
        values: Frames of the feature, shape (T,) for a scalar feature or (T, D) for a vector.

    Returns:
        Per-dimension statistics, each of shape (D,) (shape (1,) for a scalar feature); ``count``
        has shape (1,) and holds T.
    """
    array = np.asarray(values)
    batch = array.reshape(-1, 1) if array.ndim == 1 else array.reshape(array.shape[0], -1)
    batch = batch.astype(np.result_type(batch.dtype, np.float32), copy=False)
    count = batch.shape[0]
    if count < 2:
        mean = np.mean(batch, axis=0)
        stats: Stats = {
            "min": np.min(batch, axis=0),
            "max": np.max(batch, axis=0),
            "mean": mean,
            "std": np.std(batch, axis=0),
            "count": np.array([count]),
        }
        stats.update({quantile_key(q): mean.copy() for q in QUANTILES})
        return stats
    lo, hi = np.min(batch, axis=0), np.max(batch, axis=0)
    mean = np.mean(batch, axis=0)
    variance = np.mean(batch**2, axis=0) - mean**2
    stats = {
        "min": lo,
        "max": hi,
        "mean": mean,
        "std": np.sqrt(np.maximum(0, variance)),
        "count": np.array([count]),
    }
    edges = [
        np.linspace(lo[j] - 1e-10, hi[j] + 1e-10, QUANTILE_BINS + 1) for j in range(batch.shape[1])
    ]
    histograms = [np.histogram(batch[:, j], bins=edges[j])[0] for j in range(batch.shape[1])]
    for q in QUANTILES:
        stats[quantile_key(q)] = np.array(
            [_histogram_quantile(h, e, q * count) for h, e in zip(histograms, edges, strict=True)]
        )
    return stats


def aggregate(stats_list: Sequence[Stats]) -> Stats:
    """Merge per-episode statistics of one feature (``aggregate_feature_stats``).

    Means and quantiles are count-weighted, the variance by the parallel algorithm, min and max
    element-wise.
    """
    means = np.stack([s["mean"] for s in stats_list])
    variances = np.stack([s["std"] ** 2 for s in stats_list])
    counts = np.stack([s["count"] for s in stats_list])
    total = counts.sum(axis=0)
    while counts.ndim < means.ndim:
        counts = np.expand_dims(counts, axis=-1)
    mean = (means * counts).sum(axis=0) / total
    variance = ((variances + (means - mean) ** 2) * counts).sum(axis=0) / total
    merged: Stats = {
        "min": np.min(np.stack([s["min"] for s in stats_list]), axis=0),
        "max": np.max(np.stack([s["max"] for s in stats_list]), axis=0),
        "mean": mean,
        "std": np.sqrt(variance),
        "count": total,
    }
    for q in QUANTILES:
        key = quantile_key(q)
        merged[key] = (np.stack([s[key] for s in stats_list]) * counts).sum(axis=0) / total
    return merged


def to_json(stats: dict[str, Stats]) -> dict[str, dict[str, list[float]]]:
    """Statistics as JSON lists (``serialize_dict``), e.g. for ``meta/stats.json``."""
    return {
        feature: {key: np.asarray(value).tolist() for key, value in values.items()}
        for feature, values in stats.items()
    }


def _histogram_quantile(
    hist: NDArray[np.int64], edges: NDArray[np.float64], target: float
) -> float:
    """``RunningQuantileStats._compute_single_quantile``: interpolate within the target bin."""
    cumsum = np.cumsum(hist)
    idx = int(np.searchsorted(cumsum, target))
    if idx == 0:
        return float(edges[0])
    if idx >= len(cumsum):
        return float(edges[-1])
    before = cumsum[idx - 1]
    in_bin = cumsum[idx] - before
    if in_bin == 0:
        return float(edges[idx])
    return float(edges[idx] + (target - before) / in_bin * (edges[idx + 1] - edges[idx]))
