"""Stage 1 of the cleaner: canonical motion extraction (paper Sec. III-B steps 2-6).

Data flow (Algorithm 1 lines 5-8)::

    demos[best] ──fit_periodic_dmp──▶ PeriodicDmp ──canonical_reference──▶ x^d (closed, N)
                                          │                                  │
                                          └──build_value_map(x^d)──▶ V_E     │
    x^g = R(−θ_best)(x^d − c)/ρ_best  ◀──────────────────────────────────────┘
    x_i^aligned = phase_align(ρ_i R(θ_i) x^g + c, demo_i)  ──▶  L4_i (Eq. 9)

Every reference sits at the centre c of the best demo's loop (docs/algorithms.md §7 row 13).
By default c is the centre of x^d's bounding box in the best demonstrator's unrotated frame:
unlike the DMP anchor g (x^d's mean over one period in time) it does not move with the best
demo's speed profile, and on an asymmetric loop (the pick-and-place arch) rotating and scaling
about g instead misplaces the other demonstrators' references by several millimetres. On the
synthetic D1 sets (3 tasks × 4 seeds, references vs naive demos' truth, mean Chamfer ratio) box
gives 0.090, the arc-length centroid 0.155 and g 0.231; the true centre gives 0.089.

θ_i/ρ_i come from each demo's metadata; missing ones are
estimated by a similarity fit to x^g (§7 row 19). When the best demo's own θ/ρ are unknown,
θ_best = 0 and ρ_best = 1 are assumed, so x^g keeps the best demonstrator's bias, and every other
demo's θ/ρ is then estimated relative to x^g (given values would be relative to a frame we do
not know).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bt_pipeline.clean.stage1.alignment import (
    apply_preference,
    estimate_preference,
    phase_align,
    remove_preference,
    rotation_matrix,
)
from bt_pipeline.clean.stage1.dmp import DmpConfig, PeriodicDmp, fit_periodic_dmp
from bt_pipeline.clean.stage1.value_map import ValueMap, ValueMapConfig, build_value_map
from bt_pipeline.data.demo import Demo
from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError, DemoError

PreferenceSource = Literal["given", "estimate"]
"""Where θ/ρ come from: the demos' metadata (estimating only missing ones), or always estimated."""


CentreRule = Literal["box", "arc_length", "anchor"]
"""Where the centre c of the preferences is taken on x^d (module doc): "box", the centre of its
bounding box in the best demonstrator's unrotated frame, c = R(θ_best) · box(R(−θ_best) x^d);
"arc_length", its centroid by arc length; "anchor", the DMP anchor g (its mean over one period
in time, so it moves with the best demo's speed profile)."""


@dataclass(frozen=True)
class Stage1Config:
    """Settings of Stage 1."""

    dmp: DmpConfig = field(default_factory=DmpConfig)
    """Periodic DMP fit."""
    value_map: ValueMapConfig = field(default_factory=ValueMapConfig)
    """Value map V_E."""
    allow_reversal: bool = True
    """Let a demo run the loop the other way round in the phase alignment and the θ/ρ fit."""
    preferences: PreferenceSource = "given"
    """"given" uses each demo's θ/ρ and estimates missing ones; "estimate" ignores them."""
    centre: CentreRule = "box"
    """Where the centre c of the preferences sits on x^d."""

    def __post_init__(self) -> None:
        if self.centre not in ("box", "arc_length", "anchor"):
            raise ConfigError(
                f"centre must be 'box', 'arc_length' or 'anchor'; got {self.centre!r}"
            )
        if self.preferences not in ("given", "estimate"):
            raise ConfigError(
                f"preferences must be 'given' or 'estimate'; got {self.preferences!r}"
            )


_RESULT_ARRAYS = (
    "reference",
    "global_shape",
    "centre",
    "aligned",
    "shifts",
    "reversed",
    "thetas",
    "rhos",
    "estimated",
    "shape_losses",
)


