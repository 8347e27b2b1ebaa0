"""The competence (oracle) checks: can a learner learn the task at all, independent of cleaning?

Perfect demos are the synthetic demonstrators' intended paths (the canonical shape under a
demonstrator's θ and ρ, :mod:`bt_pipeline.data.shapes`), each with its own timing: a random start
phase and a smooth random speed profile φ(s) = φ_0 + 2π (s + a sin(2π f s + c) / (2π f) - ...),
one loop over the demo, N samples uniform in normalised time. Nothing in them was cleaned.

* **One demonstrator** (:func:`one_demonstrator_check`): every learner is trained on
  `per_teacher` perfect demos of demonstrator A and rolled out from perturbed demo states. Pass:
  coverage ≥ 0.9 (the share of the true loop within 5 mm of a rollout, mean over rollouts) and
  shape error (phase-free Chamfer distance to the true loop) ≤ 2 × the training demos' own, with
  the demos' own floored at 1 mm (a perfect demo's own error is sampling round-off, ~0.1 mm).
* **Four demonstrators** (:func:`four_demonstrator_check`): one perfect demo per D1
  demonstrator; each rollout is compared with the loop of the demonstrator whose demo it started
  from, with the nearest of the four loops, and with the *mean-preference* loop (θ, ρ averaged).
  A policy that averages preferences lies nearer the mean loop than its own. *Conditioned*
  (``conditioned=True``): the learner takes each demo's demonstrator preference (θ, ρ) as an
  input and each rollout is run with the preference of the demonstrator it starts from. Pass:
  for every demonstrator, its rollouts' mean shape error to its own loop ≤ 2 mm
  (:data:`CONDITIONED_PASS_M`; the largest of the four is ``worst_own_error_m``).
* **Attraction** (both checks): rollouts from points 1-3 cm off the true loop (along its normal,
  either side) must end, one canonical period (N samples) later, within 2 mm of the loop.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import KDTree

from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.shapes import canonical_loop, canonical_shape, similarity_transform
from bt_pipeline.data.synth import DEMONSTRATORS, TRUTH_SAMPLES, Demonstrator
from bt_pipeline.data.tasks import GuidedTask, parse_guided_task
from bt_pipeline.evaluate.distance import chamfer_distance
from bt_pipeline.evaluate.learners import (
    LearnedPolicy,
    LearnerName,
    learner_config,
    train_learner,
)

COVERAGE_TOLERANCE_M = 0.005
"""A true-loop point is covered when a rollout passes within this distance [m]."""
COVERAGE_PASS = 0.9
"""Coverage a competent learner reaches."""
SHAPE_RATIO_PASS = 2.0
"""A competent learner's shape error is at most this multiple of the demos' own."""
CONVERGED_M = 0.002
"""A rollout from 1-3 cm off the loop has converged when it ends this close to it [m]."""
OWN_ERROR_FLOOR_M = 0.001
"""Floor of the demos' own shape error in the pass rule [m] (perfect demos have ~0.1 mm)."""
CONDITIONED_PASS_M = 0.002
"""A conditioned learner passes the four-demonstrator check when the rollouts of every
demonstrator lie this close to its own loop, on average [m]."""


@dataclass(frozen=True)
class PerfectSet:
    """Perfect demos with their demonstrators and true loops."""

    positions: FloatArray
    """Demos, shape (M, N, 2), in task coordinates [m], uniform in normalised time."""
    demonstrators: tuple[str, ...]
    """Who drew each demo (M names)."""
    truths: dict[str, FloatArray]
    """True loop of each demonstrator, shape (600, 2), in [m]."""


def perfect_demos(
    task: GuidedTask,
    teachers: Sequence[Demonstrator],
    per_teacher: int,
    n_samples: int = 300,
    seed: int = 0,
) -> PerfectSet:
    """`per_teacher` perfect demos of each demonstrator, each with its own timing (module doc).

    Raises:
        UnknownTaskError: `task` has no built-in guide shape (perfect demos are drawn on it).
    """
    task = parse_guided_task(task)
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, n_samples)
    positions, names = [], []
    for _ in range(per_teacher):
        for teacher in teachers:
            f = int(rng.integers(1, 3))
            a, c = float(rng.uniform(0.2, 0.5)), float(rng.uniform(0.0, 2.0 * math.pi))
            warp = s + a / (2.0 * math.pi * f) * (np.sin(2.0 * math.pi * f * s + c) - math.sin(c))
            phase = float(rng.uniform(0.0, 2.0 * math.pi)) + 2.0 * math.pi * warp
            shape = canonical_shape(task, phase)
            positions.append(similarity_transform(shape, teacher.theta_deg, teacher.rho))
            names.append(teacher.name)
    truths = {
        t.name: similarity_transform(canonical_loop(task, TRUTH_SAMPLES), t.theta_deg, t.rho)
        for t in teachers
    }
    return PerfectSet(np.stack(positions), tuple(names), truths)


