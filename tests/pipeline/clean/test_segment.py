"""Segmentation of the periodic part and the guide fit, against the human-style ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from bt_pipeline.clean.guide_fit import PreferenceRange, fit_guide
from bt_pipeline.clean.periodic import pool_preferences, segment_all
from bt_pipeline.clean.segment import segment_demo, track_phase
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.data.shapes import canonical_loop, similarity_transform
from bt_pipeline.data.synth import make_demo_set
from bt_pipeline.data.synth_human import make_human_set
from bt_pipeline.data.synth_truth import truth_of
from bt_pipeline.data.tasks import Task, default_plane
from bt_pipeline.exceptions import DemoError
from bt_pipeline.testing.operator_sets import operator_set


@pytest.mark.parametrize("task", ["wiping", "weaving", "pick_and_place"])
def test_expert_span_and_cycles_match_truth(task: Task) -> None:
    """The expert-like demo's kept span lies within 0.5 s of the true loop part; cycles ±0.3.

    Over 30 expert-like demos (10 seeds x 3 tasks) the start error's 10th-90th percentiles are
    -0.43..0.05 s and the end error's -0.05..0.09 s.
    """
    synth = make_human_set(task, 4, seed=3)
    demo = synth.demos[synth.expert_index]
    plane = default_plane(task)
    uv = plane.to_plane(demo.record.ee_pos)
    segment = segment_demo(uv, demo.record.timestamps, task, demo.name)
    on_times = demo.record.timestamps[demo.on_loop]
    assert abs(segment.start_s - on_times[0]) < 0.5
    assert abs(segment.end_s - on_times[-1]) < 0.5
    assert abs(segment.cycles - demo.cycles) < 0.3
    # Never re-based: the span lies inside the raw demo's own times.
    assert demo.record.timestamps[0] <= segment.start_s < segment.end_s
    assert segment.end_s <= demo.record.timestamps[-1]


def test_guide_fit_recovers_theta_rho_and_stays_in_range() -> None:
    loop = similarity_transform(canonical_loop("wiping", 300), 20.0, 1.3, (0.01, -0.02))
    fit = fit_guide(loop, "wiping")
    assert abs(fit.theta_deg - 20.0) < 0.5 and abs(fit.rho - 1.3) < 0.01
    # A wiping loop turned by 200° looks like one turned by 20°: the smallest rotation is kept.
    turned = similarity_transform(canonical_loop("wiping", 300), 200.0, 1.3)
    assert abs(fit_guide(turned, "wiping").theta_deg - 20.0) < 0.5
    narrow = fit_guide(loop, "wiping", allowed=PreferenceRange(10.0, 0.5, 1.2))
    assert narrow.theta_deg <= 10.0 + 1e-9 and narrow.rho <= 1.2 + 1e-9


def test_lopsided_loop_is_fitted_to_its_true_side() -> None:
    """One side drawn 30 % bigger: the fit follows the other side, not a compromise."""
    from bt_pipeline.data.shapes import canonical_shape
    from bt_pipeline.data.synth import lopsided

    phases = np.linspace(0.0, 2 * np.pi, 400, endpoint=False)
    cases: tuple[tuple[Task, float], ...] = (("wiping", 1.0), ("pick_and_place", -1.0))
    for task, side in cases:
        uv = canonical_shape(task, phases)
        rng = np.random.default_rng(3 if side > 0 else 4)
        bulged, _ = lopsided(uv, task, rng)
        drawn = similarity_transform(bulged, 12.0, 1.1)
        fit = fit_guide(drawn, task)
        assert abs(fit.rho - 1.1) < 0.05 and abs(fit.theta_deg - 12.0) < 5.0, (task, fit)


def test_lopsided_arch_is_fitted_centred_where_the_app_draws_the_guide() -> None:
    """Pick-and-place arches drawn bigger on one side, whose best similarity is a shifted
    compromise (these three failed before the centred candidates): the guide centred on the
    task plane's origin, where the app draws it, lets the fit follow the true side."""
    from bt_pipeline.data.shapes import canonical_shape
    from bt_pipeline.data.synth import lopsided

    phases = np.linspace(0.0, 2 * np.pi, 400, endpoint=False)
    for seed in (7, 11, 16):
        rng = np.random.default_rng(seed)
        bulged, _ = lopsided(canonical_shape("pick_and_place", phases), "pick_and_place", rng)
        theta, rho = rng.uniform(-30, 30), rng.uniform(0.75, 1.35)
        drawn = similarity_transform(bulged, theta, rho) + rng.normal(0.0, 0.001, (400, 2))
        fit = fit_guide(drawn, "pick_and_place")
        assert abs(fit.rho - rho) < 0.05 and abs(fit.theta_deg - theta) < 5.0, (seed, fit)


