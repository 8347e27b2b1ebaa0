"""Demo sets from a second, independent generator: one steady operator and wobbly ones.

``bt_pipeline.data.synth_human`` draws heavy defects (jitter, tremor, spikes, lopsided loops);
this generator, written apart from it, draws what a careful but unsteady hand does instead, so
the cleaner is not judged only on the data it was tuned on. Each demo of a set (5 by default):

* a rest of 0.3-1.5 s 6-20 cm from the loop, a straight eased approach of 1-2.5 s, the loops,
  a retreat and a rest the same way;
* loops of the task's canonical shape (or of the loop given, for example one of
  :mod:`bt_pipeline.testing.lab_loops`) under the operator's θ ∈ [−40°, 40°] and ρ ∈ [0.65, 1.6]
  starting at a random phase: 1-5 loops (the steady operator 2-3), a period of 2-5 s with the
  speed swinging ±40 % slowly, 0-2 pauses of 0.5-2.5 s, and for a wobbly operator in 30 % of
  the demos a last loop stopped 10-30 % early;
* a wobbly operator's hand adds three slow sinusoids per axis (0.1-0.6 Hz, 1-4 mm each) and
  1-3 mm of sample noise; the steady operator's only 0.3 mm;
* samples at 15, 30, 60 or 120 Hz with ±30 % jitter and rare gaps of 0.2-0.6 s, on a time base
  that starts at 0-100 s.

Truth per demo: the intended path (the loops at the operator's phase, approach and retreat,
without wobble or noise) at the sample times, and which samples are on the loops.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bt_pipeline.data.demo import DEFAULT_SAMPLES, Demo, resample_uniform
from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.shapes import canonical_shape, similarity_transform
from bt_pipeline.data.tasks import GuidedTask, Task, default_plane, parse_guided_task

_FINE_HZ = 400.0  # The motion is built on this clock, then read at the sample times.


@dataclass(frozen=True)
class OperatorDemo:
    """One demo with its truth."""

    demo: Demo
    intended: FloatArray
    """Intended path at the demo's sample times, shape (T, 2) [m]."""
    on_loop: np.ndarray
    """Whether each sample is on the loops, shape (T,) bool."""
    theta_deg: float
    rho: float
    loops: int


@dataclass(frozen=True)
class OperatorSet:
    """A set of demos of one task, one of them drawn by the steady operator."""

    demos: tuple[OperatorDemo, ...]
    steady_index: int


def operator_set(
    task: Task, seed: int, n_demos: int = 5, hidden: bool = False, loop: LoopShape | None = None
) -> OperatorSet:
    """A set of `n_demos` demos, one operator each; θ/ρ stored as unknown when `hidden`.

    The operators draw `loop` at θ/ρ relative to it, or the task's guide when it is None; the
    demos are stored under `task` either way (its plane).

    Raises:
        UnknownTaskError: `task` is not one of bt's three tasks.
    """
    guided = parse_guided_task(task)
    rng = np.random.default_rng([seed, 99])
    steady = int(rng.integers(n_demos))
    demos = []
    for k in range(n_demos):
        theta, rho = float(rng.uniform(-40, 40)), float(rng.uniform(0.65, 1.6))
        demos.append(_demo(guided, rng, k, k == steady, theta, rho, hidden, loop))
    return OperatorSet(tuple(demos), steady)


def _phase(rng: np.random.Generator, loops: int, steady: bool) -> FloatArray:
    """The operator's phase [rad] on the fine clock: speed swings, pauses, an early stop."""
    n = int(loops * rng.uniform(2.0, 5.0) * _FINE_HZ)
    t = np.arange(n) / _FINE_HZ
    speed = 1.0 + 0.4 * np.sin(2 * np.pi * rng.uniform(0.05, 0.3) * t + rng.uniform(0, 7))
    phase = np.cumsum(speed)
    phase *= 2 * np.pi * loops / phase[-1]
    if not steady and rng.random() < 0.3:
        phase = phase[: int(n * (1.0 - rng.uniform(0.1, 0.3) / loops))]
    for _ in range(int(rng.integers(0, 3))):
        k = int(rng.integers(1, phase.size - 1))
        hold = np.full(int(rng.uniform(0.5, 2.5) * _FINE_HZ), phase[k])
        phase = np.concatenate([phase[:k], hold, phase[k:]])
    return phase