def coverage(
    rollout: FloatArray, truth: FloatArray, tolerance_m: float = COVERAGE_TOLERANCE_M
) -> float:
    """Share of the true loop's points (K, 2) within `tolerance_m` of a rollout (N, 2) [m]."""
    gaps, _ = KDTree(rollout).query(truth)
    return float(np.mean(gaps <= tolerance_m))


def perturbed_starts(
    positions: FloatArray, count: int, noise_m: float, seed: int
) -> tuple[FloatArray, np.ndarray]:
    """`count` states of random demos at random samples plus N(0, noise_m²) per axis, and the
    index of the demo each came from."""
    rng = np.random.default_rng(seed)
    demo = rng.integers(0, positions.shape[0], size=count)
    sample = rng.integers(0, positions.shape[1], size=count)
    return positions[demo, sample] + rng.normal(0.0, noise_m, (count, 2)), demo


@dataclass(frozen=True)
class CompetenceRow:
    """One learner's competence on perfect demos of one task."""

    task: GuidedTask
    learner: LearnerName
    check: str
    """``"one"`` (one demonstrator), ``"four"`` (the D1 demonstrators) or ``"four_conditioned"``
    (the D1 demonstrators, the learner given each one's preference)."""
    coverage: float
    """Mean over rollouts of the share of the own true loop within 5 mm."""
    shape_error_m: float
    """Mean phase-free distance of the rollouts to their own true loop [m]."""
    worst_own_error_m: float
    """The same per demonstrator (over the rollouts that started from its demos), the largest
    over the demonstrators that got a rollout [m]."""
    demos_error_m: float
    """Mean phase-free distance of the training demos to their true loops [m]."""
    nearest_own: float
    """Share of rollouts whose nearest true loop is their own demonstrator's (four only)."""
    mean_loop_error_m: float
    """Mean phase-free distance of the rollouts to the mean-preference loop [m] (four only)."""
    converged: float
    """Share of rollouts from 1-3 cm off the own loop that end one period later within 2 mm
    of it."""
    final_gap_m: float
    """Largest distance to the own loop after one period from those starts [m]."""

    @property
    def passed(self) -> bool:
        """The pass rule (module doc): every demonstrator's rollouts within 2 mm of its own loop
        for ``"four_conditioned"``, the one-demonstrator rule otherwise."""
        if self.check == "four_conditioned":
            return self.worst_own_error_m <= CONDITIONED_PASS_M
        own = max(self.demos_error_m, OWN_ERROR_FLOOR_M)
        return self.coverage >= COVERAGE_PASS and self.shape_error_m <= SHAPE_RATIO_PASS * own

    def to_json(self) -> dict[str, object]:
        return {
            "task": self.task,
            "learner": self.learner,
            "check": self.check,
            "coverage": self.coverage,
            "shape_error": self.shape_error_m,
            "worst_own_error": self.worst_own_error_m,
            "demos_error": self.demos_error_m,
            "nearest_own": self.nearest_own,
            "mean_loop_error": self.mean_loop_error_m,
            "converged": self.converged,
            "final_gap": self.final_gap_m,
            "passed": self.passed,
        }