def test_lopsided_arches_are_read_from_centred_fits_alone() -> None:
    """Noisy arches (5 mm) drawn bigger on one side: with the loop near the origin, only fits
    centred there are modes, so the shifted compromise no longer wins, and among them the
    smallest ρ wins from 3 % below the median's. 30 seeds: 30 within 5° and 0.05 (26 from 6 %
    below; 13 with every fit a candidate, the rule before 2026-12-03 evening)."""
    from bt_pipeline.data.shapes import canonical_shape
    from bt_pipeline.data.synth import lopsided

    phases = np.linspace(0.0, 2 * np.pi, 400, endpoint=False)
    hits = 0
    for seed in range(30):
        rng = np.random.default_rng(seed)
        bulged, _ = lopsided(canonical_shape("pick_and_place", phases), "pick_and_place", rng)
        theta, rho = rng.uniform(-30, 30), rng.uniform(0.75, 1.35)
        drawn = similarity_transform(bulged, theta, rho) + rng.normal(0.0, 0.005, (400, 2))
        fit = fit_guide(drawn, "pick_and_place")
        hits += abs(fit.rho - rho) < 0.05 and abs(fit.theta_deg - theta) < 5.0
    assert hits >= 29


def test_closely_drawn_lopsided_arches_are_not_read_as_a_shifted_fit() -> None:
    """Three loops of an arch drawn bigger on one side, 1 mm of noise: the bulged side alone is
    nearly a similarity of the guide shifted 5-15 % of its size, and 90 % of the loop follows
    that fit within 0.5 % of its size. Such a fit once skipped the consensus (22 of these 30
    were read at the bulged side's θ/ρ); it is checked against the centred fits now."""
    from bt_pipeline.data.shapes import canonical_shape
    from bt_pipeline.data.synth import lopsided

    phases = np.linspace(0.0, 2 * np.pi * 3, 900)
    misses = []
    for seed in range(30):
        rng = np.random.default_rng(seed)
        theta, rho = rng.uniform(-30, 30), rng.uniform(0.75, 1.35)
        bulged, _ = lopsided(canonical_shape("pick_and_place", phases), "pick_and_place", rng)
        drawn = similarity_transform(bulged, theta, rho) + rng.normal(0.0, 0.001, bulged.shape)
        fit = fit_guide(drawn, "pick_and_place")
        if not (abs(fit.rho - rho) < 0.05 and abs(fit.theta_deg - theta) < 5.0):
            misses.append((seed, round(fit.theta_deg, 1), round(fit.rho, 3)))
    assert not misses


@pytest.mark.parametrize(
    ("task", "seed", "k"), [("pick_and_place", 52, 0), ("pick_and_place", 57, 2), ("wiping", 69, 0)]
)
def test_a_lopsided_loop_s_bulged_side_does_not_win_by_its_sample_count(
    task: Task, seed: int, k: int
) -> None:
    """Human-style lopsided demos, θ/ρ hidden (one loop with jitter; three with tremor and
    pauses; two with tremor). The bulged side is longer, so it holds more of the arc-length
    samples, and its fit won when fits were judged over 40 % of the points (ρ 10-32 % high).
    Judged over about the same share of each fit's own guide, the true side's fit wins."""
    synth = make_human_set(task, 4, seed, hidden=True)
    assert "lopsided" in synth.demos[k].defects
    attrs = synth.demos[k].record.attrs
    uv, t = demos_from_recording(synth.recording)[k].raw_samples()
    guide = segment_demo(uv, t, task).guide
    assert abs(guide.theta_deg - attrs["truth_theta_deg"]) < 5.0, guide
    assert abs(guide.rho - attrs["truth_rho"]) < 0.05, guide


