"""Synthetic mixed-skill demonstrators with known ground truth.

Four demonstrators (paper Sec. IV, Fig. 4) each draw the task's canonical shape
(:mod:`bt_pipeline.data.shapes`) under their own preference: rotation θ and scale ρ, about the task
centre (the origin of the task plane; all demonstrators work at the same place). Demo k belongs to
demonstrator k mod 4, so a 4-demo set is the paper's D1 (one demo each) and a 20-demo set its D2
(five each).

Every set holds exactly one expert-like demo (which one is drawn from the seed): tiny noise
(0.3 mm) and a mild, natural speed variation. Every other demo is naive: high-frequency noise
(white jitter, a 6-10 Hz tremor, or both) plus 1-3 further defects, at least one of which
(drift, incomplete or lopsided) changes the drawn loop as a whole:

==============  ============================================================================
defect          what it does (magnitudes drawn per demo)
==============  ============================================================================
jitter          white noise, std 2-6 mm per axis
tremor          band-limited 6-10 Hz oscillation, amplitude 3-8 mm per axis
drift           translation growing over the demo to 2-4 cm at the end
incomplete      the loop stops short at 70-90 % of its phase
spikes          2-5 outliers of 1-3 cm lasting 1-2 samples
lopsided        one side (left or right) bulged out by 20-35 %
speed           strongly uneven phase progression (±30-60 % speed)
hesitation      1-2 pauses of 0.4-1.0 s
==============  ============================================================================

Each demo is one loop of 5-8 s sampled at 50 Hz from a random start phase, in the canonical
direction, mapped to 3-D with the task's default plane. The ground truth of a demo is the
canonical loop under its θ and ρ at the task centre, 600 points over one full period; the
intended path at the demo's own timing (its phase progression without noise and defects) is
stored in the demo's extra attrs as in the human style (``truth_uv``, ``truth_on_loop``, ...;
see :mod:`bt_pipeline.data.synth_human`).

Both styles draw the task's guide unless given a ``shape`` (a
:class:`~bt_pipeline.data.loop_shape.LoopShape`, e.g. from
:mod:`bt_pipeline.data.random_loops`): every demo of the set then draws that loop, its truth is
that loop, and the recording's ``env_kwargs`` hold it (:mod:`bt_pipeline.data.synth_loop`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any, Literal, get_args

import numpy as np

from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.recording import DEFAULT_ENV_TYPE
from bt_pipeline.data.records import DemoRecord, FloatArray, Recording, forward_difference_actions
from bt_pipeline.data.shapes import canonical_loop, similarity_transform
from bt_pipeline.data.synth_loop import loop_positions, lopsided, resolve_task, shape_kwargs
from bt_pipeline.data.synth_truth import truth_attrs
from bt_pipeline.data.tasks import Task
from bt_pipeline.exceptions import ConfigError

Defect = Literal[
    "jitter", "tremor", "drift", "incomplete", "spikes", "lopsided", "speed", "hesitation"
]
"""A defect of a naive synthetic demo."""

DEFECTS: tuple[Defect, ...] = get_args(Defect)
NOISE_DEFECTS: tuple[Defect, ...] = ("jitter", "tremor")
"""High-frequency noise: every naive demo has at least one."""
SHAPE_DEFECTS: tuple[Defect, ...] = ("drift", "incomplete", "lopsided")
"""Defects that change the drawn loop as a whole: every naive demo has at least one."""
OUTLIER_DEFECTS: tuple[Defect, ...] = ("spikes",)
"""Defects that leave the loop but for a few samples."""
TIMING_DEFECTS: tuple[Defect, ...] = ("speed", "hesitation")
"""Defects that change only when the demo gets there."""

SAMPLE_RATE_HZ = 50.0
"""Recording rate of the synthetic demos [Hz]."""
TRUTH_SAMPLES = 600
"""Points of the dense ground-truth loop of each demo."""
EXPERT_NOISE_STD_M = 0.0003
"""Position noise of the expert-like demo, std per axis [m]."""
ENV_NAME = "bt_synthetic"
"""``env_args["env_name"]`` of synthetic recordings."""
_CREATED_EPOCH = datetime(2026, 1, 1, tzinfo=UTC)  # Fixed, so files are reproducible.


@dataclass(frozen=True)
class Demonstrator:
    """A synthetic teacher and their preference (paper Sec. III-A)."""

    name: str
    """Name stored as the demo's ``demonstrator``."""
    theta_deg: float
    """Rotation θ [deg], counter-clockwise."""
    rho: float
    """Scale ρ."""


