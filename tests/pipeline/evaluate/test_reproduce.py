"""``bt reproduce``: the pipeline on synthetic sets, its report, and its command line."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest
import scipy.stats

from bt_pipeline.cli import main
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.synth import make_d1
from bt_pipeline.data.tasks import TASKS
from bt_pipeline.evaluate.crowd_sets import GATED_DATASETS, CrowdSettings
from bt_pipeline.evaluate.protocol import evaluate_demos
from bt_pipeline.evaluate.reproduce import reproduce
from bt_pipeline.evaluate.reproduce_jobs import (
    PAPER_ILEED_D1_GAIN,
    ReproduceConfig,
    job_cost,
    prepare_set,
    run_reproduce,
    truth_demos,
)
from bt_pipeline.evaluate.reproduce_report import (
    Cell,
    results_json,
    verdict,
    verdict_cell,
    verdict_test,
)
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.execute import ExecutorConfig

TINY = ReproduceConfig(
    tasks=("wiping",),
    sets=("D1",),
    learners=("bc", "ileed"),
    rollouts=3,
    steps=10,
    clean_epochs=2,
    seeds=2,
    oracle=True,
)
"""The code path of ``bt reproduce`` with almost no training (plumbing, report format)."""


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("reproduce")
    crowd = CrowdSettings(seeds=2, per_demonstrator=2, sweeps=("no_expert",))
    reproduce(TINY, out, progress=False, conditioned=crowd)
    return out


OUTPUTS = {"rewards.png", "D1.wiping.rollouts.png", "results.json", "report.md", "success_tau.png"}
OUTPUTS |= {"rollouts.wiping.png"}


def test_tiny_run_writes_every_output(tiny_run) -> None:
    assert {p.name for p in tiny_run.iterdir()} == OUTPUTS
    for png in ("rewards.png", "D1.wiping.rollouts.png", "success_tau.png", "rollouts.wiping.png"):
        assert matplotlib.image.imread(tiny_run / png).shape[0] > 300


def test_the_report_leads_with_the_conditioned_protocol(tiny_run) -> None:
    report = (tiny_run / "report.md").read_text()
    conditioned = report.index("## Does cleaning help a learner that keeps each demonstrator")
    assert conditioned < report.index("## The paper's protocol") < report.index("## Cleaning")
    # One row per (crowd, learner), each with a gate over its two seeds.
    for crowd in ("independent", "shared"):
        for learner in ("BC", "ILEED"):
            assert f"| D1 | wiping | {crowd} | {learner} |" in report
    assert "the truth gate passes in" in report and "![success against τ]" in report
    document = json.loads((tiny_run / "results.json").read_text())["conditioned"]
    keys = {
        (r["seed"], r["crowd"], r["learner"], r["dataset"], r["approach"]) for r in document["rows"]
    }
    datasets = ("noisy", "cleaned", "best_aligned", "truth_shape", "truth_timing")
    main = {
        (s, c, lr, d, "conditioned")
        for s in (0, 1)
        for c in ("independent", "shared")
        for lr in ("bc", "ileed")
        for d in datasets
    }
    extra = {
        (s, "shared", lr, d, "held_out")
        for s in (0, 1)
        for lr in ("bc", "ileed")
        for d in GATED_DATASETS
    }
    extra |= {(s, "shared", "bc", d, "per_demonstrator") for s in (0, 1) for d in GATED_DATASETS}
    extra |= {
        (s, "no_expert", lr, d, "conditioned")
        for s in (0, 1)
        for lr in ("bc", "ileed")
        for d in GATED_DATASETS
    }
    assert keys == main | extra
    assert all(0.0 <= r["success"]["10.0"] <= 1.0 and r["shape_mm"] > 0 for r in document["rows"])
    assert len(document["cells"]) == 4 + 2 + 1 + 2
    assert all(c["verdict_success"] for c in document["cells"])
    assert "### A preference never seen" in report and "### Sweeps" in report
    for job in document["cleaning_mm"]:
        assert job["noisy"] > 0.0 and job["cleaned"] > 0.0


def test_results_json_has_every_row_of_every_seed(tiny_run) -> None:
    document = json.loads((tiny_run / "results.json").read_text())
    rows = document["results"]
    assert len(rows) == 2 * 2 * 3  # seeds × learners × datasets (noisy, cleaned, truth)
    datasets = ("noisy", "cleaned", "truth")
    assert {(r["seed"], r["learner"], r["dataset"]) for r in rows} == {
        (s, lr, d) for s in (0, 1) for lr in ("bc", "ileed") for d in datasets
    }
    for row in rows:
        assert row["set"] == "D1" and row["task"] == "wiping" and row["finite"]
        assert 0.0 <= row["reward_mean"] <= 1.0
    for job in document["cleaning"]:
        assert job["truth_distance_raw"] > 0.0 and job["truth_distance_cleaned"] > 0.0


def test_report_has_tables_the_paper_side_by_side_and_a_verdict(tiny_run) -> None:
    report = (tiny_run / "report.md").read_text()
    assert "## Cleaning quality" in report
    assert "| wiping | ileed |" in report and "| wiping | bc |" in report
    assert "(± " in report  # the spread over seeds, since seeds = 2
    assert f"| wiping | {PAPER_ILEED_D1_GAIN['wiping']:+.3f} |" in report
    assert "## Where cleaned beats noisy, and where it does not" in report
    assert "Of 2 (set, task, learner) cells" in report
    # the reasons, with this run's numbers (the tiny learners win no cell)
    assert "**Why cleaned does not win in 2 of 2 cells**" in report
    assert "*The bound of cleaning.* In 2 of these 2 cells" in report
    assert "mm from the mean-preference loop" in report
    assert "*Every learner stays below the best demonstrator.*" in report
    assert "R̄ truth" in report and "with the truth" in report
    # Two seeds: paired over them, behind the truth gate (which two seeds can hardly pass).
    assert "*How the verdicts are made.* The samples are the seeds" in report
    assert "the gate needs t > 63.7" in report  # t_{0.995, 1}: the protocol says it cannot tell
    assert "cannot tell: truth" in report or "paired t, 2 seeds" in report
    assert "Welch" not in report
    assert "## Oracle rows" in report and "mean-preference loop" in report
    assert "Four demonstrators, conditioned" in report
    assert "own loop, worst demonstrator [mm]" in report
    assert "| wiping | +0.880 |" in report and "min-max" in report
    assert "![Fig. 11-style rewards](rewards.png)" in report


def test_results_json_has_the_oracle_rows(tiny_run) -> None:
    document = json.loads((tiny_run / "results.json").read_text())
    rows = document["competence"]
    checks = ("one", "four", "four_conditioned")
    assert {(r["check"], r["learner"]) for r in rows} == {
        (c, lr) for c in checks for lr in ("bc", "ileed")
    }
    for row in rows:
        assert 0.0 <= row["coverage"] <= 1.0 and row["shape_error"] > 0.0
        # the mean over rollouts is a weighted mean of the per-demonstrator means
        assert row["worst_own_error"] >= row["shape_error"] - 1e-12
    for row in rows:
        if row["check"] == "four_conditioned":
            assert row["passed"] == (row["worst_own_error"] <= 0.002)
    verdicts = document["verdicts"]
    assert [(v["set"], v["task"], v["learner"]) for v in verdicts] == [
        ("D1", "wiping", "bc"),
        ("D1", "wiping", "ileed"),
    ]
    for v in verdicts:  # two seeds and truth rows: a paired test and a truth gate each
        assert v["seeds"] == 2 and v["gate_passed"] is not None and v["p_t"] is not None
        assert v["verdict"] in ("cleaned", "noisy", "tie", "cannot tell")


def _rows(run) -> list[dict]:
    """results.json rows without their timings (wall times differ from run to run)."""
    rows = results_json(run)["results"]
    assert isinstance(rows, list)
    return [{k: v for k, v in row.items() if k != "train_seconds"} for row in rows]


def test_results_do_not_depend_on_the_job_split_or_their_order() -> None:
    """Stage-2 jobs (one per dataset × learner, run longest first: the Neural ODE's before BC's)
    give the same rows, bit for bit, as one whole-task ``evaluate_demos`` call (the learners in
    the config's order, BC first). The process pool runs the same jobs
    (tests/pipeline/test_execute.py)."""
    config = ReproduceConfig(
        tasks=("wiping",), sets=("D1",), learners=("bc", "node"), rollouts=3, steps=6,
        clean_epochs=2, oracle=True, competence=False,
    )  # fmt: skip
    split = run_reproduce(config, progress=False, executor=ExecutorConfig("local"))
    prepared = prepare_set((0, "D1", "wiping", config))
    noisy = demos_from_recording(make_d1("wiping", 0).recording)
    cleaned, truth = (
        [d.with_positions(p) for d, p in zip(noisy, prepared.data[name][0], strict=True)]
        for name in ("cleaned", "truth")
    )
    loops = {d.demonstrator: t for d, t in zip(noisy, make_d1("wiping", 0).demos, strict=True)}
    whole = evaluate_demos(
        noisy, cleaned, config.eval_config(0), truth=truth,
        true_loops=[t.truth for t in loops.values()],
    )  # fmt: skip
    expected = [
        {"set": "D1", "seed": 0, **r.to_json(), "reward_ceiling": whole.yardstick.ceiling}
        for r in whole.results
    ]
    for row in expected:
        del row["train_seconds"]
    assert len(expected) == 2 * 3
    assert job_cost("node", config) > job_cost("bc", config)  # NODE's jobs ran first
    assert _rows(split) == expected


def _cell(seed_means: tuple[float, ...], spread: float = 0.01, per_seed: int = 50) -> Cell:
    """A cell whose seed s has `per_seed` rollouts of mean exactly ``seed_means[s]``."""
    rng = np.random.default_rng(len(seed_means) + int(1000 * sum(seed_means)))
    per = []
    for m in seed_means:
        r = rng.normal(m, spread, per_seed)
        per.append(r + m - r.mean())
    rewards = np.concatenate(per)
    return Cell(
        mean=float(np.mean(rewards)),
        std=float(np.std(rewards)),
        seed_std=float(np.std(seed_means)),
        nearest=float(np.mean(rewards)),
        minmax=0.5,
        seed_means=seed_means,
        rewards=rewards,
        shape_loss=0.01,
        shape_distance=0.01,
        coverage=1.0,
        utility=0.5,
        count=int(rewards.size),
        train_seconds=1.0,
        finite=True,
    )


def _table(noisy: Cell, cleaned: Cell, truth: Cell | None = None) -> dict:
    table = {("D1", "wiping", "bc", "noisy"): noisy, ("D1", "wiping", "bc", "cleaned"): cleaned}
    if truth is not None:
        table[("D1", "wiping", "bc", "truth")] = truth
    return table


SPREAD_SEEDS = (0.40, 0.50, 0.60, 0.70, 0.80)
"""Per-seed mean R̄ of noisy that vary widely between seeds (training-seed variance)."""


def _shifted(shift: float, jitter: float = 0.002) -> tuple[float, ...]:
    """SPREAD_SEEDS plus `shift` in every seed, give or take `jitter`."""
    wobble = np.array([1.0, -0.5, 0.3, -1.0, 0.2]) * jitter
    return tuple(float(x) for x in np.array(SPREAD_SEEDS) + shift + wobble)


def test_the_verdict_pairs_the_seeds_where_welch_would_not_see_the_gain() -> None:
    """Cleaned is better by 0.02 in each of 5 seeds whose means spread over 0.4: paired over
    seeds that is clear; Welch's test on the same per-seed means is not (the seed-to-seed spread
    swamps it). The report's cell says cleaned, so it cannot be Welch's test."""
    noisy, cleaned = _cell(SPREAD_SEEDS), _cell(_shifted(0.02))
    welch = scipy.stats.ttest_ind(cleaned.seed_means, noisy.seed_means, equal_var=False)
    assert welch.pvalue > 0.5  # pyright: ignore[reportAttributeAccessIssue]  # not in the stub
    text = verdict_cell(_table(noisy, cleaned), "D1", "wiping", "bc")
    assert text.startswith("cleaned (paired t, 5 seeds, better in 5/5, p < 0.001")
    assert verdict(noisy, cleaned) == "cleaned"
    assert verdict(cleaned, noisy) == "noisy"
    assert verdict(noisy, _cell(_shifted(0.0, jitter=0.02))) == "tie"


def test_rollouts_of_one_model_are_never_samples() -> None:
    """One seed: however many rollouts and however far apart, no test and no verdict. Several
    seeds: the per-seed means decide, not the pooled rollouts."""
    one_noisy, one_cleaned = _cell((0.50,), spread=0.01), _cell((0.60,), spread=0.01)
    welch = scipy.stats.ttest_ind(one_cleaned.rewards, one_noisy.rewards, equal_var=False)
    assert welch.pvalue < 1e-10  # pyright: ignore[reportAttributeAccessIssue]  # not in the stub
    assert verdict_cell(_table(one_noisy, one_cleaned), "D1", "wiping", "bc") == (
        "one seed: no test"
    )
    v = verdict_test(one_noisy, one_cleaned, _cell((0.70,)))
    assert v.word == "no test" and v.test is None and v.gate is None
    # Three seeds of tight rollouts: cleaned wins one seed by far and loses two narrowly. Pooled
    # rollouts as samples would call it; three pairs do not.
    noisy, cleaned = _cell((0.50, 0.50, 0.50), 0.001), _cell((0.62, 0.49, 0.49), 0.001)
    pooled = scipy.stats.ttest_ind(cleaned.rewards, noisy.rewards, equal_var=False)
    assert pooled.pvalue < 0.01  # pyright: ignore[reportAttributeAccessIssue]  # not in the stub
    v = verdict_test(noisy, cleaned)
    assert v.word == "tie" and v.test is not None and v.test.n == 3
    assert (v.test.wins, v.test.losses) == (1, 2)


def test_the_truth_gate_comes_first() -> None:
    """With truth rows a verdict needs truth to beat noisy (paired, p < 0.01), as in the
    conditioned protocol; otherwise the cell says the protocol cannot tell."""
    noisy, cleaned = _cell(SPREAD_SEEDS), _cell(_shifted(0.02))
    clear = verdict_test(noisy, cleaned, _cell(_shifted(0.10, jitter=0.004)))
    assert clear.word == "cleaned" and clear.gate is not None and clear.gate.passed
    assert clear.text().endswith("; truth gate passed)")
    assert clear.gap is not None and clear.gap.share == pytest.approx(0.2, abs=0.02)

    flat = _cell(_shifted(0.0, jitter=0.05))  # truth no better than noisy
    table = _table(noisy, cleaned, flat)
    assert verdict(noisy, cleaned, flat) == "cannot tell"
    text = verdict_cell(table, "D1", "wiping", "bc")
    assert text.startswith("cannot tell: truth does not clearly beat noisy (paired t, 5 seeds")
    worse = verdict_test(noisy, cleaned, _cell(_shifted(-0.10)))
    assert worse.word == "cannot tell" and "truth is worse than noisy" in worse.reason


def test_a_non_finite_seed_mean_gets_no_test() -> None:
    bad = dataclasses.replace(_cell((0.5, 0.6)), seed_means=(0.5, float("nan")))
    v = verdict_test(_cell((0.5, 0.5)), bad)
    assert v.word == "no test" and "non-finite" in v.reason


@pytest.mark.parametrize(
    "kwargs", [{"seeds": 0}, {"workers": 0}, {"sets": ("D3",)}, {"learners": ("gail",)}]
)
def test_config_rejects_bad_settings(kwargs) -> None:
    with pytest.raises(ConfigError):
        ReproduceConfig(**kwargs)


def test_quick_preset_is_smaller_than_the_full_one() -> None:
    quick, full = ReproduceConfig.preset(True), ReproduceConfig.preset(False)
    assert quick.quick and not full.quick
    assert quick.rollouts < full.rollouts == 50
    assert full.seeds >= 3 and quick.competence and full.competence
    assert quick.tasks == full.tasks == TASKS and quick.sets == full.sets == ("D1", "D2")


def test_bt_reproduce_command_line_runs_in_worker_processes(tmp_path, capsys, monkeypatch) -> None:
    """``bt reproduce --quick --workers 2 --seeds 1`` through the command line, its preset shrunk
    to TINY's size (the real quick run is timed by benchmarks/evaluation/bench_reproduce.py)."""
    asked: list[bool] = []

    def tiny_preset(quick: bool, **overrides: object) -> ReproduceConfig:
        asked.append(quick)
        return dataclasses.replace(TINY, **overrides)  # pyright: ignore[reportArgumentType]

    monkeypatch.setattr(ReproduceConfig, "preset", staticmethod(tiny_preset))
    conditioned = ["--conditioned-seeds", "2", "--crowds", "shared"]
    main(
        [
            "reproduce",
            "--quick",
            "--workers",
            "2",
            "--seeds",
            "1",
            *conditioned,
            "--out",
            str(tmp_path),
        ]
    )
    assert asked == [True]
    printed = {Path(p).name for p in capsys.readouterr().out.split()}
    assert printed == OUTPUTS
    rows = json.loads((tmp_path / "results.json").read_text())["results"]
    assert {(r["seed"], r["learner"], r["dataset"]) for r in rows} == {
        (0, lr, d) for lr in ("bc", "ileed") for d in ("noisy", "cleaned")
    }  # --oracle not given: no truth rows, whatever the preset says
    assert all(r["finite"] and 0.0 <= r["reward_mean"] <= 1.0 for r in rows)
    report = (tmp_path / "report.md").read_text()
    assert "Of 2 (set, task, learner) cells, none is tested" in report
    assert "| one seed: no test |" in report and "Welch" not in report