@pytest.mark.parametrize("offset_m", [0.03, 0.09])
def test_a_wobbly_loop_off_the_origin_is_not_pulled_to_it(offset_m: float) -> None:
    """A wobbly arch drawn 3 or 9 cm off the plane's origin (an imported file's origin is the
    mean of its samples): too far (9 cm, 25 % of its size), or fitting the origin far worse
    than its own centre (3 cm), the centred fits do not decide, and θ/ρ stay right."""
    from bt_pipeline.data.shapes import canonical_shape

    t = np.linspace(0.0, 8.0, 800)
    rng = np.random.default_rng(5)
    wobble = sum(
        rng.uniform(0.002, 0.004)
        * np.sin(2 * np.pi * rng.uniform(0.1, 0.6) * t[:, None] + rng.uniform(0, 7, 2))
        for _ in range(3)
    )
    loop = similarity_transform(canonical_shape("pick_and_place", 2 * np.pi * t / 4.0), 15.0, 1.2)
    fit = fit_guide(loop + wobble + np.array([offset_m, -0.3 * offset_m]), "pick_and_place")
    assert abs(fit.rho - 1.2) < 0.05 and abs(fit.theta_deg - 15.0) < 5.0, fit


def test_drift_does_not_bias_the_estimate() -> None:
    """Three loops drifting 3 cm sideways: θ/ρ still within 5° and 0.05, the drift measured."""
    from bt_pipeline.data.shapes import canonical_shape

    t = np.linspace(0.0, 15.0, 750)
    uv = similarity_transform(canonical_shape("wiping", 2 * np.pi * t / 5.0), -20.0, 0.9)
    drifted = uv + (t / t[-1])[:, None] * np.array([0.03, 0.0])
    segment = segment_demo(drifted, t + 7.0, "wiping", "demo_0")
    assert abs(segment.guide.theta_deg + 20.0) < 5.0 and abs(segment.guide.rho - 0.9) < 0.05
    assert segment.drift_m > 0.015  # most of the 3 cm is seen as drift, not as an offset
    assert abs(segment.cycles - 3.0) < 0.2


def test_track_phase_counts_loops_both_ways() -> None:
    ring = canonical_loop("weaving", 400)
    phases = np.linspace(0, 2 * np.pi * 2.5, 500)
    from bt_pipeline.data.shapes import canonical_shape

    path = canonical_shape("weaving", phases)
    assert abs(abs(np.ptp(track_phase(path, ring))) / 400 - 2.5) < 0.02
    assert abs(abs(np.ptp(track_phase(path[::-1], ring))) / 400 - 2.5) < 0.02


def test_still_demo_is_a_clear_error() -> None:
    t = np.linspace(0.0, 3.0, 150)
    with pytest.raises(DemoError, match="demo_9"):
        segment_demo(np.zeros((150, 2)), t, "wiping", "demo_9")


def test_human_set_stores_its_truth_and_hides_preferences() -> None:
    synth = make_human_set("wiping", 4, seed=1, hidden=True)
    for demo in synth.demos:
        record = demo.record
        assert np.isnan(record.theta_deg) and np.isnan(record.rho)
        stored = truth_of(record)
        assert stored is not None
        truth, on_loop = stored
        assert truth.shape == (record.timestamps.size, 2) and on_loop.any() and not on_loop.all()
        steps = np.diff(record.timestamps)
        assert steps.min() > 0 and steps.max() / steps.min() > 1.5  # uneven sample times
        assert record.timestamps[0] > 0.0  # not based at 0


