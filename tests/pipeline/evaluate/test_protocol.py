"""The evaluation protocol and ``bt evaluate``: metrics, JSON, errors, plots, Rerun, rollouts."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest
from rerun.chunk import RrdReader

from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.cli import main
from bt_pipeline.data.demo import Demo, demos_from_recording, load_demos
from bt_pipeline.data.recording import read_recording, write_recording
from bt_pipeline.data.synth import make_d1
from bt_pipeline.data.tasks import TASKS
from bt_pipeline.evaluate.driver import pair_by_task, parse_learners
from bt_pipeline.evaluate.metrics import build_yardstick, initial_states, rollout_metrics
from bt_pipeline.evaluate.protocol import EvalConfig, evaluate_task
from bt_pipeline.exceptions import ConfigError
from tests.conftest import run

ROLLOUTS = 3
SAMPLES = 100
"""N of the demos in these tests (300 in real runs): rollouts and metrics cost ∝ N."""


def cleaned_quickly(demos: list[Demo], seed: int = 0) -> list[Demo]:
    """The demos through the cleaner with very few epochs (enough for plumbing tests)."""
    result = clean_demos(demos, CleanOptions(seed=seed, epochs=2, write_rrd=False, progress=False))
    return [d.with_positions(result.positions[i]) for i, d in enumerate(demos)]


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Noisy wiping and weaving D1 files, and a directory with their cleaned versions."""
    root = tmp_path_factory.mktemp("evaluate")
    paths = {}
    for task in ("wiping", "weaving"):
        paths[task] = write_recording(root / f"{task}.hdf5", make_d1(task, seed=1).recording)
    cleaned = root / "cleaned"
    args = ["clean", str(paths["wiping"]), str(paths["weaving"]), "--out", str(cleaned)]
    main([*args, "--epochs", "2", "--no-rrd", "--json"])
    paths["cleaned"] = cleaned
    return paths