DEMONSTRATORS: tuple[Demonstrator, ...] = (
    Demonstrator("teacher_a", 5.0, 1.0),
    Demonstrator("teacher_b", -5.0, 1.1),
    Demonstrator("teacher_c", 10.0, 1.2),
    Demonstrator("teacher_d", -10.0, 1.3),
)
"""The paper's four demonstrators (Sec. IV: θ = {5, -5, 10, -10}°, ρ = {1, 1.1, 1.2, 1.3})."""


@dataclass(frozen=True)
class SynthDemo:
    """One synthetic demo with its ground truth."""

    name: str
    """``demo_<k>``."""
    record: DemoRecord
    """The demo as it is stored in a recording."""
    truth: FloatArray
    """Noise-free shape: the set's loop (the canonical one unless a shape was given) under the
    demo's θ and ρ at the task centre, shape (600, 2), in [m] (task coordinates), one full
    period, endpoint excluded."""
    is_expert: bool
    """Whether this is the set's expert-like demo."""
    defects: tuple[Defect, ...]
    """The demo's defects in :data:`DEFECTS` order; empty for the expert."""


@dataclass(frozen=True)
class SynthSet:
    """A synthetic mixed-skill demo set for one task."""

    task: Task
    """The task every demo performs (with a shape, any safe name)."""
    recording: Recording
    """The demos as a format-v1 recording (source "synthetic")."""
    demos: tuple[SynthDemo, ...]
    """The demos with their ground truth, in the order of k."""
    expert_index: int
    """Index into `demos` of the (first) expert-like demo; -1 for a crowd set without one
    (:func:`bt_pipeline.data.synth_crowd.make_crowd_set` with ``experts=0``)."""

    @property
    def expert_name(self) -> str:
        """Name of the (first) expert-like demo (``demo_<k>``).

        Raises:
            ConfigError: The set has no expert-like demo.
        """
        if not 0 <= self.expert_index < len(self.demos):
            raise ConfigError("this set has no expert-like demo")
        return self.demos[self.expert_index].name

    @property
    def truth_by_name(self) -> dict[str, FloatArray]:
        """Ground-truth shape of every demo by name, shape (600, 2) each, in [m]."""
        return {d.name: d.truth for d in self.demos}


def make_demo_set(
    task: Task | str, n_demos: int = 4, seed: int = 0, *, shape: LoopShape | None = None
) -> SynthSet:
    """Generate a mixed-skill set of `n_demos` demos of `task`, deterministic for `seed`.

    Demo k is named ``demo_<k>`` and belongs to demonstrator ``DEMONSTRATORS[k % 4]``.

    Args:
        task: The task (a :data:`bt_pipeline.data.tasks.Task` name; with a shape, any safe name).
        n_demos: Number of demos, >= 1.
        seed: Seed of the random generator, an integer >= 0.
        shape: The loop every demo draws, in task coordinates [m]; None: the task's guide.

    Returns:
        The set, with exactly one expert-like demo.

    Raises:
        UnknownTaskError: `task` is not a known task and no shape is given.
        ConfigError: `n_demos` < 1, `seed` is not an integer >= 0, or an unsafe task name.
    """
    task, task_index, plane = resolve_task(task, shape)
    n_demos, seed = check_set_args(n_demos, seed)
    expert_index = int(np.random.default_rng([seed, task_index]).integers(n_demos))
    demos = tuple(
        _make_demo(
            task,
            k,
            k == expert_index,
            np.random.default_rng([seed, task_index, k]),
            seed,
            plane,
            shape,
        )
        for k in range(n_demos)
    )
    preset = {4: "D1", 20: "D2"}.get(n_demos, "custom")
    env_kwargs = {"task": task, "seed": seed, "preset": preset, "n_demos": n_demos}
    recording = synthetic_recording(task, plane, [d.record for d in demos], env_kwargs, shape)
    return SynthSet(task=task, recording=recording, demos=demos, expert_index=expert_index)


def synthetic_recording(
    task: Task,
    plane: TaskPlane,
    records: list[DemoRecord],
    env_kwargs: dict[str, Any],
    shape: LoopShape | None,
) -> Recording:
    """A generated set as a format-v1 recording: demo_<k> records, ``env_args`` naming the
    generator, its settings `env_kwargs` and the set's loop (every generator's)."""
    return Recording(
        task=task,
        plane=plane,
        demos={f"demo_{k}": record for k, record in enumerate(records)},
        env_args={
            "env_name": ENV_NAME,
            "type": DEFAULT_ENV_TYPE,
            "env_kwargs": {**env_kwargs, **shape_kwargs(shape)},
        },
    )