def test_pooling_follows_the_estimates_that_agree() -> None:
    """A demonstrator's five hidden demos: two fits agree on the truth, three misshapen ones
    scatter to larger ρ (a median would land among those); pooling takes the agreeing ones.
    Another demonstrator's single demo keeps its own fit."""
    from bt_pipeline.clean.guide_fit import GuideFit
    from bt_pipeline.clean.periodic import pool_preferences
    from bt_pipeline.clean.segment import Segment
    from bt_pipeline.data.demo import Demo

    def demo(name: str, who: str) -> Demo:
        positions = canonical_loop("wiping", 64)
        return Demo(positions, "wiping", "", name, who, None, None, default_plane("wiping"))

    def segment(theta: float, rho: float) -> Segment:
        fit = GuideFit(theta, rho, np.zeros(2), 0.001, 0.24 * rho, LoopShape.guide("wiping"))
        return Segment(0.0, 1.0, 1.0, fit)

    fits = [(10.0, 1.00), (10.5, 1.01), (12.0, 1.09), (8.0, 1.16), (14.0, 1.23), (-5.0, 0.8)]
    demos = [demo(f"demo_{k}", "ann" if k < 5 else "bob") for k in range(6)]
    estimates = pool_preferences(demos, [segment(*f) for f in fits])
    for estimate in estimates[:5]:
        assert 10.0 <= estimate.theta_deg <= 10.5 and 1.0 <= estimate.rho <= 1.01, estimate
        assert estimate.estimated
    assert (estimates[5].theta_deg, estimates[5].rho) == (-5.0, 0.8)


def test_pooling_weighs_each_fit_by_how_well_the_whole_loop_follows_it() -> None:
    """Two hidden demos of one demonstrator disagree. A lopsided demo's fit follows one side
    closely (small trimmed residual) but its bulged side lies far off (large 90th-percentile
    misfit); the other's fit is looser but holds the whole loop. Pooling takes the second
    (weighted by the trimmed residual, it took the first; with the misfit, pick-and-place sets of
    8 went from 77 to 83 % within 5 degrees and 0.05 on benchmarks/quality/bench_preferences.py)."""
    from bt_pipeline.clean.guide_fit import GuideFit
    from bt_pipeline.clean.periodic import pool_preferences, segment_all
    from bt_pipeline.clean.segment import Segment
    from bt_pipeline.data.demo import Demo, demos_from_recording

    def demo(name: str) -> Demo:
        positions = canonical_loop("pick_and_place", 64)
        return Demo(
            positions,
            "pick_and_place",
            "",
            name,
            "dee",
            None,
            None,
            default_plane("pick_and_place"),
        )

    def segment(theta: float, rho: float, residual: float, misfit: float) -> Segment:
        fit = GuideFit(
            theta, rho, np.zeros(2), residual, 0.30 * rho, LoopShape.guide("pick_and_place")
        )
        return Segment(0.0, 1.0, 1.0, fit, misfit_m=misfit)

    fits = [segment(0.0, 1.0, 0.0008, 0.002), segment(5.0, 1.1, 0.0005, 0.004)]
    for estimate in pool_preferences([demo("demo_0"), demo("demo_1")], fits):
        assert (estimate.theta_deg, estimate.rho) == (0.0, 1.0), estimate

    # The same on real segmentation: pick-and-place set 1 of 8, whose demonstrator teacher_d
    # drew one careful but jittery loop (demo 3) and one lopsided loop (demo 7).
    synth = make_human_set("pick_and_place", 8, seed=1, hidden=True)
    demos = demos_from_recording(synth.recording)
    estimates = pool_preferences(demos, segment_all(demos))
    for k in (3, 7):
        record = synth.demos[k].record
        assert abs(estimates[k].theta_deg - record.attrs["truth_theta_deg"]) < 5.0
        assert abs(estimates[k].rho - record.attrs["truth_rho"]) < 0.05


def test_expert_span_ends_are_not_biased_into_the_approach() -> None:
    """The median span end errors of expert-like demos (3 seeds x 3 tasks) are within 0.07 s.

    Without the 0.04 s edge trim the smoothed path put both ends about 0.1 s into the approach
    and the retreat (medians -0.10 s and +0.10 s on benchmarks/quality/bench_segment.py).
    """
    starts, ends = [], []
    for task in ("wiping", "weaving", "pick_and_place"):
        for seed in range(3):
            synth = make_human_set(task, 4, seed=seed)
            demo = synth.demos[synth.expert_index]
            uv = default_plane(task).to_plane(demo.record.ee_pos)
            segment = segment_demo(uv, demo.record.timestamps, task, demo.name)
            on_times = demo.record.timestamps[demo.on_loop]
            starts.append(segment.start_s - on_times[0])
            ends.append(segment.end_s - on_times[-1])
    assert abs(float(np.median(starts))) < 0.07, starts
    assert abs(float(np.median(ends))) < 0.07, ends


