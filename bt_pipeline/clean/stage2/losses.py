"""Differentiable (torch) versions of the demo metrics, batched over demos.

Each function takes a batch of demos, shape (B, N, 2), in task coordinates [m], and returns one
value per demo, shape (B,), equal to the numpy definition in :mod:`bt_pipeline.score.losses` (L1-L4)
and :mod:`bt_pipeline.score.mi` (whose KSG counts are not differentiable: :func:`mi_kl` is the
Kozachenko-Leonenko stand-in of docs/algorithms.md §1.6). Refinement (Stage 2) trains on these.

Every function works in the dtype of its input (float32 for training, float64 for tests) and has
finite gradients everywhere, including at zero distances.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.spatial import KDTree
from scipy.special import digamma

SMOOTHNESS_ALPHAS = (0.2, 0.3, 0.5)
"""(α1, α2, α3) of Eq. (6): weights of velocity, acceleration and jerk."""

KL_NEIGHBOURS = 3
"""k of the k-nearest-neighbour MI surrogate (as for KSG, docs/algorithms.md §7 row 2)."""

_TINY = 1e-24
"""Added under square roots so gradients stay finite at zero distance [m²]."""

_LOG_FLOOR = 1e-12
"""Smallest kNN radius taken into a log (duplicated samples), in standardised units."""


def derotate(positions: torch.Tensor, thetas_deg: torch.Tensor) -> torch.Tensor:
    """Rotate each demo by -θ_i about its centroid (docs/algorithms.md §7 row 4).

    Args:
        positions: Demos, shape (B, N, 2), in [m].
        thetas_deg: Demonstrator rotations θ_i, shape (B,), in [deg] (counter-clockwise).

    Returns:
        De-rotated demos, shape (B, N, 2), same centroids.
    """
    theta = torch.deg2rad(thetas_deg.to(positions.dtype))
    cos, sin = torch.cos(theta)[:, None], torch.sin(theta)[:, None]
    centroid = positions.mean(dim=1, keepdim=True)
    rel = positions - centroid
    p, q = rel[..., 0], rel[..., 1]
    # R(-θ) = [[cos, sin], [-sin, cos]].
    rotated = torch.stack((cos * p + sin * q, -sin * p + cos * q), dim=-1)
    return rotated + centroid


def symmetry_loss(positions: torch.Tensor, thetas_deg: torch.Tensor) -> torch.Tensor:
    """L1: mean distance of each mirrored point to its nearest sample. # Eq. (4)

    The demo is first de-rotated by -θ_i about its centroid, then mirrored about the vertical line
    through the centroid, (p, q) -> (2 C_x - p, q); the hard min over j is differentiable almost
    everywhere (the gradient flows to the nearest sample).

    Args:
        positions: Demos, shape (B, N, 2), in [m].
        thetas_deg: Demonstrator rotations θ_i, shape (B,), in [deg].

    Returns:
        L1 per demo, shape (B,), in [m].
    """
    upright = derotate(positions, thetas_deg)
    # Centre first: the loss is translation invariant and float32 keeps more digits near 0.
    upright = upright - upright.mean(dim=1, keepdim=True)
    mirrored = torch.stack((-upright[..., 0], upright[..., 1]), dim=-1)
    # The nearest sample is a discrete choice: find it without autograd (a k-d tree, as the
    # numpy loss), then take the distance to it differentiably (the gradient of the hard min).
    nearest = _neighbours(mirrored, upright, rank=1, p=2.0)
    diff = mirrored - _gather(upright, nearest)
    return torch.sqrt((diff * diff).sum(dim=-1) + _TINY).mean(dim=-1)


def closure_loss(positions: torch.Tensor) -> torch.Tensor:
    """L2: distance between the first and the last sample. # Eq. (5)

    Args:
        positions: Demos, shape (B, N, 2), in [m].

    Returns:
        L2 per demo, shape (B,), in [m].
    """
    gap = positions[:, 0] - positions[:, -1]
    return torch.sqrt((gap * gap).sum(dim=-1) + _TINY)


def smoothness_loss(
    positions: torch.Tensor, alphas: tuple[float, float, float] = SMOOTHNESS_ALPHAS
) -> torch.Tensor:
    """L3: weighted squared norms of the 1st-3rd raw sample differences. # Eq. (6)

    Differences are taken without Δt (as written in the paper, docs/algorithms.md §7 row 6);
    ‖·‖² is the squared Frobenius norm of the (N - n, 2) difference matrix.

    Args:
        positions: Demos, shape (B, N, 2), in [m].
        alphas: (α1, α2, α3).

    Returns:
        L3 per demo, shape (B,), in [m²].
    """
    total = positions.new_zeros(positions.shape[0])
    for order, alpha in enumerate(alphas, start=1):
        diff = torch.diff(positions, n=order, dim=1)
        total = total + alpha * (diff * diff).sum(dim=(1, 2))
    return total


def shape_loss(positions: torch.Tensor, references: torch.Tensor) -> torch.Tensor:
    """L4: mean pointwise distance to the phase-aligned reference. # Eq. (9)

    `references[b, k]` is the target of `positions[b, k]` (the circular shift and direction that
    best align x_i^aligned with the raw demo are chosen in Stage 1 and kept fixed here,
    docs/algorithms.md §7 row 14).

    Args:
        positions: Demos, shape (B, N, 2), in [m].
        references: Phase-aligned references x_i^aligned, shape (B, N, 2), in [m].

    Returns:
        L4 per demo, shape (B,), in [m].
    """
    diff = positions - references
    return torch.sqrt((diff * diff).sum(dim=-1) + _TINY).mean(dim=-1)


def _standardise(values: torch.Tensor) -> torch.Tensor:
    """Divide each coordinate of each demo by its standard deviation (after removing the mean)."""
    centred = values - values.mean(dim=1, keepdim=True)
    std = centred.std(dim=1, keepdim=True, correction=0).clamp_min(_LOG_FLOOR)
    return centred / std


def _neighbours(queries: torch.Tensor, points: torch.Tensor, rank: int, p: float) -> torch.Tensor:
    """Index into `points` of each query's `rank`-th nearest neighbour, shape (B, Q) (int64).

    A k-d tree per demo on detached float64 copies (scipy): far cheaper than an (N, N) distance
    matrix, and the same choice as the numpy metrics make.
    """
    q = queries.detach().to(torch.float64).numpy()
    x = points.detach().to(torch.float64).numpy()
    index = np.empty(q.shape[:2], dtype=np.int64)
    for b in range(q.shape[0]):
        _, found = KDTree(x[b]).query(q[b], k=rank, p=p)
        index[b] = np.asarray(found).reshape(q.shape[1], rank)[:, -1]
    return torch.from_numpy(index)


def _gather(points: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """points[b, index[b, i]], shape (B, Q, d)."""
    return points.gather(1, index[..., None].expand(-1, -1, points.shape[-1]))


def _mean_log_radius(points: torch.Tensor, k: int) -> torch.Tensor:
    """Mean over samples of log ‖z_i - z_nb(i)‖_∞ to the k-th neighbour (self excluded), (B,)."""
    # Rank k + 1 counts the sample itself (distance 0) as the first neighbour.
    neighbour = _neighbours(points, points, rank=k + 1, p=math.inf)
    radius = (points - _gather(points, neighbour)).abs().amax(dim=-1)
    return torch.log(radius.clamp_min(_LOG_FLOOR)).mean(dim=-1)


def mi_kl(positions: torch.Tensor, k: int = KL_NEIGHBOURS) -> torch.Tensor:
    """Kozachenko-Leonenko estimate of I(S; A) per demo, a differentiable KSG stand-in [nats].

    S are the positions and A their forward differences with a_N = 0 (paper Sec. II); each
    coordinate of S and of A is standardised per demo, as for KSG (docs/algorithms.md §1.4).
    With max-norm k-NN radii r (docs/algorithms.md §1.6),

        I_KL = ψ(N) - ψ(k) + d_S⟨log r_S⟩ + d_A⟨log r_A⟩ - (d_S + d_A)⟨log r_SA⟩,

    the sum of the three Kozachenko-Leonenko entropies H(S) + H(A) - H(S, A) (the unit-ball
    constants cancel). The k-NN indices are a discrete choice; the radii are differentiable.

    It ranks demos like KSG while the position noise stays below about the sample spacing
    (Spearman ρ ≈ 0.88, docs/algorithms.md §1.6), but not beyond: there its negative bias
    shrinks as S and A become independent, so I_KL rises again towards 0 and *adding* noise to a
    very noisy demo can raise it. One reason not to maximise it without bounds.

    Args:
        positions: Demos, shape (B, N, 2), in [m]; N > k.
        k: Number of neighbours.

    Returns:
        I_KL per demo, shape (B,), in [nats].
    """
    n = positions.shape[1]
    # Δt cancels in the standardisation, so raw differences serve as actions.
    last = positions.new_zeros(positions[:, :1].shape)
    actions = torch.cat((torch.diff(positions, dim=1), last), dim=1)
    states = _standardise(positions)
    actions = _standardise(actions)
    joint = torch.cat((states, actions), dim=-1)
    d_s = d_a = 2
    const = float(digamma(n) - digamma(k))
    return (
        const
        + d_s * _mean_log_radius(states, k)
        + d_a * _mean_log_radius(actions, k)
        - (d_s + d_a) * _mean_log_radius(joint, k)
    )
