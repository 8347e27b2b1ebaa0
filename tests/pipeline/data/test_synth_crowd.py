"""Crowd sets whose naive demos share biases (bt_pipeline.data.synth_crowd, issue 36)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import uniform_filter1d
from scipy.spatial import KDTree

from bt_pipeline.cli import main
from bt_pipeline.data.crowd_biases import CROWD_BIASES
from bt_pipeline.data.random_loops import LoopFamily, draw_set_loop
from bt_pipeline.data.recording import read_recording
from bt_pipeline.data.shapes import canonical_loop, similarity_transform
from bt_pipeline.data.synth import DEMONSTRATORS, SynthDemo, SynthSet, make_demo_set
from bt_pipeline.data.synth_crowd import make_crowd_set
from bt_pipeline.exceptions import ConfigError

BINS = 20
SPACED = ("cut", "undershoot", "bulge", "missing")  # the disjoint bias intervals' param prefixes


def _own_frame(synth_set: SynthSet, demo: SynthDemo) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The demo's samples, its intended path and its truth loop with θ/ρ undone, each (., 2)."""
    attrs = demo.record.attrs
    theta, rho = float(attrs["truth_theta_deg"]), float(attrs["truth_rho"])
    uv = synth_set.recording.plane.to_plane(demo.record.ee_pos)

    def own(points: np.ndarray) -> np.ndarray:
        return similarity_transform(points, -theta, 1.0 / rho)

    return own(uv), own(attrs["truth_uv"]), own(demo.truth)


def _phase(intended: np.ndarray, loop: np.ndarray) -> np.ndarray:
    """Phase of each intended sample as a fraction of the loop, from the nearest truth point."""
    return np.asarray(KDTree(loop).query(intended)[1]) / len(loop)


def _deviation_profile(synth_set: SynthSet, demo: SynthDemo) -> np.ndarray:
    """Mean distance [m] of the demo's samples to its truth loop per phase bin, shape (BINS,)."""
    uv, intended, loop = _own_frame(synth_set, demo)
    distance = KDTree(loop).query(uv)[0]
    bins = (_phase(intended, loop) * BINS).astype(int)
    counts = np.bincount(bins, minlength=BINS)  # an incomplete demo leaves bins empty: NaN
    with np.errstate(invalid="ignore"):
        return np.bincount(bins, weights=distance, minlength=BINS) / counts


def _mean_correlation(profiles: list[np.ndarray]) -> float:
    """Mean Pearson correlation over all pairs of profiles, each on the bins both cover."""
    pairs = []
    for i, a in enumerate(profiles):
        for b in profiles[i + 1 :]:
            both = np.isfinite(a) & np.isfinite(b)
            pairs.append(np.corrcoef(a[both], b[both])[0, 1])
    return float(np.mean(pairs))


def _in_interval(u: np.ndarray, start: float, width: float) -> np.ndarray:
    return ((u - start) % 1.0) < width


def _meta(demo: SynthDemo) -> dict:
    return demo.record.ep_meta["synthetic"]