def test_a_loop_that_runs_to_the_recordings_end_keeps_its_last_sample() -> None:
    """A demo that is all loop (the single-loop style) keeps every raw sample, the last included.

    The analysis clock stops short of the last raw time, so the span used to end one sample
    early: the expert-like demo, passed through raw, then lost a sample of its loop (shape
    ratios up to 1.14 against its truth in benchmarks/quality/bench_clean_human.py --styles single).
    """
    t = np.sort(np.random.default_rng(0).uniform(0.0, 6.0, 400))
    phase = 2 * np.pi * t / 6.0
    uv = similarity_transform(canonical_loop("wiping", 4096), 0.0, 1.0)
    uv = np.stack(
        [np.interp(phase, np.linspace(0, 2 * np.pi, 4096), uv[:, d]) for d in range(2)], 1
    )
    segment = segment_demo(uv, t, "wiping", theta_deg=0.0, rho=1.0)
    assert segment.start_s == t[0]
    assert segment.end_s == t[-1]


def test_a_recording_cut_mid_loop_keeps_a_bulged_side_at_its_end() -> None:
    """A single-loop recording (no rest, no retreat) that ends on its bulged (lopsided) side keeps
    that side: with no rest at the end there is no retreat, and the part after the on-guide run
    travels on around the loop. It used to be cut (2.2 s of 2.9 s of loop), leaving the
    cleaned demo half a loop (shape ratio 0.49 against its truth, 0.02 now)."""
    synth = make_demo_set("weaving", 4, seed=0)
    record = next(iter(synth.recording.demos.values()))
    assert "lopsided" in record.ep_meta["synthetic"]["defects"]
    uv = default_plane("weaving").to_plane(record.ee_pos)
    segment = segment_demo(uv, record.timestamps, "weaving")
    assert segment.start_s == record.timestamps[0]
    assert segment.end_s == record.timestamps[-1]


def test_an_approach_beside_the_loop_does_not_loosen_the_on_loop_tolerance() -> None:
    """An expert-like demo whose approach runs 1-8 mm beside its loop for a second (wiping,
    seed 7): the tolerance is read from the middle of the on-loop samples, so the span starts
    where the loop does (0.17 s early), not in the approach (1.0 s early when the approach's
    distances set the tolerance to 10.9 mm)."""
    synth = make_human_set("wiping", 4, seed=7)
    demo = synth.demos[synth.expert_index]
    uv = default_plane("wiping").to_plane(demo.record.ee_pos)
    segment = segment_demo(uv, demo.record.timestamps, "wiping", demo.name)
    on_times = demo.record.timestamps[demo.on_loop]
    assert abs(segment.start_s - on_times[0]) < 0.3


def test_a_jittery_rest_is_not_taken_for_motion() -> None:
    """A jittery naive demo drawn slowly (wiping, seed 1, demo 0, every time x 2: 15-30 Hz,
    a 4 s rest): its rest's jitter passed 10 mm from the first sample, so the motion seemed to
    start at once and the span took in 6.8 s of rest and approach (timing ratio 3.34 in
    benchmarks/quality/bench_robustness.py). The rest pose is now the median of the first 0.2 s and
    "away" is at least 4 x the sample noise."""
    synth = make_human_set("wiping", 8, seed=1)
    demo = synth.demos[0]
    assert "jitter" in demo.defects
    uv = default_plane("wiping").to_plane(demo.record.ee_pos)
    times = 2.0 * demo.record.timestamps
    segment = segment_demo(uv, times, "wiping", theta_deg=demo.theta_deg, rho=demo.rho)
    assert segment.start_s - times[demo.on_loop][0] > -2.0


def test_theta_rho_are_fitted_over_the_wider_reading_of_the_loop() -> None:
    """θ/ρ come from the span the on-loop tolerance read over all on-loop samples finds (when it
    is longer than the kept span): a kept span cut short to part of a drifting loop fitted a
    wrong ρ (0.11 off) within 0.8 mm, outweighed its demonstrator's other four demos in the
    pooling and moved all five 0.105 off (wiping, 20 demos, seed 3, teacher_c)."""
    synth = make_human_set("wiping", 20, seed=3)
    assert synth.hidden
    pairs = [
        (demo, human)
        for demo, human in zip(demos_from_recording(synth.recording), synth.demos, strict=True)
        if demo.demonstrator == "teacher_c"  # Pooling is per demonstrator.
    ]
    demos = [demo for demo, _ in pairs]
    assert len(demos) == 5
    preferences = pool_preferences(demos, segment_all(demos))
    for (_, human), preference in zip(pairs, preferences, strict=True):
        assert abs(preference.rho - human.rho) < 0.05
        assert abs(preference.theta_deg - human.theta_deg) < 5.0


