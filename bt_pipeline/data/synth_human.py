"""Synthetic demos shaped like people really record them (``bt synth --style human``).

The default style (:mod:`bt_pipeline.data.synth`) draws one loop per demo at 50 Hz with known
θ/ρ. Recordings from the app or from other labs look different, and this style draws them so:

* the hand rests (0.3-2 s, sensor noise only), **approaches** the task along a curved path from
  a rest pose 5-15 cm away (or from a point on the loop, as the app's home pose can be), draws
  **1-4 loops** (an "incomplete" demo stops its last loop at 70-90 %), then
  **retreats** to a rest pose and rests again;
* the phase speed follows one of five profile families (steady swell, speeding up, slowing
  down, a random mix of slow harmonics, a step change) and the loop part holds 0-2 **pauses**
  of 0.3-1.5 s (more for the "hesitation" defect);
* sample times are **uneven**: a per-demo rate of 30-60 Hz, ±25 % jitter per step, ~2 % dropped
  samples, and a first timestamp that is not 0;
* the hand **wobbles** 1-4 mm out of the task plane;
* in sets made with ``hidden=True`` every demo's θ/ρ are stored as NaN (unknown);
* the demonstrators' preferences are drawn per set: θ ∈ [−30°, 30°], ρ ∈ [0.75, 1.35];
* every demo draws the task's guide, or the set's ``shape`` when one is given (as in
  :mod:`bt_pipeline.data.synth`: the truth is then that loop, recorded in ``env_kwargs``).

The naive demos get the same defects as the default style (jitter, tremor, drift, spikes,
lopsided, speed, hesitation, incomplete: the last loop stops at 70-90 %;
:func:`bt_pipeline.data.synth.draw_defects`); the
expert-like demo only 0.3 mm of noise.

Ground truth per demo, stored in the demo's extra attrs of the format-v1 file (so any reader of
the file, benchmarks and tests included, finds it next to the data):

==================  ==========================================================================
attr                meaning
==================  ==========================================================================
``truth_uv``        the intended path at the demo's own timing, shape (T, 2) float32, in task
                    coordinates [m]: approach, the loops at the demo's own phase progression
                    (pauses, speed changes, an incomplete last loop included) and retreat,
                    without noise, tremor, spikes, drift, lopsidedness or wobble
``truth_on_loop``   per sample, 1 where the hand is on the loops (in-loop pauses included),
                    0 on the rest, approach and retreat, shape (T,) uint8
``truth_theta_deg`` the demonstrator's θ [deg] (also when the file's ``theta_deg`` is NaN)
``truth_rho``       the demonstrator's ρ
``truth_cycles``    loops drawn (fractional for an incomplete loop)
==================  ==========================================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.records import DemoRecord, FloatArray, Recording, forward_difference_actions
from bt_pipeline.data.shapes import similarity_transform
from bt_pipeline.data.synth import (
    Defect,
    Demonstrator,
    add_noise_and_outliers,
    check_set_args,
    draw_defects,
    synthetic_recording,
)
from bt_pipeline.data.synth_loop import loop_positions, lopsided, resolve_task
from bt_pipeline.data.synth_truth import truth_attrs
from bt_pipeline.data.tasks import Task

TRUTH_ATTRS = ("truth_uv", "truth_on_loop", "truth_theta_deg", "truth_rho", "truth_cycles")
"""Extra demo attrs holding the ground truth of a human-style demo."""
_FINE_HZ = 400.0  # The motion is built on this fine clock, then read at the uneven sample times.


@dataclass(frozen=True)
class HumanDemo:
    """One human-style synthetic demo with its ground truth (also in ``record.attrs``)."""

    name: str
    """``demo_<k>``."""
    record: DemoRecord
    """The demo as stored (θ/ρ NaN when hidden)."""
    truth_uv: FloatArray
    """Intended path at the demo's sample times, shape (T, 2), in [m]."""
    on_loop: np.ndarray
    """Whether each sample is on the loops, shape (T,) (bool)."""
    theta_deg: float
    """True θ [deg]."""
    rho: float
    """True ρ."""
    cycles: float
    """Loops drawn."""
    is_expert: bool
    """Whether this is the set's expert-like demo."""
    defects: tuple[Defect, ...]
    """The demo's defects; empty for the expert."""