@pytest.fixture(scope="module")
def evaluated(files: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> dict:
    """One ``bt evaluate --json --plots --rrd --rollouts-out`` run on both tasks, two learners."""
    out = tmp_path_factory.mktemp("evaluated")
    args = ["evaluate", "--noisy", str(files["wiping"]), str(files["weaving"])]
    args += ["--cleaned", str(files["cleaned"]), "--learners", "bc,node", "--quick"]
    args += ["--rollouts", str(ROLLOUTS), "--steps", "20", "--json", "--plots", str(out / "plots")]
    args += ["--rrd", str(out / "eval.rrd"), "--rollouts-out", str(out / "rollouts")]
    args += ["--samples", str(SAMPLES)]
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        main(args)
    return {"document": json.loads(stdout.getvalue()), "out": out}


def test_json_has_one_row_per_task_learner_dataset(evaluated) -> None:
    rows = evaluated["document"]["results"]
    assert len(rows) == 2 * 2 * 2
    keys = {"task", "learner", "dataset", "reward_mean", "reward_std", "shape_loss", "utility"}
    got = {(r["task"], r["learner"], r["dataset"]) for r in rows}
    assert got == {
        (t, lr, d)
        for t in ("wiping", "weaving")
        for lr in ("bc", "node")
        for d in ("noisy", "cleaned")
    }
    for row in rows:
        assert keys <= set(row)
        assert 0.0 <= row["reward_mean"] <= 1.0 and row["reward_std"] >= 0.0
        assert 0.0 <= row["reward_direct_mean"] <= 1.0
        assert row["shape_loss"] >= 0.0 and 0.0 <= row["utility"] <= 1.0
        assert row["rollouts"] == ROLLOUTS and row["finite"] is True


def test_json_prints_alone_on_stdout(files, capsys) -> None:
    cleaned = files["cleaned"] / "wiping.cleaned.hdf5"
    args = ["--noisy", str(files["wiping"]), "--cleaned", str(cleaned), "--learners", "bc"]
    args += ["--rollouts", "2", "--steps", "5", "--samples", str(SAMPLES), "--json"]
    code, out, err = run(capsys, "evaluate", *args)
    assert code == 0
    assert list(json.loads(out)) == ["results"]  # the whole of stdout is the document
    assert "\r" not in err  # stderr is not a terminal: no progress bar fills the log


def test_plots_are_written(evaluated) -> None:
    plots = evaluated["out"] / "plots"
    for name in ("wiping.rollouts.png", "weaving.rollouts.png", "rewards.png"):
        image = matplotlib.image.imread(plots / name)
        assert image.shape[0] > 300 and image.shape[1] > 500
        assert float(np.std(image[..., :3])) > 0.05  # not a blank canvas


def test_rrd_holds_rollouts_and_the_table(evaluated) -> None:
    paths = {
        str(chunk.entity_path)
        for chunk in RrdReader(evaluated["out"] / "eval.rrd").stream().to_chunks()
    }
    for task in ("wiping", "weaving"):
        assert f"/{task}/plane/cleaned/node/rollouts" in paths
        assert f"/{task}/plane/references" in paths
        assert f"/{task}/rewards/noisy" in paths
    assert "/summary" in paths


def test_rollouts_out_are_valid_replayable_recordings(evaluated, files) -> None:
    noisy = read_recording(files["wiping"])
    duration = np.mean([d.timestamps[-1] - d.timestamps[0] for d in noisy.demos.values()])
    recording = read_recording(evaluated["out"] / "rollouts" / "wiping.bc.cleaned.rollouts.hdf5")
    assert recording.task == "wiping"
    assert len(recording.demos) == ROLLOUTS
    for record in recording.demos.values():
        assert record.demonstrator == "bc-cleaned" and record.source == "import"
        assert record.ep_meta["rollout_of"]["learner"] == "bc"
        assert record.timestamps[-1] == pytest.approx(duration)
        uv = recording.plane.to_plane(record.ee_pos)  # on the noisy set's task plane
        np.testing.assert_allclose(recording.plane.to_world(uv), record.ee_pos, atol=1e-12)
    assert len(list((evaluated["out"] / "rollouts").glob("*.hdf5"))) == 2 * 2 * 2


def test_task_in_one_set_only_is_an_error(files, capsys) -> None:
    noisy = ["--noisy", str(files["wiping"]), str(files["weaving"])]
    cleaned = ["--cleaned", str(files["cleaned"] / "wiping.cleaned.hdf5")]
    code, out, err = run(capsys, "evaluate", *noisy, *cleaned, "--learners", "bc")
    assert code == 2 and out == ""
    assert err.strip().count("\n") == 0 and "weaving" in err


def test_unknown_learner_is_an_error(files, capsys) -> None:
    sets = ["--noisy", str(files["wiping"]), "--cleaned", str(files["cleaned"])]
    code, _, err = run(capsys, "evaluate", *sets, "--learners", "bc,gail")
    assert code == 2
    assert err.strip().count("\n") == 0 and "gail" in err and "traj_bc" in err


def test_bad_rrd_suffix_fails_before_training(files, capsys) -> None:
    sets = ["--noisy", str(files["wiping"]), "--cleaned", str(files["cleaned"])]
    code, _, err = run(capsys, "evaluate", *sets, "--rrd", "out.txt")
    assert code == 2 and ".rrd" in err


def test_parse_learners_and_pairing() -> None:
    assert parse_learners(" node, bc ") == ("node", "bc")
    for bad in ("", "bc,bc", "bc,dagger"):
        with pytest.raises(ConfigError):
            parse_learners(bad)
    wiping = demos_from_recording(make_d1("wiping", 0).recording)
    weaving = demos_from_recording(make_d1("weaving", 0).recording)
    with pytest.raises(ConfigError, match="wiping has noisy demos but no cleaned"):
        pair_by_task(wiping, weaving)
    with pytest.raises(ConfigError, match="weaving has cleaned demos but no noisy"):
        pair_by_task(wiping, [*wiping, *weaving])


@pytest.mark.parametrize(
    "kwargs", [{"learners": ()}, {"learners": ("bc", "bc")}, {"rollouts": 0}, {"seed": -1}]
)
def test_eval_config_rejects_bad_settings(kwargs) -> None:
    with pytest.raises(ConfigError):
        EvalConfig(**kwargs)


@pytest.fixture(scope="module")
def wiping_yardstick():
    synth = make_d1("wiping", 0)
    demos = demos_from_recording(synth.recording)
    loops = [d.truth for d in synth.demos]  # D1: one demo, one true loop per demonstrator
    return demos, build_yardstick(demos, true_loops=loops), loops


def test_true_loops_are_the_references_and_v_e_is_read_as_the_paper_does(wiping_yardstick) -> None:
    _, yardstick, loops = wiping_yardstick
    assert yardstick.truth and len(yardstick.references) == 4
    rollouts = np.stack([_resample(loop, 300) for loop in loops])
    metrics = rollout_metrics(rollouts, yardstick)
    np.testing.assert_array_equal(metrics.nearest, [0, 1, 2, 3])
    assert metrics.shape_distances.max() < 0.001 and metrics.coverage.min() == 1.0
    assert metrics.shape_losses.max() < 0.002
    # The headline is the paper's reading: V_E read directly ranks the loops by how close each
    # preference is to the best demonstrator's; the nearest-frame reading scores them alike.
    np.testing.assert_array_equal(metrics.rewards, metrics.rewards_direct)
    best = int(np.argmax(metrics.rewards_direct))
    assert np.all(np.delete(metrics.rewards_direct, best) < metrics.rewards_direct[best] - 0.1)
    assert np.ptp(metrics.rewards_nearest) < 0.1
    nearest = rollout_metrics(rollouts, yardstick, reward_frame="nearest")
    np.testing.assert_array_equal(nearest.rewards, metrics.rewards_nearest)


def test_without_truth_the_best_raw_demo_is_the_reference_not_stage1(wiping_yardstick) -> None:
    demos, _, _ = wiping_yardstick
    yardstick = build_yardstick(demos)
    assert not yardstick.truth and len(yardstick.references) == 1
    best = demos[yardstick.stage1.best_index].positions
    np.testing.assert_array_equal(yardstick.references[0], best)
    aligned = yardstick.stage1.aligned[yardstick.stage1.best_index]
    metrics = rollout_metrics(np.stack([best, aligned]), yardstick)
    assert metrics.shape_distances[0] == 0.0 < metrics.shape_distances[1]


def test_a_displaced_loop_scores_lower(wiping_yardstick) -> None:
    _, yardstick, loops = wiping_yardstick
    loop = _resample(loops[0], 300)
    shifted = np.stack([loop, loop + np.array([0.03, 0.0])])
    metrics = rollout_metrics(shifted, yardstick)
    assert metrics.rewards_nearest[1] < metrics.rewards_nearest[0] - 0.2
    assert metrics.shape_losses[1] > metrics.shape_losses[0] + 0.02
    assert metrics.coverage[1] < 0.5 < metrics.coverage[0]
    assert metrics.utilities[1] < metrics.utilities[0]


def test_coverage_exposes_a_rollout_that_stalls_on_the_ridge(wiping_yardstick) -> None:
    _, yardstick, _ = wiping_yardstick
    loop = yardstick.stage1.aligned[yardstick.stage1.best_index]
    peak = loop[int(np.argmax(yardstick.stage1.value_map(loop)))]
    stalled = np.repeat(peak[None, None], loop.shape[0], axis=1)
    metrics = rollout_metrics(np.stack([loop, stalled[0]]), yardstick)
    assert metrics.coverage[0] > 0.5 and metrics.coverage[1] < 0.2
    assert metrics.rewards[1] > metrics.rewards[0]  # Eq. 11 alone prefers standing still


def test_initial_states_perturb_raw_demo_states(wiping_yardstick) -> None:
    demos, _, _ = wiping_yardstick
    a, b = (initial_states(demos, 40, 0.005, seed=3) for _ in range(2))
    np.testing.assert_array_equal(a, b)
    states = np.concatenate([d.positions for d in demos])
    nearest = np.min(np.linalg.norm(a[:, None] - states[None], axis=2), axis=1)
    assert nearest.max() < 5 * 0.005 and nearest.mean() > 0.001
    firsts = initial_states(demos, 40, 0.0, seed=3, anywhere=False)
    starts = np.stack([d.positions[0] for d in demos])
    assert np.min(np.linalg.norm(firsts[:, None] - starts[None], axis=2), axis=1).max() == 0.0
    # anywhere: spread along the loops, not only at the demos' first samples
    assert np.min(np.linalg.norm(a[:, None] - starts[None], axis=2), axis=1).max() > 0.05


def _resample(loop: np.ndarray, n: int) -> np.ndarray:
    closed = np.vstack([loop, loop[:1]])
    s = np.linspace(0.0, 1.0, len(closed))
    t = np.linspace(0.0, 1.0, n)
    return np.stack([np.interp(t, s, closed[:, j]) for j in range(2)], axis=1)


@pytest.mark.parametrize("task", TASKS)
def test_every_learner_trains_finitely_and_rolls_out_bounded(task) -> None:
    noisy = demos_from_recording(make_d1(task, seed=2).recording, n_samples=SAMPLES)
    cleaned = cleaned_quickly(noisy, seed=2)
    config = EvalConfig(rollouts=4, quick=True, steps=15, seed=2)
    results = evaluate_task(noisy, cleaned, config)
    assert [(r.dataset, r.learner) for r in results] == [
        (d, lr) for d in ("noisy", "cleaned") for lr in config.learners
    ]
    points = np.concatenate([np.stack([d.positions for d in s]) for s in (noisy, cleaned)])
    low, high = points.reshape(-1, 2).min(axis=0), points.reshape(-1, 2).max(axis=0)
    margin = 0.26 * float(np.max(high - low))  # the learners' rollout box pads by 25 %
    for result in results:
        assert result.finite, f"{result.learner} on {result.dataset} {task} is not finite"
        assert np.isfinite(result.final_loss)
        assert np.all(result.rollouts >= low - margin) and np.all(result.rollouts <= high + margin)
        assert np.all((result.rewards >= 0.0) & (result.rewards <= 1.0))


def test_loading_the_cleaned_directory_pairs_by_task(files) -> None:
    noisy = load_demos([files["wiping"], files["weaving"]])
    pairs = pair_by_task(noisy, load_demos([files["cleaned"]]))
    assert list(pairs) == ["wiping", "weaving"]
    assert all(len(n) == len(c) == 4 for n, c in pairs.values())