def test_confidence_is_how_much_agreeing_evidence_backs_the_estimate() -> None:
    """Three good fits agree and three misshapen demos' fits (large misfit) scatter: the pooled
    estimate is confident (it was the mean quality over all six, 0.49: uncertain). Two
    equally good fits that disagree: uncertain. One demo: its own quality."""
    from bt_pipeline.clean.guide_fit import GuideFit
    from bt_pipeline.clean.periodic import UNCERTAIN, pool_preferences
    from bt_pipeline.clean.segment import Segment
    from bt_pipeline.data.demo import Demo

    def demo(k: int, who: str) -> Demo:
        positions = canonical_loop("wiping", 64)
        return Demo(positions, "wiping", "", f"d{k}", who, None, None, default_plane("wiping"))

    def segment(theta: float, rho: float, misfit: float) -> Segment:
        return Segment(
            0.0,
            1.0,
            1.0,
            GuideFit(theta, rho, np.zeros(2), 1e-3, 0.24, LoopShape.guide("wiping")),
            0.0,
            misfit,
        )

    fits = [(0.0, 1.0, 0.001), (0.5, 1.01, 0.001), (-0.5, 0.99, 0.001)]
    fits += [(9.0, 1.2, 0.03), (-12.0, 0.8, 0.03), (20.0, 1.5, 0.03)]  # Misfit 6 x 2 % of size.
    fits += [(0.0, 1.0, 0.001), (10.0, 1.2, 0.001)]  # Two good fits that disagree.
    fits += [(3.0, 1.1, 0.0012)]  # One demo.
    who = ["ann"] * 6 + ["bob"] * 2 + ["cy"]
    demos = [demo(k, w) for k, w in enumerate(who)]
    estimates = pool_preferences(demos, [segment(*f) for f in fits])
    assert all(e.confidence > UNCERTAIN for e in estimates[:6])
    assert all(e.confidence < UNCERTAIN for e in estimates[6:8])
    quality = 1.0 / (1.0 + (0.0012 / (0.02 * 0.24)) ** 2)
    assert estimates[8].confidence == pytest.approx(quality)


@pytest.mark.parametrize(("task", "seed"), [("wiping", 2), ("wiping", 4), ("pick_and_place", 3)])
def test_a_wobbly_hand_is_not_read_as_a_smaller_loop(task, seed) -> None:
    """Sets of the independent operator generator, θ/ρ hidden: every estimate within 5° and
    0.05. Among about equally good fits the smallest ρ won always (a lopsided loop's bulge);
    a slow wobble of a few mm scatters those fits, and 2 of 5 estimates per set read ρ 2-9 %
    low. The smallest now wins only when more than 6 % below the median fit."""
    ops = operator_set(task, seed, hidden=True)
    demos = [o.demo for o in ops.demos]
    for op, p in zip(ops.demos, pool_preferences(demos, segment_all(demos)), strict=True):
        assert abs(p.theta_deg - op.theta_deg) < 5.0, (op.demo.name, p, op.theta_deg)
        assert abs(p.rho - op.rho) < 0.05, (op.demo.name, p, op.rho)


@pytest.mark.parametrize("seed", [3, 8])
def test_a_steady_fast_figure_eight_keeps_its_scale(seed) -> None:
    """The operator sets' steady weaving demo, θ/ρ hidden: ρ within 2 %. Refitted from the fit
    of the whole moving part (approach and retreat included, ρ 6-9 % low), with that part's
    drift, the span's fit stayed 5-6 % low (the code at the start of 2026-12-02 evening: both
    the span refit of step 6 and the consensus rule of guide_consensus each fix it on their own)."""
    ops = operator_set("weaving", seed, hidden=True)
    steady = ops.demos[ops.steady_index]
    x, t = steady.demo.raw_samples()
    fit = segment_demo(x, t, "weaving", steady.demo.name).guide
    assert abs(fit.rho / steady.rho - 1.0) < 0.02, (fit.rho, steady.rho)
    assert abs(fit.theta_deg - steady.theta_deg) < 2.0, (fit.theta_deg, steady.theta_deg)


