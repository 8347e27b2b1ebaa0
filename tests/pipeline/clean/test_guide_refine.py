"""The last step of the θ/ρ estimate: the robust least-squares similarity over every sample."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bt_pipeline.clean import span_fit
from bt_pipeline.clean.guide_fit import GuideFit, fit_guide
from bt_pipeline.clean.guide_refine import refine_fit
from bt_pipeline.clean.periodic import pool_preferences
from bt_pipeline.clean.segment import segment_demo
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.data.shapes import canonical_shape, similarity_transform
from bt_pipeline.data.synth import lopsided
from bt_pipeline.data.synth_human import make_human_set
from bt_pipeline.data.synth_truth import oracle_similarity
from bt_pipeline.data.tasks import Task
from bt_pipeline.testing.operator_sets import operator_set


def _wobbly_loop(
    task: Task, theta: float, rho: float, seed: int, loops: float = 3.0
) -> tuple[np.ndarray, np.ndarray]:
    """Loops of the guide at 50 Hz with a slow wobble (sinusoids of 2-4 mm) and 1 mm noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 4.0 * loops, 0.02)
    phase = 2 * np.pi * t / 4.0 + 0.3 * np.sin(2 * np.pi * 0.1 * t)
    loop = similarity_transform(canonical_shape(task, phase), theta, rho)
    for axis in range(2):
        for _ in range(3):
            freq, amp = rng.uniform(0.1, 0.6), rng.uniform(0.002, 0.004)
            loop[:, axis] += amp * np.sin(2 * np.pi * freq * t + rng.uniform(0, 7))
    return loop + rng.normal(0.0, 0.001, loop.shape), t


def test_wobbly_operators_are_read_closer_to_their_true_scale() -> None:
    """On the independent generator's wobbly operators (θ/ρ hidden), the median |Δρ| of the
    per-demo estimates is smaller with the refinement than with the trimmed fit alone, and
    |Δθ| is no worse (16 demos; without it 0.0147 / 0.88°, with it 0.0094 / 0.62°)."""
    errors: dict[bool, list[tuple[float, float]]] = {False: [], True: []}
    refined = span_fit.refine_fit
    try:
        for refine in (False, True):
            span_fit.refine_fit = refined if refine else (lambda y, fit, *a, **k: fit)  # type: ignore[assignment]
            for seed in range(4):
                ops = operator_set("wiping", seed, hidden=True)
                for i, op in enumerate(ops.demos):
                    if i == ops.steady_index:
                        continue
                    positions, times = op.demo.raw_samples()
                    fit = segment_demo(positions, times, "wiping").guide
                    errors[refine].append(
                        (abs(fit.theta_deg - op.theta_deg), abs(fit.rho - op.rho))
                    )
    finally:
        span_fit.refine_fit = refined
    before, after = np.array(errors[False]), np.array(errors[True])
    assert np.median(after[:, 1]) < 0.8 * np.median(before[:, 1])
    assert np.median(after[:, 0]) <= np.median(before[:, 0])


@pytest.mark.parametrize("task", ["wiping", "weaving", "pick_and_place"])
def test_refinement_reads_wobbly_loops_closer_than_the_trimmed_fit(task: Task) -> None:
    """8 wobbly demos of 3 loops per task, refined from the trimmed fit: median |Δρ| and |Δθ|
    both smaller (measured: ρ 0.0137 → 0.0074, 0.0085 → 0.0037, 0.0093 → 0.0053; θ 1.47° →
    1.01°, 0.43° → 0.19°, 0.59° → 0.22°)."""
    trimmed, refined = [], []
    for seed in range(8):
        positions, _ = _wobbly_loop(task, 12.0, 1.15, seed)
        fit = fit_guide(positions, task)
        trimmed.append((abs(fit.theta_deg - 12.0), abs(fit.rho - 1.15)))
        fit = refine_fit(positions, fit)
        refined.append((abs(fit.theta_deg - 12.0), abs(fit.rho - 1.15)))
    before, after = np.median(trimmed, axis=0), np.median(refined, axis=0)
    assert after[1] < 0.8 * before[1]
    assert after[0] < before[0]


