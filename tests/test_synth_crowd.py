"""Crowd sets whose naive demos share biases (bt_pipeline.data.synth_crowd, issue 36)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import KDTree

from bt_pipeline.cli import main
from bt_pipeline.data.random_loops import draw_set_loop
from bt_pipeline.data.recording import read_recording
from bt_pipeline.data.shapes import canonical_loop, similarity_transform
from bt_pipeline.data.synth import DEMONSTRATORS, SynthDemo, SynthSet, make_demo_set
from bt_pipeline.data.synth_crowd import CROWD_BIASES, make_crowd_set
from bt_pipeline.exceptions import ConfigError

BINS = 20


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
                assert {"corner_cut", "undershoot", "hesitation"} <= set(meta["biases"])
                assert {"jitter", "tremor"} & set(demo.defects) and "hesitation" in demo.defects
                assert error > 3e-3


@pytest.mark.parametrize("task", ["wiping", "weaving", "pick_and_place"])
def test_the_largest_deviations_fall_on_the_same_phases_only_in_a_crowd(task) -> None:
    crowd_corr, independent_corr = [], []
    for seed in range(3):
        crowd = make_crowd_set(task, 8, seed, experts=1)
        params = _meta(crowd.demos[0])["params"]
        naive = [d for d in crowd.demos if not d.is_expert]
        profiles = [_deviation_profile(crowd, d) for d in naive]
        centres = (np.arange(BINS) + 0.5) / BINS
        biased = _in_interval(
            centres, params["cut_start"] - 0.5 / BINS, params["cut_width"] + 1 / BINS
        )
        biased |= _in_interval(
            centres,
            params["undershoot_start"] - 0.5 / BINS,
            params["undershoot_width"] + 1 / BINS,
        )
        for profile in profiles:
            assert biased[int(np.argmax(profile))], (seed, np.argmax(profile), params)
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
    for seed in range(3):
        crowd = make_crowd_set(task, 12, seed, experts=1)
        params = _meta(crowd.demos[0])["params"]
        fine = 60
        pooled: list[list[np.ndarray]] = [[] for _ in range(fine)]
        single_norms = []
        for demo in crowd.demos:
            if demo.is_expert:
                continue
            uv, intended, loop = _own_frame(crowd, demo)
            u = _phase(intended, loop)
            # The middle half of the cut, where the chord is farthest from the loop.
            middle = _in_interval(
                u, params["cut_start"] + 0.25 * params["cut_width"], 0.5 * params["cut_width"]
            )
            single_norms.append(float(np.linalg.norm(np.mean(uv[middle] - intended[middle], 0))))
            for b, offset in zip((u * fine).astype(int), uv - intended, strict=True):
                pooled[b].append(offset)
        means = [np.mean(p, axis=0) if p else np.zeros(2) for p in pooled]
        centres = (np.arange(fine) + 0.5) / fine
        inside = _in_interval(
            centres, params["cut_start"] + 0.25 * params["cut_width"], 0.5 * params["cut_width"]
        )
        clear = ~_in_interval(centres, params["cut_start"] - 0.05, params["cut_width"] + 0.1)
        clear &= ~_in_interval(
            centres, params["undershoot_start"] - 0.05, params["undershoot_width"] + 0.1
        )
        cut_mean = float(np.mean([np.linalg.norm(means[b]) for b in np.flatnonzero(inside)]))
        clear_mean = float(np.mean([np.linalg.norm(means[b]) for b in np.flatnonzero(clear)]))
        assert cut_mean > 5e-3 and cut_mean > 0.6 * np.mean(single_norms), (seed, cut_mean)
        assert cut_mean > 3.0 * clear_mean, (seed, cut_mean, clear_mean)


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


def test_the_biases_are_named() -> None:
    assert CROWD_BIASES == ("corner_cut", "undershoot", "hesitation", "backwards")


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


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--experts", "2"], "--experts needs --crowd shared"),
        (["--crowd", "shared", "--style", "human"], "not supported with --style human"),
        (["--crowd", "shared", "--experts", "5"], "experts must be in 0..n_demos (4)"),
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