def _track_by_definition(x: np.ndarray, ring: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """track_phase as its docstring defines it: each point's nearest loop point among the
    candidates within the reach of the previous phase (the first such minimum), from each
    start about as near to the first point (up to 3 local minima of its distance within
    max(the nearest distance, 5 % of the loop's extent)); the track nearest the points wins."""
    p = ring.shape[0]
    reach = max(1, int(0.05 * p))
    d = np.linalg.norm(ring - x[0], axis=1)
    slack = max(float(d.min()), 0.05 * float(np.max(np.ptp(ring, axis=0))))
    minima = [
        i
        for i in range(p)
        if d[i] <= d.min() + slack and d[i] <= d[i - 1] and d[i] < d[(i + 1) % p]
    ]
    starts = [int(np.argmin(d))]
    starts += sorted((i for i in minima if i != starts[0]), key=lambda i: d[i])[:2]
    tracks = []
    for start in starts:
        phase = [start]
        for k in range(1, x.shape[0]):
            wide = max(reach, min(int(reach * max(steps[k], 1.0)), p // 2))
            candidates = phase[-1] + np.arange(-wide, wide + 1)
            d2 = np.sum((ring[candidates % p] - x[k]) ** 2, axis=1)
            phase.append(int(candidates[int(np.argmin(d2))]))
        track = np.array(phase, dtype=np.float64)
        cost = float(np.mean(np.sum((ring[np.array(phase) % p] - x) ** 2, axis=1)))
        tracks.append((cost, len(tracks), track))
    return min(tracks, key=lambda c: c[:2])[2]


@pytest.mark.parametrize("task", ["wiping", "weaving", "pick_and_place"])
def test_the_phase_track_is_its_definition(task: Task) -> None:
    """The fast track (the loop laid out twice, one slice per window) gives the phases of the
    plain definition bit for bit: three noisy loops with a speed swing and gaps, run both ways
    round, and a loop of 37 points (windows round the seam)."""
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 1.0, 1500)
    phase = 2 * np.pi * (3 * t + 0.2 * np.sin(5 * t))
    steps = np.where(rng.random(t.size) < 0.02, rng.uniform(1, 30, t.size), 1.0)
    for n in (512, 37):
        ring = canonical_loop(task, n)
        for sign in (1.0, -1.0):
            x = canonical_loop(task, 4000)[(sign * phase / (2 * np.pi) * 4000).astype(int) % 4000]
            x = x + rng.normal(0.0, 0.004, x.shape)
            fast = track_phase(x, ring, steps=steps)
            assert np.array_equal(fast, _track_by_definition(x, ring, steps))
            if n == 512:
                assert abs(fast[-1] - fast[0]) > 2.5 * n  # it followed the loops


@pytest.mark.parametrize(
    ("task", "seed", "early_s"), [("pick_and_place", 8, 0.39), ("weaving", 11, 0.26)]
)
def test_an_approach_closing_in_on_the_loop_is_trimmed_on_a_dense_guide(
    task: Task, seed: int, early_s: float
) -> None:
    """Operator sets, θ/ρ given: the steady operator (0.3 mm of noise) approaches along the
    loop from a few mm. Measured to the vertices of a 512-point guide (2-3 mm apart) its
    samples read 0.4-1.2 mm farther off than they are, the end trim's threshold grew with them
    and the span started `early_s` before the loops (shape ratio 2.74 and 1.20); measured to
    a dense guide the span starts within 0.1 s of them."""
    ops = operator_set(task, seed)
    steady = ops.demos[ops.steady_index]
    uv, t = steady.demo.raw_samples()
    segment = segment_demo(
        uv, t, steady.demo.task, theta_deg=steady.demo.theta_deg, rho=steady.demo.rho
    )
    first = float(t[steady.on_loop][0])
    assert abs(segment.start_s - first) < 0.1 < early_s, (segment.start_s, first)


def test_a_retreat_running_on_along_the_loop_is_trimmed_on_a_dense_guide() -> None:
    """Human-style weaving, a set of 8, seed 1: the expert-like demo (0.3 mm of noise) ends its
    4 loops with a retreat that runs on along the loop 2-4 mm off for 0.7 s. Measured to the
    vertices of a 512-point guide its samples read a median 0.8 mm off, the end trim's
    threshold was 3.2 mm and the retreat stayed in the span (4.05 loops, shape ratio 1.18);
    measured to a dense guide the end is cut within 0.4 s of the true one (0.32 s after it
    with the trimmed fit's ρ, 0.3 % small; 0.06 s before it, 3.96 loops, since the refined
    fit reads ρ within 0.1 %: a kept retreat would count more than 4.02)."""
    synth = make_human_set("weaving", 8, 1)
    demo = demos_from_recording(synth.recording)[synth.expert_index]
    record = list(synth.recording.demos.values())[synth.expert_index]
    stored = truth_of(record)
    assert stored is not None
    _, on_loop = stored
    uv, t = demo.raw_samples()
    segment = segment_demo(uv, t, demo.task, theta_deg=demo.theta_deg, rho=demo.rho)
    assert abs(segment.end_s - t[on_loop][-1]) < 0.4, (segment.end_s, t[on_loop][-1])
    assert -0.05 <= segment.cycles - 4.0 <= 0.02


def test_the_end_trim_reads_the_drift_against_the_final_fit() -> None:
    """Operator sets, weaving seed 8, θ/ρ hidden: the steady operator's fitted ρ is 0.5 %
    small. With the drift estimated against the span's first fit, its last 0.6 s of loop lay
    2-3 mm off and the end trim cut them (1.71 of 2 loops kept, shape ratio 2.26); with the
    drift estimated against the final fit the span keeps both loops."""
    ops = operator_set("weaving", 8, hidden=True)
    steady = ops.demos[ops.steady_index]
    uv, t = steady.demo.raw_samples()
    segment = segment_demo(uv, t, steady.demo.task)
    assert abs(segment.end_s - float(t[steady.on_loop][-1])) < 0.1
    assert abs(segment.cycles - 2.0) <= 0.05


def test_a_steady_single_loop_s_span_stops_where_the_retreat_leaves_the_loop() -> None:
    """Human-style pick-and-place seed 11's expert-like demo: one loop at 0.3 mm of noise, whose
    retreat sets off along the loop and leaves it slowly. The raw-end trim ran only on spans of
    1.5 loops or more, so its span kept the retreat to 4.6 mm off the loop (shape ratio 1.17);
    a single loop whose middle follows its guide within 1 mm is trimmed too, to under 1.5 mm."""
    from scipy.spatial import KDTree

    synth = make_human_set("pick_and_place", 4, 11)
    k = synth.expert_index
    human = synth.demos[k]
    uv, t = demos_from_recording(synth.recording)[k].raw_samples()
    seg = segment_demo(uv, t, "pick_and_place", theta_deg=human.theta_deg, rho=human.rho)
    assert seg.cycles < 1.5
    kept = uv[(t >= seg.start_s) & (t <= seg.end_s)]
    loop = similarity_transform(canonical_loop("pick_and_place", 4000), human.theta_deg, human.rho)
    assert float(np.max(KDTree(loop).query(kept)[0])) < 0.0015


def test_a_loop_ending_with_the_recording_keeps_its_last_samples() -> None:
    """Single-loop weaving seed 33's expert-like demo: the recording ends with the hand still on
    the loop, and the on-loop run stopped one sample short (the analysis path's smoothing at the
    edge). One sample left after the span was too short to test as loop, so the span's end then
    moved in by the edge trim: 4 samples (0.08 s) of the loop lost, shape ratio 1.16."""
    from bt_pipeline.data.synth import make_demo_set

    single = make_demo_set("weaving", 4, 33)
    record = list(single.recording.demos.values())[single.expert_index]
    uv, t = demos_from_recording(single.recording)[single.expert_index].raw_samples()
    seg = segment_demo(uv, t, "weaving", theta_deg=record.theta_deg, rho=record.rho)
    assert seg.end_s == t[-1] and seg.start_s == t[0], (seg.start_s, seg.end_s, t[0], t[-1])
