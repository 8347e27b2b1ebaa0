"""The conditioned protocol's crowds and jobs: the sweeps, the ablation, the held-out preference,
the per-demonstrator learner, their report tables and the rollout figures."""

from __future__ import annotations

import matplotlib.image
import numpy as np
import pytest

from bt_pipeline.data.shapes import canonical_loop
from bt_pipeline.evaluate.crowd_figures import plot_task_rollouts
from bt_pipeline.evaluate.crowd_jobs import CrowdRun, run_crowd, stage2_units
from bt_pipeline.evaluate.crowd_report import crowd_cells, crowd_section
from bt_pipeline.evaluate.crowd_sets import GATED_DATASETS, CrowdSettings, prepare_crowd
from bt_pipeline.evaluate.distance import chamfer_distance
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.execute import ExecutorConfig

SETTINGS = CrowdSettings(
    seeds=2,
    per_demonstrator=2,
    sweeps=("same_preference", "random_loop"),
    sweep_learners=("bc",),
    per_demonstrator_learners=("bc",),
)


@pytest.fixture(scope="module")
def tiny() -> CrowdRun:
    return run_crowd(
        SETTINGS,
        tasks=("weaving",),
        learners=("bc", "ileed"),
        quick=True,
        executor=ExecutorConfig("local", 1),
        steps=10,
        clean_epochs=2,
        progress=False,
    )


def test_every_crowd_trains_what_its_table_needs(tiny: CrowdRun) -> None:
    got = {(r.seed, r.crowd, r.learner, r.dataset, r.approach) for r in tiny.rows}
    want = set()
    for seed in (0, 1):
        for crowd in ("independent", "shared"):
            for dataset in ("noisy", "cleaned", "best_aligned", "truth_shape", "truth_timing"):
                want |= {(seed, crowd, lr, dataset, "conditioned") for lr in ("bc", "ileed")}
        for dataset in GATED_DATASETS:
            want |= {(seed, "shared", lr, dataset, "held_out") for lr in ("bc", "ileed")}
            want.add((seed, "shared", "bc", dataset, "per_demonstrator"))
            want |= {(seed, c, "bc", dataset, "conditioned") for c in SETTINGS.sweeps}
    assert got == want
    for row in tiny.rows:
        finite = np.isfinite(row.shape_by_demonstrator_mm)
        if row.approach == "held_out":  # rolled out for demonstrator (seed mod 4) only
            assert finite.tolist() == [d == row.seed % 4 for d in range(4)]
        else:
            assert finite.all()
        assert row.l4_mm > 0 and (row.examples is not None) == (row.seed == 0)


def test_the_ablation_and_the_random_loops_are_what_they_say(tiny: CrowdRun) -> None:
    by = {(p.crowd, p.seed): p for p in tiny.prepared}
    same = by["same_preference", 0]
    assert np.allclose(same.preferences, [0.0, 1.0], atol=1e-9)
    shared = by["shared", 0]
    assert np.ptp(shared.preferences[:, 0]) > 5.0  # the main crowd's demonstrators differ
    guide = canonical_loop("weaving", 600)
    for seed in (0, 1):
        loop = by["random_loop", seed].loops[0].loop
        assert 1e3 * chamfer_distance(loop, guide) > 10.0  # not the task's guide
    assert not np.allclose(by["random_loop", 0].loops[0].loop, by["random_loop", 1].loops[0].loop)


def test_the_report_has_the_held_out_and_sweep_tables(tiny: CrowdRun, tmp_path) -> None:
    cells = crowd_cells(tiny)
    text = "\n".join(crowd_section(tiny, cells))
    assert "| D1 | weaving | BC | held out |" in text
    assert "| D1 | weaving | BC | per demonstrator |" in text
    assert "| D1 | weaving | shared, all at θ = 0, ρ = 1 | BC |" in text
    assert "| D1 | weaving | shared, random loop | BC |" in text
    assert "![rollouts, weaving](rollouts.weaving.png)" in text
    assert text.count("the truth gate passes in") >= 2 + 2 + 2  # main, held-out, per-demo, sweeps
    path = plot_task_rollouts(tiny, "weaving", tmp_path / "rollouts.weaving.png")
    assert path is not None and matplotlib.image.imread(path).shape[0] > 300
    assert plot_task_rollouts(tiny, "wiping", tmp_path / "x.png") is None


def test_quick_units_and_bad_settings() -> None:
    lean = CrowdSettings(held_out=False, per_demonstrator_learners=(), sweeps=())
    assert len(stage2_units(lean, "shared", ["bc"])) == 5
    assert stage2_units(lean, "no_expert", ["bc"]) == []
    with pytest.raises(ConfigError, match="unknown crowd"):
        CrowdSettings(sweeps=("nobody",))  # type: ignore[arg-type]
    prepared = prepare_crowd((0, "D1", "wiping", "no_expert", CrowdSettings(), 2))
    assert prepared.positions["noisy"].shape[0] == 4


def test_the_report_says_why_from_its_own_numbers(tiny: CrowdRun) -> None:
    for p in tiny.prepared:
        assert np.all(p.coverage["truth_shape"] >= 0.99)  # the truth covers its own loop
        assert 0 <= p.best < 4
    shared = [p for p in tiny.prepared if p.crowd == "shared"]
    # Every naive demo of a shared crowd leaves the same part of its loop out.
    assert all(np.delete(p.coverage["noisy"], p.best).max() < 0.97 for p in shared)
    for row in tiny.rows:
        per = np.array(row.success_by_demonstrator)
        if row.approach == "conditioned":  # equal rollouts per demonstrator: the mean is the rate
            assert np.mean(per) == pytest.approx(row.success_at(10.0))
    text = "\n".join(crowd_section(tiny, crowd_cells(tiny)))
    assert "*Why, independent crowd.*" in text and "*Why, shared crowd.*" in text