def test_truth_demos_trace_the_true_loops_from_each_demos_start() -> None:
    synth = make_d1("pick_and_place", 0)
    demos = demos_from_recording(synth.recording, n_samples=120)
    truths = [d.truth for d in synth.demos]
    for demo, truth, oracle in zip(demos, truths, truth_demos(demos, truths), strict=True):
        assert oracle.n_samples == 120 and oracle.demonstrator == demo.demonstrator
        closed = np.concatenate([truth, truth[:1]])
        u, dense = np.linspace(0, 1, len(closed)), np.linspace(0, 1, 20 * len(closed))
        polyline = np.stack([np.interp(dense, u, closed[:, j]) for j in range(2)], axis=1)
        off = np.min(np.linalg.norm(oracle.positions[:, None] - polyline[None], axis=2), axis=1)
        assert off.max() < 1e-4  # on the true loop
        length = np.sum(np.linalg.norm(np.diff(closed, axis=0), axis=1))
        walked = np.sum(np.linalg.norm(np.diff(oracle.positions, axis=0), axis=1))
        assert walked == pytest.approx(length, rel=0.02)  # all of it, once
        np.testing.assert_allclose(oracle.positions[0], oracle.positions[-1])  # one period
        gap = np.linalg.norm(oracle.positions[0] - demo.positions[0])
        assert gap <= np.min(np.linalg.norm(truth - demo.positions[0], axis=1)) + 1e-12