@dataclass(frozen=True)
class HumanSet:
    """A human-style mixed-skill demo set for one task."""

    task: Task
    """The task (with a shape, any safe name)."""
    recording: Recording
    """The demos as a format-v1 recording."""
    demos: tuple[HumanDemo, ...]
    expert_index: int
    """Index of the expert-like demo."""
    hidden: bool
    """Whether θ/ρ are stored as NaN."""


def make_human_set(
    task: Task | str,
    n_demos: int = 4,
    seed: int = 0,
    hidden: bool | None = None,
    *,
    shape: LoopShape | None = None,
) -> HumanSet:
    """Generate a human-style mixed-skill set, deterministic for `seed` (module doc).

    Demo k belongs to demonstrator k mod 4 (so 4 demos are the paper's D1 and 20 its D2).

    Args:
        task: The task (with a shape, any safe name: see
            :func:`~bt_pipeline.data.synth_loop.resolve_task`).
        n_demos: Number of demos, ≥ 1.
        seed: Seed, an integer ≥ 0.
        hidden: Store θ/ρ as NaN; None draws it from the seed (half of the sets).
        shape: The loop every demo draws, in task coordinates [m]; None: the task's guide.

    Raises:
        UnknownTaskError: Unknown task and no shape.
        ConfigError: `n_demos` < 1, a negative seed or an unsafe task name.
    """
    task, task_index, plane = resolve_task(task, shape)
    n_demos, seed = check_set_args(n_demos, seed)
    set_rng = np.random.default_rng([int(seed), task_index, 7])
    if hidden is None:
        hidden = bool(set_rng.integers(2))
    teachers = tuple(
        Demonstrator(
            f"teacher_{'abcd'[j]}",
            float(np.round(set_rng.uniform(-30.0, 30.0), 1)),
            float(np.round(set_rng.uniform(0.75, 1.35), 3)),
        )
        for j in range(4)
    )
    expert_index = int(set_rng.integers(n_demos))
    demos = tuple(
        _make_demo(
            task,
            k,
            teachers[k % 4],
            k == expert_index,
            hidden,
            np.random.default_rng([int(seed), task_index, 7, k]),
            plane,
            shape,
        )
        for k in range(n_demos)
    )
    env_kwargs = {"task": task, "seed": int(seed), "style": "human", "n_demos": n_demos}
    recording = synthetic_recording(task, plane, [d.record for d in demos], env_kwargs, shape)
    return HumanSet(task, recording, demos, expert_index, hidden)


def _speed_profile(s: FloatArray, rng: np.random.Generator) -> tuple[FloatArray, str]:
    """Relative phase speed over normalised loop time `s` ∈ [0, 1], one of five families."""
    family = ("swell", "faster", "slower", "harmonics", "step")[int(rng.integers(5))]
    base = 1.0 + rng.uniform(0.05, 0.15) * np.sin(2 * np.pi * s + rng.uniform(0, 2 * np.pi))
    if family == "faster":
        base *= 1.0 + rng.uniform(0.3, 0.8) * s
    elif family == "slower":
        base *= 1.0 + rng.uniform(0.3, 0.8) * (1.0 - s)
    elif family == "harmonics":
        for _ in range(3):
            f = rng.uniform(0.5, 5.0)
            base += rng.uniform(0.05, 0.2) * np.sin(2 * np.pi * f * s + rng.uniform(0, 7))
    elif family == "step":
        at = rng.uniform(0.3, 0.7)
        base *= 1.0 + rng.uniform(-0.35, 0.5) / (1.0 + np.exp(-(s - at) / 0.03))
    return np.maximum(base, 0.2), family


