"""Synthetic crowds whose naive demonstrators share biases (``bt synth --crowd shared``).

The default generators (:mod:`bt_pipeline.data.synth`, :mod:`bt_pipeline.data.synth_human`) draw
every defect independently per demo, so a learner that pools the demos averages them out. Real
crowds share their mistakes: people cut the same corner, pause at the same tricky spot. This
generator draws each bias **once per set** from the seed and applies it to every naive demo,
with small per-demo variation (interval edges and pause phase ±1 % of the loop, magnitudes
±15 %, pause length ±20 %, drift direction ±10°); the expert-like demos get none of them.
Phases are fractions of the loop; the size is the larger side of the loop's bounding box:

=============  =============================================================================
bias           what every naive demo does (set-level magnitudes drawn from the seed)
=============  =============================================================================
corner_cut     over one phase interval of 10-20 % of the loop the path is a blend of the loop
               and its chord, weight 0.6-1.0 on the chord (1 is the straight chord); the
               interval is drawn among those whose chord cuts deepest (a real corner)
undershoot     over another phase interval of 15-25 % of the loop the hand falls short: the
               path is pulled toward the loop's centre (the centre of its bounding box) by
               15-30 % at the interval's middle, tapering smoothly (sin²) to nothing at its
               ends, as a hand that does not reach all the way out
hesitation     a pause of 0.3-1.0 s at one shared phase (a flat-topped slow-down to 3 % speed),
               20-80 % of the way along the part the demos draw
backwards      one demonstrator (of those with naive demos, when at least three have some)
               draws the loop in the reverse direction: a minority, e.g. 1 of 4
bulge          over another phase interval of 15-25 % of the loop the path swings out along
               the loop's normal by 8-15 % of its size at the interval's middle, tapering
               (sin²) to nothing at its ends; always to the same side of the loop (the side
               outward at the interval's middle), whichever way the demo travels
drift          a translation growing linearly with the part of the loop drawn, from nothing
               at the start to 3-8 % of the loop's size where the hand stops, in one
               direction drawn per set (uniform over 360°)
wrong_lobe     only on a loop that crosses itself (weaving's figure-eight; some random
               loops), found numerically (the crossing splitting the loop most evenly, both
               lobes at least 20 % of it): arriving at the crossing, the hand turns back into
               the lobe it came from instead of crossing over, so it goes round that lobe
               twice and never into the other (drawn per set); the turn is a "kiss": over
               ±2-3 % of the loop about each pass the path blends (smootherstep) from the
               branch it came on to the one it leaves on, touching the crossing point.
               Absent (not in ``biases``) on a loop without a crossing
missing_part   an interval of 8-15 % of the loop is left out: every naive demo starts right
               after it (right before it, backwards) and stops short before it, easing to a
               stop over ±2 % of the loop, then rests there for the time the rest of the
               loop would have taken: an incomplete loop, open at the same place
=============  =============================================================================

The cut, undershoot, bulge and left-out intervals do not overlap: the three follow the cut round
the loop in a random order with at least 3 % of the loop between any two. The wrong lobe remaps
the phase before the cut, undershoot and bulge shape the loop, so they fall where the hand is
(:mod:`bt_pipeline.data.crowd_biases` gives the order). Every naive demo also has its own
high-frequency noise as in the default style (white jitter 2-6 mm, a 6-10 Hz tremor 3-8 mm, or
both; :func:`~bt_pipeline.data.synth.add_noise_and_outliers`). ``experts`` of the demos (drawn
from the seed; default 1, 0 for none) are expert-like: 0.3 mm noise, no bias, the canonical
direction, a random start.

Each demo is one loop of 5-8 s of motion (plus its pause) at 50 Hz with a mild speed swell, by
demonstrator k mod 4 (:data:`~bt_pipeline.data.synth.DEMONSTRATORS`, known θ/ρ; with
``same_preference`` every demonstrator draws at θ = 0, ρ = 1), in the task's default plane. The
ground truth is stored as the default style stores it: ``SynthDemo.truth`` (the set's loop under
the demo's θ/ρ, 600 points) and the ``truth_*`` attrs (the intended full loop at the demo's own
timing and direction, pause included, biases and noise not). ``ep_meta["synthetic"]`` holds
``is_expert``, ``defects`` (noise and hesitation, in :data:`~bt_pipeline.data.synth.DEFECTS`
terms), ``biases`` (the shared ones it carries), ``direction`` (±1), ``params`` (the set's
:class:`~bt_pipeline.data.crowd_biases.CrowdBiases`) and ``demo_params`` (its own).
"""

from __future__ import annotations

import dataclasses
import math
from datetime import UTC, datetime, timedelta
from typing import Any

import numpy as np