def test_spikes_do_not_pull_the_refinement() -> None:
    """Five 3 cm spikes in a clean loop: the robust weights leave θ/ρ where the loop is."""
    positions, _ = _wobbly_loop("wiping", -20.0, 0.9, seed=1)
    rng = np.random.default_rng(0)
    for k in rng.choice(positions.shape[0], 5, replace=False):
        positions[k] += 0.03
    fit = refine_fit(
        positions, GuideFit(-20.5, 0.91, np.zeros(2), 0.002, 0.2, LoopShape.guide("wiping"))
    )
    assert abs(fit.rho - 0.9) < 0.01
    assert abs(fit.theta_deg + 20.0) < 1.0


def test_a_lopsided_loop_keeps_its_true_side_fit() -> None:
    """A loop drawn 30 % bigger on one side: fitted to its true side, the refinement (which would
    be pulled to the compromise without its basin bound) leaves it there."""
    phase = np.linspace(0.0, 6 * np.pi, 1500)
    drawn, _ = lopsided(canonical_shape("wiping", phase), "wiping", np.random.default_rng(3))
    positions = similarity_transform(drawn, 10.0, 1.1)
    fit = fit_guide(positions, "wiping")
    assert abs(fit.rho - 1.1) < 0.05  # The consensus finds the true side.
    refined = refine_fit(positions, fit)
    assert abs(refined.rho - 1.1) < 0.05
    assert abs(refined.theta_deg - 10.0) < 5.0


def test_known_values_stay_fixed_and_bad_input_keeps_the_fit() -> None:
    """A known θ (ρ) is held; both known, too few samples or NaN return the fit unchanged."""
    positions, _ = _wobbly_loop("weaving", 5.0, 1.2, seed=2)
    start = GuideFit(6.0, 1.22, np.zeros(2), 0.002, 0.36, LoopShape.guide("weaving"))
    assert refine_fit(positions, start, theta_deg=6.0).theta_deg == 6.0
    assert refine_fit(positions, start, rho=1.22).rho == 1.22
    assert refine_fit(positions, start, theta_deg=6.0, rho=1.22) is start
    assert refine_fit(positions[:5], start) is start
    broken = positions.copy()
    broken[10] = np.nan
    assert refine_fit(broken, start) is start


def test_a_fast_incomplete_arch_keeps_its_right_estimate_in_the_pooling() -> None:
    """Human-style pick-and-place, a set of 8, seed 1, every time halved (drawn twice as fast):
    demonstrator 3's incomplete arch (demo 3) is read within 0.2 % of its ρ, their lopsided arch
    (demo 7) 16 % large. Read on the analysis path (σ = 0.08 s, which shrinks a fast loop), the
    right fit's misfit was 4.9 mm, about the lopsided one's, and the pooling took the lopsided
    one; read on the path θ/ρ are fitted to it is under 3 mm and the pooled ρ is right."""
    synth = make_human_set("pick_and_place", 8, 1)
    records = list(synth.recording.demos.values())
    demos, segments = [], []
    for i in (3, 7):
        uv, t = demos_from_recording(synth.recording)[i].raw_samples()
        fast = t[0] + 0.5 * (t - t[0])
        demo = dataclasses.replace(
            demos_from_recording(synth.recording)[i],
            raw_times_s=fast,
            duration_s=0.5 * (t[-1] - t[0]),
        )
        demos.append(demo)
        segments.append(segment_demo(uv, fast, "pick_and_place"))
    truth = records[3].attrs["truth_rho"]
    assert records[7].attrs["truth_rho"] == truth  # One demonstrator.
    assert abs(segments[0].guide.rho - truth) < 0.01
    assert segments[0].misfit_m < 0.003
    assert segments[0].misfit_m < segments[1].misfit_m
    pooled = pool_preferences(demos, segments)
    assert abs(pooled[0].rho - truth) < 0.02
    assert abs(pooled[1].rho - truth) < 0.02


def test_the_oracle_similarity_reads_a_known_rotation_and_scale() -> None:
    """The benchmarks' reference: a drawn loop that is the intended one turned by 2°, scaled by
    1.03 and moved reads (2°, 1.03); samples off the loop part do not count."""
    intended, _ = _wobbly_loop("wiping", 0.0, 1.0, seed=0, loops=1.0)
    drawn = similarity_transform(intended, 2.0, 1.03) + np.array([0.01, -0.02])
    on_loop = np.ones(len(drawn), dtype=bool)
    on_loop[:20] = False
    drawn[:20] = 5.0  # An approach far away, off the loop part.
    turn, scale = oracle_similarity(drawn, intended, on_loop)
    assert turn == pytest.approx(2.0, abs=1e-9)
    assert scale == pytest.approx(1.03, abs=1e-12)