def _signed_area(points: np.ndarray) -> float:
    x, y = points[:, 0], points[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _pen_phase(u: np.ndarray, params: dict) -> np.ndarray:
    """Where on the loop the hand is at truth phases `u`: a wrong lobe's skipped lobe maps
    linearly onto the kept one (the module doc); elsewhere the phase itself."""
    if params["lobe_start"] is None:
        return u
    start, width = params["lobe_start"], params["lobe_width"]
    x = (u - start) % 1.0
    return np.where(x < width, start + width + x * (1.0 - width) / width, u) % 1.0


def _progress(demo: SynthDemo, intended: np.ndarray, loop: np.ndarray) -> np.ndarray:
    """How far along its loop the demo's intended path is at each sample, from 0 (unwrapped)."""
    meta = _meta(demo)
    u = _phase(intended, loop) - meta["start_phase_rad"] / (2.0 * np.pi)
    f = np.unwrap(2.0 * np.pi * meta["direction"] * u) / (2.0 * np.pi)
    return f - np.round(f[0])


def _truth_at(loop: np.ndarray, phase: float) -> np.ndarray:
    """The truth loop (n, 2) at a phase (fraction of the loop), linearly interpolated."""
    x = (phase % 1.0) * len(loop)
    i = int(x)
    return (i + 1 - x) * loop[i % len(loop)] + (x - i) * loop[(i + 1) % len(loop)]


def _drift(synth_set: SynthSet, demo: SynthDemo) -> tuple[np.ndarray, np.ndarray]:
    """A naive demo's drift as measured: where its hand rests after stopping short minus the
    truth where it stopped (2,) [m], and the part of its drawn stretch done at each sample (T,).

    The drift is nil at the start (by construction; measured there it is only noise) and no other
    bias is within 1 % of the loop of the stop, so the resting offset is the drift (its mean over
    20-60 samples averages the noise out)."""
    uv, intended, loop = _own_frame(synth_set, demo)
    width = _meta(demo)["params"]["missing_width"]
    f = _progress(demo, intended, loop)
    resting = f >= 1.0 - width + 0.025  # the hand eases to its stop over ±2 % of the loop
    meta = _meta(demo)
    stop = meta["start_phase_rad"] / (2.0 * np.pi) + meta["direction"] * (1.0 - width)
    drift = np.mean(uv[resting], axis=0) - _truth_at(loop, stop)
    return drift, np.clip(f / (1.0 - width), 0.0, 1.0)


def _left_normals(loop: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Unit normals to the left of the truth loop's direction at points `index`, (n, 2)."""
    tangent = np.roll(loop, -1, axis=0)[index] - np.roll(loop, 1, axis=0)[index]
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    return np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)


def _arc_coverage(uv: np.ndarray, loop: np.ndarray, part: np.ndarray, bins: int = 100) -> float:
    """Fraction of the truth loop's `part` (bool over its points) the demo covers: of the arc-length
    bins (1 % of the loop's length) the part spans, those holding the nearest truth point of a
    demo sample (smoothed over 9 samples, so noise does not scatter it)."""
    segments = np.linalg.norm(np.diff(np.vstack([loop, loop[:1]]), axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(segments)[:-1]]) / segments.sum()
    nearest = np.asarray(KDTree(loop).query(uniform_filter1d(uv, 9, axis=0, mode="nearest"))[1])
    covered = np.zeros(bins, dtype=bool)
    covered[(arc[nearest] * bins).astype(int)] = True
    return float(np.mean(covered[np.unique((arc[part] * bins).astype(int))]))


def _random_loop_set(family: LoopFamily, seed: int, n_demos: int = 8) -> SynthSet:
    return make_crowd_set("stirring", n_demos, seed, shape=draw_set_loop(family, seed))


def test_same_seed_same_set_other_seed_other_set() -> None:
    a, b, c = (make_crowd_set("wiping", 6, seed) for seed in (3, 3, 4))
    for x, y in zip(a.demos, b.demos, strict=True):
        np.testing.assert_array_equal(x.record.ee_pos, y.record.ee_pos)
        assert x.record.ep_meta == y.record.ep_meta
    assert a.expert_index == b.expert_index
    assert _meta(a.demos[0])["params"] != _meta(c.demos[0])["params"]
    assert not np.array_equal(a.demos[1].record.ee_pos[:50], c.demos[1].record.ee_pos[:50])


@pytest.mark.parametrize("experts", [0, 1, 3])
def test_expert_count_and_experts_carry_no_bias(experts: int) -> None:
    for seed in range(3):
        synth_set = make_crowd_set("weaving", 8, seed, experts=experts)
        expert_ks = [k for k, d in enumerate(synth_set.demos) if d.is_expert]
        assert len(expert_ks) == experts
        assert synth_set.expert_index == (expert_ks[0] if expert_ks else -1)
        kwargs = synth_set.recording.env_args["env_kwargs"]
        assert (kwargs["crowd"], kwargs["experts"]) == ("shared", experts)
        for demo in synth_set.demos:
            meta = _meta(demo)
            assert meta["is_expert"] == demo.is_expert
            uv, intended, _ = _own_frame(synth_set, demo)
            error = float(np.mean(np.linalg.norm(uv - intended, axis=1)))
            if demo.is_expert:
                assert demo.defects == () and meta["biases"] == [] and meta["direction"] == 1
                assert error < 1e-3
            else:
                assert set(CROWD_BIASES) - {"backwards"} <= set(meta["biases"])  # weaving crosses
                assert {"jitter", "tremor"} & set(demo.defects) and "hesitation" in demo.defects
                assert error > 3e-3


@pytest.mark.parametrize("task", ["wiping", "weaving", "pick_and_place"])
def test_the_largest_deviations_fall_on_the_same_phases_only_in_a_crowd(task) -> None:
    crowd_corr, independent_corr = [], []
    for seed in range(3):
        crowd = make_crowd_set(task, 8, seed, experts=1)
        params = _meta(crowd.demos[0])["params"]
        # The drift grows along the direction of travel: compare the demos going the same way.
        naive = [d for d in crowd.demos if not d.is_expert and _meta(d)["direction"] == 1]
        profiles = [_deviation_profile(crowd, d) for d in naive]
        centres = (np.arange(BINS) + 0.5) / BINS
        biased = np.zeros(BINS, dtype=bool)
        for name in SPACED:  # where the hand is (a wrong lobe moves it) or where it should be
            for u in (centres, _pen_phase(centres, params)):
                biased |= _in_interval(
                    u, params[f"{name}_start"] - 0.5 / BINS, params[f"{name}_width"] + 1 / BINS
                )
        # ... or on the last tenth before the stop, where the drift is largest.
        biased |= _in_interval(centres, params["missing_start"] - 0.1, 0.1)
        for profile in profiles:
            assert biased[int(np.nanargmax(profile))], (seed, np.nanargmax(profile), params)
        crowd_corr.append(_mean_correlation(profiles))
        independent = make_demo_set(task, 8, seed)
        independent_corr.append(
            _mean_correlation(
                [_deviation_profile(independent, d) for d in independent.demos if not d.is_expert]
            )
        )
    assert min(crowd_corr) > 0.7, crowd_corr
    assert max(independent_corr) < 0.5, independent_corr
    assert np.mean(crowd_corr) > np.mean(independent_corr) + 0.5


@pytest.mark.parametrize("task", ["wiping", "pick_and_place"])
def test_the_pooled_naive_demos_keep_the_corner_cut(task) -> None:
    fine = 60
    centres = (np.arange(fine) + 0.5) / fine

    def cut_offset(offsets: list[np.ndarray], params: dict) -> np.ndarray:
        """The mean offset (2,) over the cut's middle half less that at its two ends (where the
        cut is nil), so the drift, linear in phase across the cut, drops out."""
        start, width = params["cut_start"], params["cut_width"]
        middle = np.flatnonzero(_in_interval(centres, start + 0.25 * width, 0.5 * width))
        ends = [int((start * fine) % fine), int(((start + width) * fine) % fine)]
        return np.mean([offsets[b] for b in middle], 0) - np.mean([offsets[b] for b in ends], 0)

    for seed in range(3):
        crowd = make_crowd_set(task, 12, seed, experts=1)
        params = _meta(crowd.demos[0])["params"]
        pooled: list[list[np.ndarray]] = [[] for _ in range(fine)]
        single_norms = []
        for demo in crowd.demos:
            if demo.is_expert:
                continue
            uv, intended, loop = _own_frame(crowd, demo)
            bins = (_phase(intended, loop) * fine).astype(int)
            offsets = [np.mean((uv - intended)[bins == b], axis=0) for b in range(fine)]
            single_norms.append(float(np.linalg.norm(cut_offset(offsets, params))))
            for b, offset in zip(bins, uv - intended, strict=True):
                pooled[b].append(offset)
        pooled_cut = cut_offset([np.mean(p, axis=0) for p in pooled], params)
        loop = _own_frame(crowd, crowd.demos[0])[2]
        start, width = params["cut_start"], params["cut_width"]
        chord_middle = 0.5 * (_truth_at(loop, start) + _truth_at(loop, start + width))
        inward = chord_middle - _truth_at(loop, start + 0.5 * width)  # toward the chord
        cut_norm = float(np.linalg.norm(pooled_cut))
        arc = loop[_in_interval(np.arange(len(loop)) / len(loop), start, width)]
        chord = _truth_at(loop, start + width) - _truth_at(loop, start)
        across = (arc - _truth_at(loop, start)) @ np.array([-chord[1], chord[0]])
        sag = float(np.max(np.abs(across))) / float(np.linalg.norm(chord))  # the corner's depth
        assert cut_norm > 0.5 * params["cut_blend"] * sag, (seed, cut_norm, sag)  # not pooled away
        assert cut_norm > 0.6 * np.mean(single_norms), (seed, cut_norm, single_norms)
        assert pooled_cut @ inward / (cut_norm * np.linalg.norm(inward)) > 0.8, (seed, pooled_cut)


def test_a_minority_draws_the_loop_backwards() -> None:
    for seed in range(4):
        crowd = make_crowd_set("wiping", 8, seed)
        areas = {
            d.name: _signed_area(crowd.recording.plane.to_plane(d.record.ee_pos))
            for d in crowd.demos
        }
        backwards = {d.name for d in crowd.demos if _meta(d)["direction"] == -1}
        assert 1 <= len(backwards) < len(crowd.demos) / 2
        teacher = _meta(crowd.demos[0])["params"]["backwards_teacher"]
        for demo in crowd.demos:
            reversed_ = demo.name in backwards
            assert reversed_ == ("backwards" in _meta(demo)["biases"])
            assert reversed_ == (demo.record.demonstrator == teacher and not demo.is_expert)
            assert (areas[demo.name] < 0) == reversed_  # wiping's loop is counter-clockwise
            assert (_signed_area(demo.record.attrs["truth_uv"]) < 0) == reversed_
            assert _signed_area(demo.truth) > 0  # the truth loop keeps its direction


def test_a_set_with_too_few_naive_demonstrators_has_nobody_backwards() -> None:
    crowd = make_crowd_set("wiping", 3, 0, experts=1)
    assert _meta(crowd.demos[0])["params"]["backwards_teacher"] is None
    assert all(_meta(d)["direction"] == 1 for d in crowd.demos)


def test_everyone_naive_pauses_at_the_same_place() -> None:
    crowd = make_crowd_set("wiping", 8, 5, experts=1)
    params = _meta(crowd.demos[0])["params"]
    for demo in crowd.demos:
        _, intended, loop = _own_frame(crowd, demo)
        t = demo.record.timestamps
        speed = np.linalg.norm(np.diff(intended, axis=0), axis=1) / np.diff(t)
        slow = speed < 0.5 * np.median(speed)  # the flat-topped slow-down lasts ~pause_s here
        if demo.is_expert:
            assert not slow.any()
            continue
        held_s = float(np.sum(np.diff(t)[slow]))
        pause_s = _meta(demo)["demo_params"]["pause_s"]
        assert 0.7 * pause_s < held_s < 1.3 * pause_s, (demo.name, held_s, pause_s)
        where = float(_phase(intended[1 + np.argmin(speed)][None], loop)[0])
        gap = (where - params["pause_phase"] + 0.5) % 1.0 - 0.5
        assert abs(gap) < 0.02, (demo.name, where, params["pause_phase"])


@pytest.mark.parametrize("task", ["wiping", "weaving"])
def test_truth_attrs_are_the_intended_loop_in_the_demonstrators_frame(task) -> None:
    crowd = make_crowd_set(task, 5, 2, experts=2)
    dense = canonical_loop(task, 20_000)
    for k, demo in enumerate(crowd.demos):
        attrs, teacher = demo.record.attrs, DEMONSTRATORS[k % 4]
        n = demo.record.timestamps.size
        assert attrs["truth_uv"].shape == (n, 2) and attrs["truth_uv"].dtype == np.float32
        assert attrs["truth_on_loop"].shape == (n,) and attrs["truth_on_loop"].dtype == np.uint8
        assert np.all(attrs["truth_on_loop"] == 1) and attrs["truth_cycles"] == 1.0
        assert (attrs["truth_theta_deg"], attrs["truth_rho"]) == (teacher.theta_deg, teacher.rho)
        assert demo.truth.shape == (600, 2)
        np.testing.assert_allclose(
            demo.truth,
            similarity_transform(canonical_loop(task, 600), teacher.theta_deg, teacher.rho),
        )
        _, intended, _ = _own_frame(crowd, demo)
        assert KDTree(dense).query(intended)[0].max() < 1e-4  # on the loop, biases left out
        assert demo.record.timestamps[-1] >= 5.0


def test_a_given_shape_is_drawn_and_recorded() -> None:
    shape = draw_set_loop("oval", 1)
    crowd = make_crowd_set("stirring", 4, 1, experts=1, shape=shape)
    kwargs = crowd.recording.env_args["env_kwargs"]
    assert kwargs["shape"] == shape.label and kwargs["task"] == "stirring"
    expert = crowd.demos[crowd.expert_index]
    np.testing.assert_allclose(
        expert.truth,
        similarity_transform(shape.points(600), expert.record.theta_deg, expert.record.rho),
    )


@pytest.mark.parametrize("experts", [-1, 5, True, 1.5])
def test_bad_experts_is_a_config_error(experts) -> None:
    with pytest.raises(ConfigError, match="experts must be"):
        make_crowd_set("wiping", 4, 0, experts=experts)


def _crowd(family: LoopFamily | None, seed: int, task: str = "wiping") -> SynthSet:
    """A crowd set of 8 on the task's guide (None) or on a random loop of `family`."""
    return make_crowd_set(task, 8, seed) if family is None else _random_loop_set(family, seed)


def _clear_of_biases(u: np.ndarray, params: dict, margin: float = 0.02) -> np.ndarray:
    """Which truth phases `u` are `margin` or more clear of every bias interval."""
    clear = np.ones(u.shape, dtype=bool)
    for name in SPACED:
        start, width = params[f"{name}_start"], params[f"{name}_width"]
        clear &= ~_in_interval(u, start - margin, width + 2.0 * margin)
    return clear


@pytest.mark.parametrize("family", [None, "oval", "asymmetric"])
def test_every_naive_demo_bulges_out_on_the_same_side_by_the_drawn_amount(family) -> None:
    for seed in range(3):
        crowd = _crowd(family, seed)
        params = _meta(crowd.demos[0])["params"]
        start, width, amount_m = params["bulge_start"], params["bulge_width"], params["bulge_m"]
        sides = set()
        for demo in crowd.demos:
            uv, intended, loop = _own_frame(crowd, demo)
            index = np.asarray(KDTree(loop).query(intended)[1])
            u = index / len(loop)
            drift, done = (np.zeros(2), np.zeros(len(u))) if demo.is_expert else _drift(crowd, demo)
            # The offset along the truth's left normal, the demo's drift taken out.
            offset = uv - intended - done[:, None] * drift
            normal_offset = np.sum(offset * _left_normals(loop, index), axis=1)
            x = ((u - start) % 1.0) / width
            taper = np.where(x < 1.0, np.sin(np.pi * x) ** 2, 0.0)
            amount = float(normal_offset @ taper / (taper @ taper))  # least squares on sin²
            if demo.is_expert:
                assert abs(amount) < 0.05 * amount_m, (seed, amount)
                continue
            assert 0.6 < abs(amount) / amount_m < 1.4, (seed, demo.name, amount, amount_m)
            sides.add(int(np.sign(amount)))
            clear = _clear_of_biases(u, params)
            assert abs(np.mean(normal_offset[clear])) < 0.25 * amount_m, (seed, demo.name)
        # One side for all, and outward: the left normal points out of a clockwise loop.
        clockwise = _signed_area(crowd.demos[0].truth) < 0
        assert sides == {params["bulge_side"]} == {1 if clockwise else -1}, seed


@pytest.mark.parametrize("family", [None, "oval", "rounded_polygon"])
def test_every_naive_demo_drifts_the_same_way(family) -> None:
    for seed in range(3):
        crowd = _crowd(family, seed)
        params = _meta(crowd.demos[0])["params"]
        angle = np.radians(params["drift_angle_deg"])
        direction = np.array([np.cos(angle), np.sin(angle)])
        drifts, starts = [], []
        for demo in crowd.demos:
            uv, intended, _ = _own_frame(crowd, demo)
            if demo.is_expert:
                assert np.linalg.norm(np.mean(uv[-25:] - intended[-25:], axis=0)) < 1e-3
                continue
            drift, done = _drift(crowd, demo)
            drifts.append(drift)
            starts.append(np.mean((uv - intended)[done < 0.03], axis=0))
        drifts_m = np.linalg.norm(drifts, axis=1)
        cosines = np.asarray(drifts) @ direction / drifts_m
        assert cosines.min() > 0.9, (seed, cosines)
        mean = np.mean(drifts, axis=0)
        assert (np.asarray(drifts) @ mean / (drifts_m * np.linalg.norm(mean))).min() > 0.9
        ratios = drifts_m / params["drift_m"]
        assert ratios.min() > 0.5 and ratios.max() < 1.6, (seed, ratios)
        # It grows from nothing: the naive demos start on the truth (their noise averaged).
        assert np.linalg.norm(np.mean(starts, axis=0)) < 0.4 * params["drift_m"], seed


@pytest.mark.parametrize("family", [None, "figure_eight"])
def test_naive_demos_turn_back_into_the_lobe_they_came_from(family) -> None:
    for seed in range(3):
        crowd = _crowd(family, seed, task="weaving")
        params = _meta(crowd.demos[0])["params"]
        start, width = params["lobe_start"], params["lobe_width"]
        assert start is not None and 0.2 <= width <= 0.8, params
        for demo in crowd.demos:
            uv, intended, loop = _own_frame(crowd, demo)
            size = float(np.max(np.ptp(loop, axis=0)))
            # Both passes of the crossing are one point of the truth loop.
            assert np.linalg.norm(_truth_at(loop, start) - _truth_at(loop, start + width)) < (
                1e-3 * size
            )
            # Just past the crossing, where the truth enters the skipped lobe (either pass) ...
            u = _phase(intended, loop)
            past = _in_interval(u, start + 0.06, 0.08) | _in_interval(u, start + width - 0.14, 0.08)
            off_branch = float(np.median(np.linalg.norm(uv - intended, axis=1)[past])) / size
            # ... and how near the demo comes to the middle of the skipped lobe.
            lobe = _in_interval(np.arange(len(loop)) / len(loop), start + 0.2 * width, 0.6 * width)
            reach = KDTree(uv).query(loop[lobe])[0] / size
            if demo.is_expert:
                assert off_branch < 0.02 and reach.max() < 0.03, (seed, off_branch, reach.max())
            else:
                assert "wrong_lobe" in _meta(demo)["biases"]
                assert off_branch > 0.2 and reach.min() > 0.06, (seed, demo.name, off_branch)


@pytest.mark.parametrize("family", [None, "oval", "asymmetric"])
def test_a_loop_without_a_crossing_has_no_wrong_lobe(family) -> None:
    crowd = _crowd(family, 1)
    params = _meta(crowd.demos[0])["params"]
    assert params["lobe_start"] is None and params["lobe_width"] is None
    assert not any("wrong_lobe" in _meta(d)["biases"] for d in crowd.demos)
    assert all("missing_part" in _meta(d)["biases"] for d in crowd.demos if not d.is_expert)


@pytest.mark.parametrize("family", [None, "oval", "asymmetric"])
def test_every_naive_demo_leaves_out_the_same_part(family) -> None:
    for seed in range(3):
        crowd = _crowd(family, seed)
        params = _meta(crowd.demos[0])["params"]
        start, width = params["missing_start"], params["missing_width"]
        u = np.arange(600) / 600
        inner = _in_interval(u, start + 0.02, width - 0.04)  # clear of the ±1 % per-demo edges
        elsewhere = ~_in_interval(u, start - 0.03, width + 0.06)
        # A corner cut skips its corner's tip too.
        elsewhere &= ~_in_interval(u, params["cut_start"] - 0.02, params["cut_width"] + 0.04)
        for demo in crowd.demos:
            uv, _, loop = _own_frame(crowd, demo)
            if demo.is_expert:
                assert _arc_coverage(uv, loop, inner) == 1.0
                assert _arc_coverage(uv, loop, elsewhere) == 1.0
                continue
            drift, done = _drift(crowd, demo)  # taken out first, as an alignment would
            drawn = uv - done[:, None] * drift
            assert _arc_coverage(drawn, loop, inner) < 0.35, (seed, demo.name)
            assert _arc_coverage(drawn, loop, elsewhere) > 0.8, (seed, demo.name)


def test_same_preference_has_everyone_draw_at_theta_0_rho_1() -> None:
    same = make_crowd_set("weaving", 8, 4, same_preference=True)
    default = make_crowd_set("weaving", 8, 4)
    assert same.recording.env_args["env_kwargs"]["same_preference"] is True
    assert "same_preference" not in default.recording.env_args["env_kwargs"]
    assert len({(d.record.theta_deg, d.record.rho) for d in default.demos}) == 4
    for demo, other in zip(same.demos, default.demos, strict=True):
        record = demo.record
        assert (record.theta_deg, record.rho) == (0.0, 1.0)
        assert (record.attrs["truth_theta_deg"], record.attrs["truth_rho"]) == (0.0, 1.0)
        assert record.demonstrator == other.record.demonstrator
        # One loop for everyone (up to phase; here all start at phase 0): the guide as drawn.
        distance = KDTree(same.demos[0].truth).query(demo.truth)[0]
        assert distance.max() < 1e-9
        np.testing.assert_allclose(demo.truth, canonical_loop("weaving", 600))
        # Otherwise the same demos: the intended paths are the default set's with θ/ρ undone.
        _, intended, _ = _own_frame(default, other)
        np.testing.assert_allclose(record.attrs["truth_uv"], intended, atol=1e-6)
        assert record.ep_meta == other.record.ep_meta


def test_a_random_loop_set_is_reproducible() -> None:
    a, b, c = (_random_loop_set("figure_eight", seed) for seed in (2, 2, 3))
    for x, y in zip(a.demos, b.demos, strict=True):
        np.testing.assert_array_equal(x.record.ee_pos, y.record.ee_pos)
        assert x.record.ep_meta == y.record.ep_meta
    assert _meta(a.demos[0])["params"] != _meta(c.demos[0])["params"]


def test_the_biases_are_named() -> None:
    assert CROWD_BIASES == (
        "corner_cut",
        "undershoot",
        "hesitation",
        "backwards",
        "bulge",
        "drift",
        "wrong_lobe",
        "missing_part",
    )


def test_the_cli_writes_a_crowd_set(tmp_path, capsys) -> None:
    path = tmp_path / "crowd.hdf5"
    args = ["synth", "--crowd", "shared", "--experts", "0", "--seed", "2", "--out", str(path)]
    main(args)
    assert capsys.readouterr().out.strip() == str(path)
    recording = read_recording(path)
    kwargs = recording.env_args["env_kwargs"]
    assert (kwargs["crowd"], kwargs["experts"], kwargs["n_demos"]) == ("shared", 0, 4)
    same = make_crowd_set("wiping", 4, 2, experts=0)
    assert same.expert_index == -1
    for demo in same.demos:
        stored = recording.demos[demo.name]
        assert (
            stored.ep_meta == demo.record.ep_meta and not stored.ep_meta["synthetic"]["is_expert"]
        )
        np.testing.assert_allclose(stored.ee_pos, demo.record.ee_pos)


def test_the_cli_writes_a_same_preference_set(tmp_path) -> None:
    path = tmp_path / "same.hdf5"
    main(["synth", "--crowd", "shared", "--same-preference", "--demos", "5", "--out", str(path)])
    recording = read_recording(path)
    assert recording.env_args["env_kwargs"]["same_preference"] is True
    same = make_crowd_set("wiping", 5, 0, same_preference=True)
    for demo in same.demos:
        stored = recording.demos[demo.name]
        assert (stored.theta_deg, stored.rho) == (0.0, 1.0)
        np.testing.assert_allclose(stored.ee_pos, demo.record.ee_pos)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--experts", "2"], "--experts needs --crowd shared"),
        (["--crowd", "shared", "--style", "human"], "not supported with --style human"),
        (["--crowd", "shared", "--experts", "5"], "experts must be in 0..n_demos (4)"),
        (["--same-preference"], "--same-preference needs --crowd shared"),
    ],
)
def test_the_cli_refuses_bad_crowd_options(tmp_path, capsys, args, message) -> None:
    path = tmp_path / "x.hdf5"
    with pytest.raises(SystemExit) as exit_:
        main(["synth", *args, "--out", str(path)])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not path.exists()


def test_a_set_without_experts_has_no_expert_name() -> None:
    crowd = make_crowd_set("weaving", 4, 1, experts=0)
    assert crowd.expert_index == -1 and not any(d.is_expert for d in crowd.demos)
    with pytest.raises(ConfigError, match="no expert-like demo"):
        _ = crowd.expert_name