from bt_pipeline.data.crowd_biases import (
    CROWD_BIASES,
    CrowdBias,
    CrowdBiases,
    Loop,
    apply_biases,
    draw_biases,
    drift_offsets,
    stop_short,
    varied_biases,
)
from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.records import DemoRecord, FloatArray, forward_difference_actions
from bt_pipeline.data.shapes import similarity_transform
from bt_pipeline.data.synth import (
    DEMONSTRATORS,
    SAMPLE_RATE_HZ,
    TRUTH_SAMPLES,
    Defect,
    SynthDemo,
    SynthSet,
    add_noise_and_outliers,
    check_set_args,
    synthetic_recording,
)
from bt_pipeline.data.synth_loop import loop_positions, resolve_task
from bt_pipeline.data.synth_truth import truth_attrs
from bt_pipeline.data.tasks import Task
from bt_pipeline.exceptions import ConfigError

_CROWD_KEY = 36  # Seeds the crowd's streams apart from make_demo_set's (issue 36).
_PAUSE_SPEED = 0.03  # Relative speed at the bottom of a pause.
_BUMP_AREA = 2.0 * math.gamma(1.25)  # ∫ exp(-x⁴) dx over the real line.
_NOISE_CHOICES: tuple[tuple[Defect, ...], ...] = (("jitter",), ("tremor",), ("jitter", "tremor"))
_CREATED_EPOCH = datetime(2026, 1, 1, tzinfo=UTC)  # As the default style's: reproducible files.


def make_crowd_set(
    task: Task | str,
    n_demos: int = 4,
    seed: int = 0,
    *,
    experts: int = 1,
    shape: LoopShape | None = None,
    same_preference: bool = False,
) -> SynthSet:
    """Generate a crowd set of `n_demos` demos whose naive demos share biases (module doc).

    Demo k is named ``demo_<k>`` and belongs to demonstrator ``DEMONSTRATORS[k % 4]``.

    Args:
        task: The task (a :data:`bt_pipeline.data.tasks.Task` name; with a shape, any safe name).
        n_demos: Number of demos, >= 1.
        seed: Seed of the random generator, an integer >= 0; the same seed gives the same set.
        experts: How many demos are expert-like (0.3 mm noise, no bias), 0..n_demos.
        shape: The loop every demo draws, in task coordinates [m]; None: the task's guide.
        same_preference: Every demonstrator draws at θ = 0, ρ = 1 (their stored θ/ρ and truth
            too): an ablation where the crowd shares one preference. The file's env_kwargs then
            hold ``same_preference: true``.

    Returns:
        The set. Its ``expert_index`` is the first expert-like demo's index, or -1 when
        `experts` is 0 (then ``expert_name`` has no meaning).

    Raises:
        UnknownTaskError: `task` is not a known task and no shape is given.
        ConfigError: `n_demos` < 1, `seed` is not an integer >= 0, `experts` is not an integer
            in 0..n_demos, or an unsafe task name.
    """
    task, task_index, plane = resolve_task(task, shape)
    n_demos, seed = check_set_args(n_demos, seed)
    if isinstance(experts, bool) or not isinstance(experts, int | np.integer):
        raise ConfigError(f"experts must be an integer in 0..n_demos; got {experts!r}")
    if not 0 <= experts <= n_demos:
        raise ConfigError(f"experts must be in 0..n_demos ({n_demos}); got {experts}")
    experts = int(experts)
    rng = np.random.default_rng([seed, task_index, _CROWD_KEY])
    expert_ks = {int(k) for k in rng.choice(n_demos, size=experts, replace=False)}
    naive_teachers = sorted({k % len(DEMONSTRATORS) for k in range(n_demos) if k not in expert_ks})

    def loop(phase: FloatArray) -> FloatArray:
        return loop_positions(task, shape, phase)

    centre = np.zeros(2) if shape is None else shape.centre
    biases = draw_biases(loop, naive_teachers, rng)
    demos = tuple(
        _make_demo(
            k, k in expert_ks, biases, (seed, task_index), plane, loop, centre, same_preference
        )
        for k in range(n_demos)
    )
    env_kwargs = {"task": task, "seed": seed, "preset": "crowd", "n_demos": n_demos}
    env_kwargs |= {"crowd": "shared", "experts": experts}
    if same_preference:
        env_kwargs["same_preference"] = True
    recording = synthetic_recording(task, plane, [d.record for d in demos], env_kwargs, shape)
    expert_index = min(expert_ks) if expert_ks else -1
    return SynthSet(task=task, recording=recording, demos=demos, expert_index=expert_index)