def _pauses(t: FloatArray, count: int, rng: np.random.Generator) -> FloatArray:
    """Speed factor in [0.02, 1] over loop time `t` [s] with `count` flat-topped pauses."""
    factor = np.ones_like(t)
    for _ in range(count):
        centre = rng.uniform(0.1, 0.9) * t[-1]
        half = 0.5 * rng.uniform(0.3, 1.5)
        factor *= 1.0 - 0.98 * np.exp(-(((t - centre) / half) ** 6))
    return factor


def _transfer(start: FloatArray, end: FloatArray, n: int, rng: np.random.Generator) -> FloatArray:
    """A curved minimum-jerk move from `start` to `end` in `n` samples, shape (n, 2) [m]."""
    u = np.linspace(0.0, 1.0, n)
    s = 10 * u**3 - 15 * u**4 + 6 * u**5
    chord = end - start
    normal = np.array([-chord[1], chord[0]])
    bend = rng.uniform(-0.3, 0.3) * normal  # Quadratic Bézier control offset.
    control = 0.5 * (start + end) + bend
    return (
        ((1 - s) ** 2)[:, None] * start
        + (2 * s * (1 - s))[:, None] * control
        + (s**2)[:, None] * end
    )


def _sample_times(duration_s: float, rng: np.random.Generator) -> tuple[FloatArray, float]:
    """Uneven sample times over [0, duration]: 30-60 Hz, ±25 % jitter, ~2 % dropped."""
    rate = float(rng.uniform(30.0, 60.0))
    n = int(duration_s * rate * 1.5) + 10
    steps = (1.0 + rng.uniform(-0.25, 0.25, n)) / rate
    steps[rng.random(n) < 0.02] *= 2.0  # A dropped sample.
    t = np.concatenate([[0.0], np.cumsum(steps)])
    return t[t <= duration_s], rate