def _eased(a: FloatArray, b: FloatArray, seconds: float) -> FloatArray:
    u = 0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, int(seconds * _FINE_HZ)))
    return a + u[:, None] * (b - a)


def _away(point: FloatArray, rng: np.random.Generator) -> FloatArray:
    angle = rng.uniform(0.0, 2 * np.pi)
    return point + rng.uniform(0.06, 0.2) * np.array([math.cos(angle), math.sin(angle)])


def _demo(
    task: GuidedTask,
    rng: np.random.Generator,
    k: int,
    steady: bool,
    theta: float,
    rho: float,
    hidden: bool,
    shape: LoopShape | None,
) -> OperatorDemo:
    loops = int(rng.integers(2, 4)) if steady else int(rng.integers(1, 6))
    phase = rng.uniform(0.0, 2 * np.pi) + _phase(rng, loops, steady)
    drawn_loop = canonical_shape(task, phase) if shape is None else shape.at(phase)
    loop = similarity_transform(drawn_loop, theta, rho)
    rest0, rest1 = _away(loop[0], rng), _away(loop[-1], rng)
    parts = [
        np.repeat(rest0[None], int(rng.uniform(0.3, 1.5) * _FINE_HZ), axis=0),
        _eased(rest0, loop[0], rng.uniform(1.0, 2.5)),
        loop,
        _eased(loop[-1], rest1, rng.uniform(1.0, 2.5)),
        np.repeat(rest1[None], int(rng.uniform(0.3, 1.5) * _FINE_HZ), axis=0),
    ]
    before = parts[0].shape[0] + parts[1].shape[0]
    intended = np.concatenate(parts)
    on = np.zeros(intended.shape[0], dtype=bool)
    on[before : before + loop.shape[0]] = True
    fine_t = np.arange(intended.shape[0]) / _FINE_HZ
    drawn = intended.copy()
    if not steady:
        for axis in range(2):
            for _ in range(3):
                freq, amp = rng.uniform(0.1, 0.6), rng.uniform(0.001, 0.004)
                drawn[:, axis] += amp * np.sin(2 * np.pi * freq * fine_t + rng.uniform(0, 7))
    rate = float(rng.choice([15.0, 30.0, 60.0, 120.0]))
    steps = rng.uniform(0.7, 1.3, size=int(fine_t[-1] * rate * 1.5) + 2) / rate
    steps += np.where(rng.random(steps.size) < 0.005, rng.uniform(0.2, 0.6, steps.size), 0.0)
    t = np.concatenate([[0.0], np.cumsum(steps)])
    t = t[t <= fine_t[-1]]
    pick = np.clip(np.round(t * _FINE_HZ).astype(int), 0, fine_t.size - 1)
    noise = 0.0003 if steady else rng.uniform(0.001, 0.003)
    x = drawn[pick] + rng.normal(0.0, noise, size=(pick.size, 2))
    times = rng.uniform(0.0, 100.0) + t
    demo = Demo(
        positions=resample_uniform(x, times, DEFAULT_SAMPLES),
        task=task,
        file="operators",
        name=f"demo_{k}",
        demonstrator=f"operator{k}",
        theta_deg=None if hidden else theta,
        rho=None if hidden else rho,
        plane=default_plane(task),
        duration_s=float(times[-1] - times[0]),
        raw_positions=x,
        raw_times_s=times,
    )
    return OperatorDemo(demo, intended[pick], on[pick], theta, rho, loops)