def _timing(
    rng: np.random.Generator, pause_s: float, pause_at: float
) -> tuple[FloatArray, FloatArray]:
    """Sample times [s] (T,) and the progress along the loop in [0, 1] at each, shape (T,).

    The motion lasts 5-8 s with a mild natural speed swell (as the default style's); a pause of
    `pause_s` [s] (0: none) is centred where the progress reaches `pause_at`.
    """
    move_s = float(rng.uniform(5.0, 8.0))
    a1, a2 = float(rng.uniform(0.05, 0.12)), float(rng.uniform(0.0, 0.05))
    p1, p2 = (float(p) for p in rng.uniform(0.0, 2.0 * np.pi, size=2))

    def progress(tau: FloatArray) -> FloatArray:  # ∫ speed, full periods integrate to move_s
        w = 2.0 * np.pi / move_s
        swell = a1 / w * (np.cos(p1) - np.cos(w * tau + p1))
        swell += a2 / (2.0 * w) * (np.cos(p2) - np.cos(2.0 * w * tau + p2))
        return (tau + swell) / move_s

    t = np.arange(round((move_s + pause_s) * SAMPLE_RATE_HZ) + 1) / SAMPLE_RATE_HZ
    if pause_s <= 0.0:
        return t, progress(t * move_s / t[-1])
    fine = np.linspace(0.0, move_s, 4001)
    tau_pause = float(np.interp(pause_at, progress(fine), fine))
    half_width = pause_s / ((1.0 - _PAUSE_SPEED) * _BUMP_AREA)  # the bump loses pause_s
    bump = np.exp(-(((t - tau_pause - 0.5 * pause_s) / half_width) ** 4))
    speed = 1.0 - (1.0 - _PAUSE_SPEED) * bump
    tau = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t))])
    return t, progress(tau * move_s / tau[-1])


def _make_demo(
    k: int,
    is_expert: bool,
    set_biases: CrowdBiases,
    set_key: tuple[int, int],
    plane: TaskPlane,
    loop: Loop,
    centre: FloatArray,
    same_preference: bool,
) -> SynthDemo:
    """Demo k of a crowd set: one loop by demonstrator k mod 4, expert-like or biased.

    `set_key` is (seed, task key); `loop` maps phase [rad] to the set's loop [m], `centre` (2,)
    [m] is where an undershoot pulls toward; `same_preference`: θ = 0, ρ = 1 for everyone.
    """
    teacher = DEMONSTRATORS[k % len(DEMONSTRATORS)]
    theta_deg, rho = (0.0, 1.0) if same_preference else (teacher.theta_deg, teacher.rho)
    rng = np.random.default_rng([*set_key, _CROWD_KEY, k])
    biases = varied_biases(set_biases, rng)
    defects: tuple[Defect, ...] = ()
    applied: tuple[CrowdBias, ...] = ()
    direction = 1.0
    if is_expert:
        start = float(rng.uniform(0.0, 1.0))
        t, progress = _timing(rng, 0.0, 0.0)
    else:
        defects = (*_NOISE_CHOICES[int(rng.choice(3, p=[0.4, 0.3, 0.3]))], "hesitation")
        backwards = teacher.name == biases.backwards_teacher
        applied = tuple(
            b
            for b in CROWD_BIASES
            if (backwards or b != "backwards")
            and (biases.lobe_start is not None or b != "wrong_lobe")
        )
        direction = -1.0 if backwards else 1.0
        # Start right after the left-out interval (right before it, backwards) and pause where
        # the set pauses, 20-80 % of the way along the drawn part.
        missing_end = biases.missing_start + biases.missing_width
        start = (biases.missing_start if backwards else missing_end) % 1.0
        pause_at = float((direction * (biases.pause_phase - start)) % 1.0)
        t, progress = _timing(rng, biases.pause_s, pause_at)
    phase = 2.0 * np.pi * (start + direction * progress)
    demo_params: dict[str, Any] = {"duration_s": float(t[-1])}
    intended = similarity_transform(loop(phase), theta_deg, rho)
    if is_expert:
        uv = intended
    else:
        demo_params |= {
            n: v for n, v in dataclasses.asdict(biases).items() if n != "backwards_teacher"
        }
        drawn = stop_short(progress, biases)
        shaped = apply_biases(loop, 2.0 * np.pi * (start + direction * drawn), biases, centre)
        uv = similarity_transform(shaped + drift_offsets(drawn, biases), theta_deg, rho)
    uv = add_noise_and_outliers(uv, t, defects, rng, demo_params)

    ee_pos = plane.to_world(uv)
    record = DemoRecord(
        ee_pos=ee_pos,
        timestamps=t,
        demonstrator=teacher.name,
        theta_deg=theta_deg,
        rho=rho,
        source="synthetic",
        actions=forward_difference_actions(ee_pos, t),
        created=(_CREATED_EPOCH + timedelta(hours=set_key[0] % 8760, minutes=k)).isoformat(),
        # Ground truth, as in the default style (bt_pipeline.data.synth).
        attrs=truth_attrs(intended, np.ones(t.size), theta_deg, rho, 1.0),
        ep_meta={
            "synthetic": {
                "is_expert": is_expert,
                "defects": list(defects),
                "biases": list(applied),
                "direction": int(direction),
                "start_phase_rad": 2.0 * math.pi * start,
                "params": dataclasses.asdict(set_biases),
                "demo_params": demo_params,
            }
        },
    )
    truth = loop(2.0 * np.pi * np.arange(TRUTH_SAMPLES) / TRUTH_SAMPLES)
    return SynthDemo(
        name=f"demo_{k}",
        record=record,
        truth=similarity_transform(truth, theta_deg, rho),
        is_expert=is_expert,
        defects=defects,
    )


__all__ = ["make_crowd_set"]