def _make_demo(
    task: Task,
    k: int,
    teacher: Demonstrator,
    is_expert: bool,
    hidden: bool,
    rng: np.random.Generator,
    plane: TaskPlane,
    shape: LoopShape | None,
) -> HumanDemo:
    defects: tuple[Defect, ...] = () if is_expert else draw_defects(rng)
    params: dict[str, Any] = {}
    incomplete = "incomplete" in defects
    cycles = float(rng.integers(1, 5))
    if incomplete:  # The last loop stops short at 70-90 %.
        cycles -= float(rng.uniform(0.1, 0.3))
    period_s = float(rng.uniform(3.0, 7.0))
    n_pauses = int(rng.integers(0, 3)) + (int(rng.integers(1, 3)) if "hesitation" in defects else 0)

    # Loop part on the fine clock: phase from the speed profile, pauses on top.
    loop_s = cycles * period_s * (1.0 + 0.25 * n_pauses / max(cycles, 1.0))
    t_loop = np.arange(0.0, loop_s, 1.0 / _FINE_HZ)
    speed, family = _speed_profile(t_loop / t_loop[-1], rng)
    if "speed" in defects:
        for _ in range(3):
            f = rng.uniform(0.5, 4.0)
            speed += rng.uniform(0.1, 0.25) * np.sin(
                2 * np.pi * f * t_loop / loop_s + rng.uniform(0, 7)
            )
        speed = np.maximum(speed, 0.15)
    speed = speed * _pauses(t_loop, n_pauses, rng)
    progress = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]))])
    phase = float(rng.uniform(0, 2 * np.pi)) + 2 * np.pi * cycles * progress / progress[-1]
    if rng.random() < 0.15:
        phase = phase[0] - (phase - phase[0])  # Some demonstrators run the loop the other way.
    drawn_loop = loop_positions(task, shape, phase)
    intended_loop = similarity_transform(drawn_loop, teacher.theta_deg, teacher.rho)
    if "lopsided" in defects:
        drawn_loop, extra = lopsided(drawn_loop, task, rng, shape)
        params.update(extra)
    drawn_loop = similarity_transform(drawn_loop, teacher.theta_deg, teacher.rho)

    # Rest, approach, loops, retreat, rest.

    def rest_pose(anchor: FloatArray) -> FloatArray:
        if rng.random() < 0.2:
            return anchor.copy()  # The app's home pose can sit on the loop itself.
        angle = rng.uniform(0, 2 * np.pi)
        return anchor + rng.uniform(0.05, 0.15) * np.array([np.cos(angle), np.sin(angle)])

    start_rest, end_rest = rest_pose(drawn_loop[0]), rest_pose(drawn_loop[-1])
    approach_s, retreat_s = rng.uniform(0.8, 2.5, size=2)
    lead_s, tail_s = rng.uniform(0.3, 2.0, size=2)
    parts_intended, parts_drawn, on_loop = [], [], []
    for piece_s, a, b in ((lead_s, start_rest, start_rest), (approach_s, start_rest, None)):
        n = max(2, int(piece_s * _FINE_HZ))
        target = drawn_loop[0] if b is None else b
        path = _transfer(a, target, n, rng) if b is None else np.repeat(a[None], n, axis=0)
        intended_end = intended_loop[0] if b is None else b
        parts_drawn.append(path)
        parts_intended.append(path + np.linspace(0, 1, n)[:, None] * (intended_end - target))
        on_loop.append(np.zeros(n, dtype=bool))
    parts_drawn.append(drawn_loop)
    parts_intended.append(intended_loop)
    on_loop.append(np.ones(t_loop.size, dtype=bool))
    for piece_s, rest in ((retreat_s, end_rest), (tail_s, None)):
        n = max(2, int(piece_s * _FINE_HZ))
        if rest is not None:
            path = _transfer(drawn_loop[-1], rest, n, rng)
            ideal = path + np.linspace(1, 0, n)[:, None] * (intended_loop[-1] - drawn_loop[-1])
        else:
            path = ideal = np.repeat(end_rest[None], n, axis=0)
        parts_drawn.append(path)
        parts_intended.append(ideal)
        on_loop.append(np.zeros(n, dtype=bool))
    fine_drawn = np.concatenate(parts_drawn)
    fine_intended = np.concatenate(parts_intended)
    fine_on = np.concatenate(on_loop)
    fine_t = np.arange(fine_drawn.shape[0]) / _FINE_HZ

    t, rate = _sample_times(float(fine_t[-1]), rng)
    pick = np.clip(np.round(t * _FINE_HZ).astype(int), 0, fine_t.size - 1)
    uv = fine_drawn[pick]
    truth = fine_intended[pick]
    mask = fine_on[pick]
    noisy = add_noise_and_outliers(uv, t, defects, rng, params)
    wobble_amp = float(rng.uniform(0.001, 0.004))
    wobble = wobble_amp * np.sin(2 * np.pi * rng.uniform(0.2, 1.0) * t + rng.uniform(0, 7))
    ee_pos = plane.to_world(noisy) + wobble[:, None] * plane.normal
    t0 = float(np.round(rng.uniform(0.0, 50.0), 3))
    timestamps = t0 + t
    attrs = truth_attrs(truth, mask, teacher.theta_deg, teacher.rho, cycles)
    record = DemoRecord(
        ee_pos=ee_pos,
        timestamps=timestamps,
        demonstrator=teacher.name,
        theta_deg=math.nan if hidden else teacher.theta_deg,
        rho=math.nan if hidden else teacher.rho,
        source="synthetic",
        actions=forward_difference_actions(ee_pos, timestamps),
        ep_meta={
            "synthetic": {
                "style": "human",
                "is_expert": is_expert,
                "defects": list(defects),
                "speed_profile": family,
                "pauses": n_pauses,
                "rate_hz": rate,
                "wobble_m": wobble_amp,
                "params": params,
            }
        },
        attrs=attrs,
    )
    return HumanDemo(
        name=f"demo_{k}",
        record=record,
        truth_uv=truth,
        on_loop=mask,
        theta_deg=teacher.theta_deg,
        rho=teacher.rho,
        cycles=cycles,
        is_expert=is_expert,
        defects=defects,
    )