def check_set_args(n_demos: object, seed: object) -> tuple[int, int]:
    """`n_demos` (an integer ≥ 1) and `seed` (an integer ≥ 0) as ints, or a ConfigError."""
    if isinstance(n_demos, bool) or not isinstance(n_demos, int | np.integer) or n_demos < 1:
        raise ConfigError(f"n_demos must be an integer >= 1; got {n_demos!r}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ConfigError(f"seed must be an integer >= 0; got {seed!r}")
    return int(n_demos), int(seed)


def make_d1(task: Task | str, seed: int = 0, *, shape: LoopShape | None = None) -> SynthSet:
    """The paper's D1: 4 demos, one per demonstrator (Sec. IV)."""
    return make_demo_set(task, n_demos=4, seed=seed, shape=shape)


def make_d2(task: Task | str, seed: int = 0, *, shape: LoopShape | None = None) -> SynthSet:
    """The paper's D2: 20 demos, five per demonstrator (Sec. IV)."""
    return make_demo_set(task, n_demos=20, seed=seed, shape=shape)


def draw_defects(rng: np.random.Generator) -> tuple[Defect, ...]:
    """HF noise (jitter, tremor or both) plus 1-3 others, at least one changing the shape."""
    noise = [("jitter",), ("tremor",), ("jitter", "tremor")][int(rng.choice(3, p=[0.4, 0.3, 0.3]))]
    n_other = int(rng.integers(1, 4))
    first = SHAPE_DEFECTS[int(rng.integers(len(SHAPE_DEFECTS)))]
    pool = [d for d in (*SHAPE_DEFECTS, *OUTLIER_DEFECTS, *TIMING_DEFECTS) if d != first]
    rest = [pool[int(i)] for i in rng.choice(len(pool), size=n_other - 1, replace=False)]
    chosen = {*noise, first, *rest}
    return tuple(d for d in DEFECTS if d in chosen)


def _speed_profile(
    s: FloatArray, duration_s: float, defects: tuple[Defect, ...], rng: np.random.Generator
) -> FloatArray:
    """Relative phase speed over normalised time `s` (shape (T,)), > 0 except in pauses."""
    # Natural variation, also the expert's: a slow ±5-12 % swell plus a little second harmonic.
    speed = 1.0 + rng.uniform(0.05, 0.12) * np.sin(2 * np.pi * s + rng.uniform(0, 2 * np.pi))
    speed += rng.uniform(0.0, 0.05) * np.sin(4 * np.pi * s + rng.uniform(0, 2 * np.pi))
    if "speed" in defects:
        weights = rng.dirichlet(np.ones(3)) * rng.uniform(0.3, 0.6)
        for w in weights:
            speed += w * np.sin(2 * np.pi * rng.uniform(0.5, 4.0) * s + rng.uniform(0, 2 * np.pi))
        speed = np.maximum(speed, 0.15)
    if "hesitation" in defects:
        for _ in range(int(rng.integers(1, 3))):
            centre = rng.uniform(0.1, 0.9)
            half_width = 0.5 * rng.uniform(0.4, 1.0) / duration_s
            bump = np.exp(-(((s - centre) / half_width) ** 4))  # flat-topped pause
            speed = speed * (1.0 - 0.97 * bump)
    return speed


def _phase(speed: FloatArray, s: FloatArray, fraction: float) -> FloatArray:
    """Progress u(s) ∈ [0, fraction] of the loop, the normalised integral of `speed`."""
    steps = 0.5 * (speed[1:] + speed[:-1]) * np.diff(s)
    progress = np.concatenate([[0.0], np.cumsum(steps)])
    return fraction * progress / progress[-1]


def _tremor(t: FloatArray, amplitude: float, rng: np.random.Generator) -> FloatArray:
    """6-10 Hz oscillation per axis with a slowly varying envelope, RMS amplitude/√2."""
    out = np.zeros((t.size, 2))
    for axis in range(2):
        for _ in range(3):
            freq = rng.uniform(6.0, 10.0)
            out[:, axis] += rng.uniform(0.5, 1.0) * np.sin(2 * np.pi * freq * t + rng.uniform(0, 7))
        envelope = 1.0 + 0.4 * np.sin(2 * np.pi * rng.uniform(0.1, 0.4) * t + rng.uniform(0, 7))
        out[:, axis] *= envelope
        out[:, axis] *= amplitude / (math.sqrt(2.0) * float(np.std(out[:, axis])))
    return out


def add_noise_and_outliers(
    uv: FloatArray,
    t: FloatArray,
    defects: tuple[Defect, ...],
    rng: np.random.Generator,
    params: dict[str, Any],
) -> FloatArray:
    """`uv` (shape (T, 2), [m]) with the demo's noise, drift and spikes added; records params."""
    out = uv.copy()
    s = t / t[-1]
    if not defects:  # the expert-like demo
        out += rng.normal(0.0, EXPERT_NOISE_STD_M, size=out.shape)
    if "jitter" in defects:
        params["jitter_std_m"] = std = float(rng.uniform(0.002, 0.006))
        out += rng.normal(0.0, std, size=out.shape)
    if "tremor" in defects:
        params["tremor_amplitude_m"] = amplitude = float(rng.uniform(0.003, 0.008))
        out += _tremor(t, amplitude, rng)
    if "drift" in defects:
        params["drift_m"] = size = float(rng.uniform(0.02, 0.04))
        angle = rng.uniform(0.0, 2.0 * np.pi)
        growth = s ** rng.uniform(1.0, 2.0)
        out += size * growth[:, None] * np.array([np.cos(angle), np.sin(angle)])
    if "spikes" in defects:
        params["spikes"] = count = int(rng.integers(2, 6))
        for start in rng.choice(np.arange(1, t.size - 2), size=count, replace=False):
            angle = rng.uniform(0.0, 2.0 * np.pi)
            offset = rng.uniform(0.01, 0.03) * np.array([np.cos(angle), np.sin(angle)])
            out[start : start + int(rng.integers(1, 3))] += offset
    return out


def _make_demo(
    task: Task,
    k: int,
    is_expert: bool,
    rng: np.random.Generator,
    seed: int,
    plane: TaskPlane,
    shape: LoopShape | None,
) -> SynthDemo:
    """Demo k of a set: one loop drawn by demonstrator k mod 4, expert-like or naive."""
    teacher = DEMONSTRATORS[k % len(DEMONSTRATORS)]
    duration_s = float(rng.uniform(5.0, 8.0))
    t = np.arange(round(duration_s * SAMPLE_RATE_HZ) + 1) / SAMPLE_RATE_HZ
    s = t / t[-1]
    defects: tuple[Defect, ...] = () if is_expert else draw_defects(rng)
    params: dict[str, Any] = {"duration_s": float(t[-1])}

    # Where along the loop the hand is at each sample, in the demonstrator's own frame.
    fraction = float(rng.uniform(0.7, 0.9)) if "incomplete" in defects else 1.0
    if "incomplete" in defects:
        params["loop_fraction"] = fraction
    start_phase = float(rng.uniform(0.0, 2.0 * np.pi))
    speed = _speed_profile(s, duration_s, defects, rng)
    uv = loop_positions(task, shape, start_phase + 2.0 * np.pi * _phase(speed, s, fraction))
    intended = similarity_transform(uv, teacher.theta_deg, teacher.rho)
    if "lopsided" in defects:
        uv, extra = lopsided(uv, task, rng, shape)
        params.update(extra)
    uv = similarity_transform(uv, teacher.theta_deg, teacher.rho)
    uv = add_noise_and_outliers(uv, t, defects, rng, params)

    ee_pos = plane.to_world(uv)
    record = DemoRecord(
        ee_pos=ee_pos,
        timestamps=t,
        demonstrator=teacher.name,
        theta_deg=teacher.theta_deg,
        rho=teacher.rho,
        source="synthetic",
        actions=forward_difference_actions(ee_pos, t),
        created=(_CREATED_EPOCH + timedelta(hours=seed % 8760, minutes=k)).isoformat(),
        # Ground truth, as in the human style (bt_pipeline.data.synth_human).
        attrs=truth_attrs(intended, np.ones(t.size), teacher.theta_deg, teacher.rho, fraction),
        ep_meta={
            "synthetic": {
                "is_expert": is_expert,
                "defects": list(defects),
                "start_phase_rad": start_phase,
                "params": params,
            }
        },
    )
    truth_canonical = (
        canonical_loop(task, TRUTH_SAMPLES) if shape is None else shape.points(TRUTH_SAMPLES)
    )
    return SynthDemo(
        name=f"demo_{k}",
        record=record,
        truth=similarity_transform(truth_canonical, teacher.theta_deg, teacher.rho),
        is_expert=is_expert,
        defects=defects,
    )


__all__ = [
    "DEFECTS",
    "DEMONSTRATORS",
    "NOISE_DEFECTS",
    "OUTLIER_DEFECTS",
    "SAMPLE_RATE_HZ",
    "SHAPE_DEFECTS",
    "TIMING_DEFECTS",
    "TRUTH_SAMPLES",
    "Defect",
    "Demonstrator",
    "SynthDemo",
    "SynthSet",
    "lopsided",
    "make_d1",
    "make_d2",
    "make_demo_set",
]