def competence(
    task: GuidedTask,
    learner: LearnerName,
    teachers: Sequence[Demonstrator],
    per_teacher: int,
    rollouts: int = 20,
    quick: bool = False,
    seed: int = 0,
    init_noise: float = 0.02,
    steps: int | None = None,
    paper: bool = False,
    conditioned: bool = False,
) -> CompetenceRow:
    """Train `learner` on perfect demos of `teachers` and measure its rollouts (module doc).

    `steps` overrides the learner's optimiser steps (tiny test runs only); `paper` trains the
    learner as the paper wrote it (2-D position state, no corrective data); `conditioned` gives
    it each demo's demonstrator preference (θ, ρ) as an input and rolls each rollout out with
    the preference of the demonstrator it starts from.
    """
    data = perfect_demos(task, teachers, per_teacher, seed=seed)
    by_name = {t.name: (t.theta_deg, t.rho) for t in teachers}
    preferences = np.array([by_name[name] for name in data.demonstrators])
    overrides: dict[str, object] = {"seed": seed}
    if steps:
        overrides["steps"] = steps
    if paper:
        overrides |= {"state": "position", "dart_fraction": 0.0}
    trained = train_learner(
        learner,
        data.positions,
        list(data.demonstrators),
        learner_config(learner, quick, **overrides),
        preferences if conditioned else None,
    )
    size = float(np.ptp(data.positions.reshape(-1, 2), axis=0).max())
    x0, demo = perturbed_starts(data.positions, rollouts, init_noise * size, seed)
    # two demo periods; the second is measured, so the start's transient is not the shape error
    n = data.positions.shape[1]
    wanted = preferences[demo] if conditioned else None
    states = trained.policy.rollout(x0, 2 * n - 1, preferences=wanted)[:, n - 1 :]
    own_truths = [data.truths[data.demonstrators[d]] for d in demo]
    own_errors = np.array([chamfer_distance(r, t) for r, t in zip(states, own_truths, strict=True)])
    who = np.array([data.demonstrators[d] for d in demo])
    mean_loop = similarity_transform(
        canonical_loop(task, TRUTH_SAMPLES),
        float(np.mean([t.theta_deg for t in teachers])),
        float(np.mean([t.rho for t in teachers])),
    )
    loops = list(data.truths.values())
    nearest_own = [
        int(np.argmin([chamfer_distance(r, loop) for loop in loops]))
        == list(data.truths).index(data.demonstrators[d])
        for r, d in zip(states, demo, strict=True)
    ]
    return CompetenceRow(
        task=task,
        learner=learner,
        check=("one" if len(teachers) == 1 else "four") + ("_conditioned" if conditioned else ""),
        coverage=float(np.mean([coverage(r, t) for r, t in zip(states, own_truths, strict=True)])),
        shape_error_m=float(np.mean(own_errors)),
        worst_own_error_m=max(float(np.mean(own_errors[who == name])) for name in set(who)),
        demos_error_m=float(
            np.mean(
                [
                    chamfer_distance(p, data.truths[name])
                    for p, name in zip(data.positions, data.demonstrators, strict=True)
                ]
            )
        ),
        nearest_own=float(np.mean(nearest_own)),
        mean_loop_error_m=float(np.mean([chamfer_distance(r, mean_loop) for r in states])),
        **_convergence(trained.policy, data, rollouts, seed, by_name if conditioned else None),
    )


def _convergence(
    policy: LearnedPolicy,
    data: PerfectSet,
    count: int,
    seed: int,
    preferences: dict[str, tuple[float, float]] | None = None,
) -> dict[str, float]:
    """Roll out one period from `count` points 1-3 cm off the true loops (along the normal, either
    side) and measure the final distance to the own loop (a conditioned policy rolled out with
    that loop's demonstrator's `preferences`)."""
    rng = np.random.default_rng(seed + 7)
    names = list(data.truths)
    who = rng.integers(0, len(names), size=count)
    finals = []
    starts = []
    for w in who:
        loop = data.truths[names[w]]
        k = int(rng.integers(0, loop.shape[0]))
        tangent = loop[(k + 1) % loop.shape[0]] - loop[k - 1]
        normal = np.array([-tangent[1], tangent[0]]) / max(float(np.linalg.norm(tangent)), 1e-12)
        starts.append(loop[k] + normal * rng.choice([-1.0, 1.0]) * rng.uniform(0.01, 0.03))
    wanted = None if preferences is None else np.array([preferences[names[w]] for w in who])
    ends = policy.rollout(np.stack(starts), data.positions.shape[1], preferences=wanted)[:, -1]
    for end, w in zip(ends, who, strict=True):
        gap, _ = KDTree(data.truths[names[w]]).query(end)
        finals.append(float(gap))
    return {
        "converged": float(np.mean(np.array(finals) <= CONVERGED_M)),
        "final_gap_m": float(np.max(finals)),
    }


def competence_check(
    check: str,
    task: GuidedTask,
    learner: LearnerName,
    quick: bool = False,
    seed: int = 0,
    rollouts: int = 20,
    steps: int | None = None,
    paper: bool = False,
    conditioned: bool = False,
) -> CompetenceRow:
    """The one-demonstrator (``"one"``: 4 perfect demos of teacher_a) or four-demonstrator
    (``"four"``: one perfect demo of each D1 demonstrator) check (module doc); `conditioned`
    gives the learner each demonstrator's preference as an input."""
    teachers, per_teacher = (DEMONSTRATORS[:1], 4) if check == "one" else (DEMONSTRATORS, 1)
    return competence(
        task,
        learner,
        teachers,
        per_teacher,
        rollouts,
        quick,
        seed,
        steps=steps,
        paper=paper,
        conditioned=conditioned,
    )