@dataclass(frozen=True, eq=False)
class Stage1Result:
    """Everything Stage 1 hands to the refinement (Step 2) and to the evaluation (read-only)."""

    best_index: int
    """Index of x^best in the demo set."""
    reference: FloatArray
    """x^d, the DMP's canonical reference, closed, shape (N, 2), in [m]."""
    global_shape: FloatArray
    """x^g, the shape without demonstrator bias, about the origin, closed, shape (N, 2), [m]."""
    centre: FloatArray
    """c, the centre of the best demo's loop (Stage1Config.centre), shape (2,), in [m]."""
    aligned: FloatArray
    """x_i^aligned phase-aligned to demo i: aligned[i, k] is the target of demo i's sample k,
    shape (M, N, 2), in [m]."""
    shifts: NDArray[np.int64]
    """s*_i of each alignment, in samples of the period N − 1, shape (M,)."""
    reversed: NDArray[np.bool_]
    """Whether each demo runs the loop the other way round, shape (M,)."""
    thetas: FloatArray
    """θ_i used [deg], shape (M,)."""
    rhos: FloatArray
    """ρ_i used, shape (M,)."""
    estimated: NDArray[np.bool_]
    """True where θ_i/ρ_i were not taken from the demo's metadata, shape (M,) (bool)."""
    shape_losses: FloatArray
    """L4_i, mean distance to x_i^aligned, shape (M,), in [m] (Eq. 9 per demo)."""
    value_map: ValueMap
    """V_E, in the best demo's frame, frozen."""
    dmp: PeriodicDmp
    """The DMP fitted to the best demo."""
    symmetry_axis_deg: float = 0.0
    """L1's axis (Eq. 4) from the vertical of the task loop's frame [deg]: demo i is mirrored
    about the line at θ_i + this (:attr:`~bt_pipeline.clean.loop_learn.TaskLoop.symmetry_axis`;
    0 for a guide)."""

    def l1_thetas(self) -> FloatArray:
        """The turns L1 de-rotates each demo by, θ_i + the axis [deg], shape (M,)."""
        return self.thetas + self.symmetry_axis_deg

    def __post_init__(self) -> None:
        for name in _RESULT_ARRAYS:
            array = np.array(getattr(self, name))  # A copy: the caller's arrays stay writable.
            array.setflags(write=False)
            object.__setattr__(self, name, array)

    @property
    def n_demos(self) -> int:
        """M."""
        return int(self.aligned.shape[0])

    def to_best_frame(self, i: int, points: ArrayLike) -> FloatArray:
        """Map points of demo i's frame into the best demo's frame (docs/algorithms.md §8 trap 2).

        x ↦ c + ρ_best R(θ_best) R(−θ_i) (x − c) / ρ_i, so a demo drawn with its own preference
        is scored by V_E as if drawn by the best demonstrator.

        Args:
            i: Demo index.
            points: Points, shape (..., 2), in [m].

        Returns:
            Mapped points, shape (..., 2), in [m].
        """
        if not 0 <= i < self.n_demos:
            raise ConfigError(f"demo index {i} is out of range; valid are 0 .. {self.n_demos - 1}")
        b = self.best_index
        scale = self.rhos[b] / self.rhos[i]
        rotation = rotation_matrix(float(self.thetas[b] - self.thetas[i]))
        x = np.asarray(points, dtype=np.float64) - self.centre
        return self.centre + scale * x @ rotation.T

    def rewards(self, positions: ArrayLike) -> FloatArray:
        """R̄_i = mean_k V_E(to_best_frame(i, x_i(t_k))), paths (M, N, 2) -> (M,) (Eq. 11)."""
        p = np.asarray(positions, dtype=np.float64)
        if p.ndim != 3 or p.shape[0] != self.n_demos or p.shape[2] != 2:
            raise ConfigError(
                f"positions must have shape ({self.n_demos}, N, 2), one path per demo; got "
                f"{p.shape}"
            )
        mapped = np.stack([self.to_best_frame(i, p[i]) for i in range(self.n_demos)])
        return self.value_map.mean_rewards(mapped)


