"""The point the demonstrators turn and scale the loop about, read from the demos' own fits.

The paper moves the best demo's loop to demonstrator i about a centre c (Sec. III-B):
x^g = R(−θ_best)(x^d − c) / ρ_best and x_i^aligned = ρ_i R(θ_i) x^g + c. Where c lies on the loop
it does not say; bt takes the centre of x^d's bounding box in the best demonstrator's unrotated
frame (:func:`~bt_pipeline.clean.stage1.extract.loop_centre`, docs/algorithms.md §7 row 13). With
θ/ρ hidden that frame is only the learned loop's, and on a loop without central symmetry the
box's centre there is not where the demonstrators' loops turn about: the references of a D shape
turned by 15-25° were placed 1-3 mm beside loops of 1.6-2.3 mm raw error
(``../shared/data/foreign-loops``, scrubbing).

Each demo's fit places the loop as it draws it: x ≈ ρ_i R(θ_i) g + t_i. If every demonstrator
turns and scales the loop about one point P, then with A_i = (ρ_i / ρ_b) R(θ_i − θ_b) relative
to the best demo b::

    (I − A_i) P = t_i − A_i t_b        for every demo i ≠ b,

two linear equations per demo. P is their weighted least-squares solution, each demo weighted by
its fit's quality (the pooling's weight, :func:`~bt_pipeline.clean.periodic.fit_quality`) and
Cauchy-reweighted four times at 2.5 × the residuals' robust spread (a lopsided demo's fit is
placed off by its bulge), with a light ridge toward c (0.1 % of the weight) where every demo has
nearly the best one's θ/ρ and P does not matter. P replaces c only when the fits say so clearly:

- an F-test of its two unknowns against c at the 5 % level, on the weighted residual sums S_P
  and S_c of the 2n equations, n the demos' effective count (Kish's, (Σw)² / Σw², at least 2):
  S_P / S_c at most 0.05 from two demos, 0.22 from three, 0.37 from four, 0.61 from seven;
- their weights sum to at least 1, one whole, closely fitted loop's worth (three lopsided demos
  of quality 0.03-0.05 agreed well enough with each other on bt's varied weaving, seed 1);
- P lies within 10 % of the loop's size of c: any centre of a loop (its box's, its centroid) lies
  in its middle (two drifting pick-and-place demos put one 50 mm off, random loops, seed 8).

On a loop with central symmetry every centre is the same point and c stays. When the best
demo's loop stays where it was drawn (``LoopShape.placed``), the pipeline sets c to the plane's
origin, the point the demos turn it about, before this test. Against the task's
guide the frame is the guide's own, which bt draws centred on its box, so the pipeline keeps c
there (on the second generator's guide sets, θ/ρ hidden, the test read a pivot 1.7-4.7 mm off in
2 of 12 pick-and-place sets, where c is the truth).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.stats import f as f_distribution

from bt_pipeline.clean.guide_fit import GuideFit
from bt_pipeline.clean.stage1.alignment import remove_preference, rotation_matrix
from bt_pipeline.clean.stage1.extract import Stage1Result
from bt_pipeline.data.records import FloatArray

MIN_DEMOS = 2
"""Effective count of demos besides the best one (Kish's, of their weights) a pivot needs."""
MIN_WEIGHT = 1.0
"""Their weights' sum a pivot needs: at least one whole, closely fitted loop's worth."""
MAX_OFFSET = 0.1
"""A pivot farther than this share of the best loop's size from c is no centre of the loop."""
LEVEL = 0.05
"""P replaces c when an F-test rejects c at this level (module doc)."""
_RIDGE = 0.001  # Pull toward c, as a share of the total weight.
_REWEIGHTS = 4  # Cauchy reweightings.
_CAUCHY = 2.5  # Cauchy scale in robust spreads of the residuals.
_FLOOR_M = 1e-4  # Smallest residual scale [m].


@dataclass(frozen=True)
class Pivot:
    """Where the preferences act: P read from the fits, or the box centre c kept."""

    point: FloatArray
    """The point used, shape (2,), in [m]: P when `read`, else c."""
    offset_m: float
    """|P − c| [m] (0 when no P could be read)."""
    support: float
    """Weighted residual sum at P over that at c (1 when no P could be read)."""
    read: bool
    """True when P replaced c."""


def read_pivot(fits: Sequence[GuideFit], quality: ArrayLike, best: int, centre: ArrayLike) -> Pivot:
    """The point the demos' loops turn and scale about (module doc).

    Args:
        fits: Each demo's fit to the task's loop (its segment's), in the same loop's frame.
        quality: Each fit's weight, shape (M,), ≥ 0.
        best: Index of the best demo.
        centre: c, shape (2,), in [m].

    Returns:
        The pivot, or c when the fits do not say clearly where it is.
    """
    c = np.asarray(centre, dtype=np.float64)
    kept = Pivot(c, 0.0, 1.0, False)
    weight = np.asarray(quality, dtype=np.float64)
    fb = fits[best]
    rows, rhs, w0 = [], [], []
    for i, fit in enumerate(fits):
        if i == best or not weight[i] > 0.0:
            continue
        turn = fit.rho / fb.rho * rotation_matrix(fit.theta_deg - fb.theta_deg)
        rows.append(np.eye(2) - turn)
        rhs.append(np.asarray(fit.translation) - turn @ np.asarray(fb.translation))
        w0.append(float(weight[i]))
    if len(rows) < MIN_DEMOS:
        return kept
    m, b, base = np.stack(rows), np.stack(rhs), np.asarray(w0)
    ridge = _RIDGE * float(base.sum())
    w, point, residual = base.copy(), c, np.zeros(len(rows))
    for _ in range(_REWEIGHTS):
        gram = ridge * np.eye(2) + np.einsum("k,kji,kjl->il", w, m, m)
        vector = ridge * c + np.einsum("k,kji,kj->i", w, m, b)
        point = np.linalg.solve(gram, vector)
        residual = np.linalg.norm(np.einsum("kij,j->ki", m, point) - b, axis=1)
        scale = _CAUCHY * 1.4826 * float(np.median(residual)) + _FLOOR_M
        w = base / (1.0 + (residual / scale) ** 2)
    if not np.all(np.isfinite(point)):
        return kept
    at_c = np.linalg.norm(np.einsum("kij,j->ki", m, c) - b, axis=1)
    support = float(np.sum(w * residual**2)) / max(float(np.sum(w * at_c**2)), 1e-18)
    offset = float(np.linalg.norm(point - c))
    # F-test of the two extra unknowns on the demos that carry weight (Kish's effective count
    # of their weights): F = ((S_c − S_P) / 2) / (S_P / (2n − 2)) above its 1 − LEVEL quantile,
    # i.e. S_P / S_c below (n − 1) / (n − 1 + F*).
    n = float(base.sum()) ** 2 / float(np.sum(base**2))
    if n < MIN_DEMOS or base.sum() < MIN_WEIGHT or offset > MAX_OFFSET * fb.size_m:
        return Pivot(c, offset, support, False)
    limit = (n - 1) / (n - 1 + float(f_distribution.ppf(1.0 - LEVEL, 2, 2 * n - 2)))
    if support > limit:
        return Pivot(c, offset, support, False)
    return Pivot(point, offset, support, True)


def pivoted(stage1: Stage1Result, point: ArrayLike) -> Stage1Result:
    """Stage 1 with its preferences acting about `point` (a pivot's, or the plane's origin),
    shape (2,) [m]: c and x^g (Sec. III-B) moved."""
    c = np.asarray(point, dtype=np.float64)
    best = stage1.best_index
    theta, rho = float(stage1.thetas[best]), float(stage1.rhos[best])
    shape = remove_preference(stage1.reference, theta, rho, c)
    return dataclasses.replace(stage1, centre=c, global_shape=shape)


__all__ = ["LEVEL", "MAX_OFFSET", "MIN_DEMOS", "MIN_WEIGHT", "Pivot", "pivoted", "read_pivot"]