def canonical_reference(
    dmp: PeriodicDmp, best_positions: ArrayLike, n: int | None = None, oversample: int = 16
) -> FloatArray:
    """The canonical reference x^d: the DMP's last of 3 periods, as a closed loop of n samples.

    The rollout starts at the best demo's first sample and velocity at phase 0. The last period
    is sampled `oversample` times finer than needed; its sample nearest the best demo's first one
    (searched within ±10% of a period of phase 0) is taken as x^d(t_1), and the loop is
    resampled from there to n points over one period at t_k = k/(n − 1), so x^d[n − 1] = x^d[0]
    (docs/algorithms.md §7 row 11).

    Args:
        dmp: The DMP fitted to the best demo.
        best_positions: The best demo, shape (N, 2), in [m].
        n: Samples of x^d; defaults to N.
        oversample: Phase resolution of the alignment, in samples of x^d.

    Returns:
        x^d, shape (n, 2), in [m], closed (last sample equal to the first).
    """
    best = np.asarray(best_positions, dtype=np.float64)
    if best.ndim != 2 or best.shape[1] != 2 or best.shape[0] < 2:
        raise ConfigError(f"best_positions must have shape (N, 2); got {best.shape}")
    n_out = best.shape[0] if n is None else n
    if n_out < 3:
        raise ConfigError(f"n must be at least 3; got {n_out}")
    spp = (n_out - 1) * oversample
    z0 = dmp.tau * (best[1] - best[0]) * (best.shape[0] - 1)  # z = τ ẏ, forward difference.
    last = dmp.rollout(best[0], z0, n_periods=3, samples_per_period=spp)[-spp:]
    # Phase 0 is the best demo's first sample by construction; look for the nearest point within
    # ±10% of a period of it, so a loop that passes its start twice (a figure-eight) stays put.
    window = np.arange(-(spp // 10), spp // 10 + 1)
    start = int(window[np.argmin(np.sum((last[window] - best[0]) ** 2, axis=1))])
    loop = np.roll(last, -start, axis=0)[::oversample]
    return np.concatenate([loop, loop[:1]], axis=0)


def loop_centre(
    x_d: ArrayLike, theta_best: float, rule: CentreRule, anchor: ArrayLike | None = None
) -> FloatArray:
    """The centre c of the best demo's loop about which preferences act (module doc).

    Args:
        x_d: Canonical reference x^d, closed, shape (N, 2), in [m].
        theta_best: θ_best [deg] (0 when unknown).
        rule: "box", "arc_length" or "anchor" (see :data:`CentreRule`).
        anchor: The DMP anchor g, shape (2,), in [m]; needed for "anchor".

    Returns:
        c, shape (2,), in [m].
    """
    x = np.asarray(x_d, dtype=np.float64)
    if rule == "box":
        rotation = rotation_matrix(theta_best)
        upright = x @ rotation  # R(−θ_best) x, row by row.
        return rotation @ (0.5 * (upright.min(axis=0) + upright.max(axis=0)))
    if rule == "arc_length":
        lengths = np.linalg.norm(np.diff(x, axis=0), axis=1)
        midpoints = 0.5 * (x[1:] + x[:-1])
        return lengths @ midpoints / lengths.sum()
    if rule == "anchor" and anchor is not None:
        return np.array(anchor, dtype=np.float64)
    raise ConfigError(
        f"centre rule must be 'box', 'arc_length' or 'anchor' (with an anchor); got {rule!r}"
    )


def run_stage1(
    demos: Sequence[Demo],
    best_index: int,
    config: Stage1Config | None = None,
    seed: int = 0,
    best_cycles: float | None = None,
) -> Stage1Result:
    """Canonical motion extraction from the best demo (paper Sec. III-B steps 2-6).

    Args:
        demos: The demo set E, all with the same number of samples N.
        best_index: Index of x^best (the argmax of Ũ, Eq. 8).
        config: Stage 1 settings; defaults to Stage1Config().
        seed: Seed of the value map's rollout perturbations.
        best_cycles: Loops in the best demo (from segmentation); the DMP is then fitted with
            period T = 1 / cycles over every cycle. None (or under 1.5 loops) lets the DMP find
            its period itself.

    Raises:
        ConfigError: No demos, or best_index out of range.
        DemoError: Demos of different lengths, or a best demo the DMP cannot fit.
    """
    config = config or Stage1Config()
    if not demos:
        raise ConfigError("run_stage1 needs at least one demo")
    if not 0 <= best_index < len(demos):
        raise ConfigError(
            f"best_index {best_index} is out of range; valid are 0 .. {len(demos) - 1}"
        )
    best = demos[best_index]
    n = best.n_samples
    for demo in demos:
        if demo.n_samples != n:
            raise DemoError(
                f"{demo.label} has {demo.n_samples} samples but the best demo {best.label} has "
                f"{n}; resample every demo of a set to the same N"
            )
    period = 1.0 / best_cycles if best_cycles is not None and best_cycles >= 1.5 else None
    dmp = fit_periodic_dmp(best.positions, period=period, config=config.dmp, name=best.label)
    x_d = canonical_reference(dmp, best.positions, n)
    if config.preferences == "given" and best.theta_deg is not None and best.rho is not None:
        theta_best, rho_best, best_known = best.theta_deg, best.rho, True
    else:
        theta_best, rho_best, best_known = 0.0, 1.0, False
    centre = loop_centre(x_d, theta_best, config.centre, dmp.anchor)
    x_g = remove_preference(x_d, theta_best, rho_best, centre)

    m = len(demos)
    thetas, rhos = np.empty(m), np.empty(m)
    estimated = np.zeros(m, dtype=bool)
    for i, demo in enumerate(demos):
        if i == best_index:
            thetas[i], rhos[i], estimated[i] = theta_best, rho_best, not best_known
            continue
        theta = demo.theta_deg if best_known else None
        rho = demo.rho if best_known else None
        if theta is None or rho is None:
            fit = estimate_preference(demo.positions, x_g, config.allow_reversal)
            theta = fit.theta_deg if theta is None else theta
            rho = fit.rho if rho is None else rho
            estimated[i] = True
        thetas[i], rhos[i] = theta, rho

    alignments = [
        phase_align(
            apply_preference(x_g, thetas[i], rhos[i], centre), demo.positions, config.allow_reversal
        )
        for i, demo in enumerate(demos)
    ]
    value_map = build_value_map(dmp, x_d, config.value_map, seed)
    return Stage1Result(
        best_index=best_index,
        reference=x_d,
        global_shape=x_g,
        centre=centre,
        aligned=np.stack([a.aligned for a in alignments]),
        shifts=np.array([a.shift for a in alignments], dtype=np.int64),
        reversed=np.array([a.reversed for a in alignments], dtype=bool),
        thetas=thetas,
        rhos=rhos,
        estimated=estimated,
        shape_losses=np.array([a.loss for a in alignments]),
        value_map=value_map,
        dmp=dmp,
    )
