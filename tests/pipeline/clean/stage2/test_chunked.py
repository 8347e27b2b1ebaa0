"""Tests of Stage 2 in chunks (bt_pipeline.clean.stage2.chunked) and of chunked `bt clean` runs.

A task of M ≤ K demos is refined bit-identically to one batch; chunks share the task's Stage 1
and frozen scales; a seeded chunked run gives the same outputs with every executor (issue 14).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from bt_pipeline.clean.driver import clean_paths
from bt_pipeline.clean.pipeline import CleanOptions, TaskCleanResult, clean_demos
from bt_pipeline.clean.stage2.chunked import (
    BestFrameRewards,
    chunk_jobs,
    chunk_seed,
    chunk_sizes,
    merge_results,
    refine_in_chunks,
)
from bt_pipeline.clean.stage2.config import RefineConfig, RefineResult
from bt_pipeline.clean.stage2.refiner import refine_demos
from bt_pipeline.clean.stage2.scales import refine_normaliser, task_scales
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.recording import read_recording, write_recording
from bt_pipeline.data.synth_human import make_human_set
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.execute import ExecutorConfig
from bt_pipeline.score.utility import Normaliser

CONFIG = RefineConfig(epochs=6, hidden=8, seed=4)
"""A small network and few epochs: chunking behaviour, fast enough for CI."""


@pytest.fixture(scope="module")
def task() -> tuple[TaskCleanResult, np.ndarray, Normaliser]:
    """A cleaned 7-demo human-style set: its Stage 1, raw positions and frozen normaliser."""
    demos = demos_from_recording(make_human_set("wiping", 7, seed=2).recording)
    result = clean_demos(demos, CleanOptions(epochs=2, progress=False))
    positions = np.stack([demo.positions for demo in result.demos])
    normaliser = refine_normaliser(result.scores.normaliser, result.stage1.shape_losses)
    return result, positions, normaliser


def test_chunk_sizes_are_near_equal_and_at_most_k() -> None:
    for m in (1, 2, 7, 256, 257, 1000):
        for k in (1, 3, 8, 256):
            sizes = chunk_sizes(m, k)
            assert sum(sizes) == m and max(sizes) <= k and max(sizes) - min(sizes) <= 1
            assert len(sizes) == -(-m // k)
    with pytest.raises(ConfigError, match="--chunk-size must be ≥ 1; got 0"):
        chunk_sizes(5, 0)
    with pytest.raises(ConfigError, match="--chunk-size must be ≥ 1; got 0"):
        CleanOptions(chunk_size=0)


def test_chunk_seeds_are_distinct_and_chunk_0_keeps_the_seed() -> None:
    seeds = [chunk_seed(7, c) for c in range(50)]
    assert seeds[0] == 7 and len(set(seeds)) == 50
    assert chunk_seed(7, 1) != chunk_seed(8, 1)


def test_one_chunk_is_bit_identical_to_one_batch(task) -> None:
    result, positions, normaliser = task
    stage1 = result.stage1
    batch = refine_demos(
        positions,
        stage1.aligned,
        thetas_deg=stage1.thetas,
        best_index=stage1.best_index,
        reward_fn=stage1.rewards,
        normaliser=normaliser,
        config=CONFIG,
    )
    for k in (len(positions), 256):
        chunked = refine_in_chunks(
            positions, stage1, normaliser=normaliser, config=CONFIG, chunk_size=k
        )
        assert chunked.chunk_sizes == (len(positions),)
        for name in ("refined", "betas", "beta_history", "loss_history", "reward_history"):
            assert np.array_equal(getattr(chunked, name), getattr(batch, name)), name


def test_chunk_rewards_are_stage1s_rewards_of_those_demos(task) -> None:
    result, positions, _ = task
    stage1 = result.stage1
    noisy = positions + np.random.default_rng(0).normal(0.0, 0.004, positions.shape)
    everyone = stage1.rewards(noisy)
    for start, stop in ((0, 3), (3, 7), (5, 6)):
        rewards = BestFrameRewards.of(stage1, start, stop)
        assert np.array_equal(rewards(noisy[start:stop]), everyone[start:stop])
    with pytest.raises(ConfigError, match=r"shape \(3, N, 2\)"):
        BestFrameRewards.of(stage1, 0, 3)(noisy)


def test_chunks_share_the_task_scales_and_one_holds_the_best(task) -> None:
    result, positions, normaliser = task
    stage1 = result.stage1
    jobs = chunk_jobs(positions, stage1, normaliser=normaliser, config=CONFIG, chunk_size=3)
    assert [len(job.positions) for job in jobs] == [3, 2, 2]
    whole = task_scales(positions, stage1.aligned)
    for job in jobs:  # frozen over the whole task, not over the chunk
        assert np.array_equal(job.scales.centre, whole.centre)
        assert (job.scales.scale, job.scales.mi_span) == (whole.scale, whole.mi_span)
        assert job.normaliser is normaliser
    own = task_scales(jobs[0].positions, jobs[0].references)
    assert own.scale != whole.scale  # so the test above could fail
    holders = [(c, job.best_index) for c, job in enumerate(jobs) if job.best_index is not None]
    assert len(holders) == 1
    chunk, local_best = holders[0]
    assert chunk == [0, 0, 0, 1, 1, 2, 2][stage1.best_index]  # chunks hold demos 0-2, 3-4, 5-6
    assert (0, 3, 5)[chunk] + local_best == stage1.best_index
    assert np.array_equal(np.concatenate([job.positions for job in jobs]), positions)
    assert len({job.config.seed for job in jobs}) == 3 and jobs[0].config.seed == CONFIG.seed
    assert "chunk 2/3 (demos 3-4)" in jobs[1].label


def test_chunked_refinement_passes_the_best_and_refines_the_rest(task) -> None:
    result, positions, normaliser = task
    stage1 = result.stage1
    out = refine_in_chunks(positions, stage1, normaliser=normaliser, config=CONFIG, chunk_size=3)
    assert out.chunk_sizes == (3, 2, 2) and out.refined.shape == positions.shape
    best = stage1.best_index
    assert np.array_equal(out.refined[best], positions[best])  # passed through, in its chunk
    others = [i for i in range(len(positions)) if i != best]
    assert np.all(np.abs(out.refined[others] - positions[others]).max(axis=(1, 2)) > 1e-6)
    assert out.beta_history.shape == (out.epochs, len(positions))
    assert out.epochs == max(out.chunk_epochs)


def _result(epochs: int, m: int, loss: float, settings_seed: int = 0) -> RefineResult:
    """A hand-made chunk result: β_i after epoch e is e/10 + i/100; the loss is constant."""
    history = np.array([[e / 10 + i / 100 for i in range(m)] for e in range(1, epochs + 1)])
    return RefineResult(
        refined=np.zeros((m, 4, 2)),
        betas=history[-1] if epochs else np.full(m, 0.5),
        beta_history=history.reshape(epochs, m),
        loss_history=np.full(epochs, loss),
        reward_history=history.reshape(epochs, m) / 2,
        variant="default",
        epochs=epochs,
        settings=RefineConfig(seed=settings_seed).resolve(),
    )


def test_merged_histories_hold_a_stopped_chunk_and_weigh_the_loss_by_demos() -> None:
    merged = merge_results(
        [_result(3, 2, -1.0), _result(5, 4, -0.4), _result(0, 1, 0.0)], [2, 4, 0]
    )
    assert merged.epochs == 5 and merged.chunk_epochs == (3, 5, 0)
    assert merged.chunk_sizes == (2, 4, 1) and merged.beta_history.shape == (5, 7)
    assert np.array_equal(merged.beta_history[3:, :2], np.tile([0.3, 0.31], (2, 1)))
    assert np.allclose(merged.loss_history[:3], (2 * -1.0 + 4 * -0.4) / 6)
    assert np.all(merged.beta_history[:, 6] == 0.5) and np.all(
        np.isnan(merged.reward_history[:, 6])
    )
    single = _result(3, 2, -1.0)
    assert merge_results([single], [2]).refined is single.refined  # one chunk: as it is


@pytest.fixture(scope="module")
def ray_local() -> Iterator[None]:
    import ray

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield
    ray.shutdown()


def _outputs(folder: Path) -> dict[str, np.ndarray]:
    recording = read_recording(folder / "wiping.cleaned.hdf5")
    return {name: record.ee_pos for name, record in recording.demos.items()}


def test_a_chunked_run_is_identical_with_every_executor(
    tmp_path: Path, ray_local: None, capsys: pytest.CaptureFixture[str]
) -> None:
    source = write_recording(tmp_path / "in.hdf5", make_human_set("wiping", 7, seed=5).recording)
    options = CleanOptions(epochs=3, write_rrd=False, chunk_size=3, progress=False)
    outputs = {}
    for config in (
        ExecutorConfig("local"),
        ExecutorConfig("processes", workers=2),
        ExecutorConfig("ray", workers=2),
    ):
        if config.kind == "ray":
            options = dataclasses.replace(options, progress=True)
        clean_paths([source], tmp_path / config.kind, options, executor=config)
        outputs[config.kind] = _outputs(tmp_path / config.kind)
    for kind in ("processes", "ray"):
        assert outputs[kind].keys() == outputs["local"].keys()
        for name, ee_pos in outputs["local"].items():
            assert np.array_equal(outputs[kind][name], ee_pos), (kind, name)
    # Progress over the chunks, as plain lines (stderr is not a terminal under pytest).
    assert "clean wiping (chunks): 3/3 jobs done" in capsys.readouterr().err
    # Another K changes the networks, so the outputs (the same seed, one batch here).
    one_batch = dataclasses.replace(options, chunk_size=256, progress=False)
    clean_paths([source], tmp_path / "k256", one_batch, executor=ExecutorConfig("local"))
    assert any(
        not np.array_equal(a, outputs["local"][name])
        for name, a in _outputs(tmp_path / "k256").items()
    )


def test_bt_clean_refuses_a_chunk_size_below_one_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from bt_pipeline.cli import main

    source = write_recording(tmp_path / "in.hdf5", make_human_set("wiping", 4, seed=1).recording)
    with pytest.raises(SystemExit) as stopped:
        main(["clean", str(source), "--out", str(tmp_path / "out"), "--chunk-size", "0"])
    assert stopped.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err == "bt: error: --chunk-size must be ≥ 1; got 0"
    assert not (tmp_path / "out").exists()


DRIVER_PROBE = """
import sys
from bt_pipeline.cli import main
try:
    main(sys.argv[1:])
finally:
    print("torch imported:", "torch" in sys.modules)
"""


@pytest.mark.parametrize("executor", ["processes", "local"])
def test_the_bt_clean_process_of_a_large_task_loads_torch_only_to_refine_itself(
    tmp_path: Path, executor: str
) -> None:
    """With workers, the process that drives a task of more than K demos sends Stage 2's chunks
    and the task scales' I_KL out as jobs and never imports torch (about 140 MiB per process,
    docs/scale.md); with ``local`` it refines them itself, so it does."""
    import os
    import subprocess
    import sys

    source = write_recording(tmp_path / "in.hdf5", make_human_set("wiping", 7, seed=5).recording)
    command = [sys.executable, "-c", DRIVER_PROBE, "clean", str(source), "--out"]
    command += [str(tmp_path / "out"), "--epochs", "2", "--chunk-size", "3", "--no-rrd"]
    command += ["--executor", executor, "--workers", "2"]
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[4])}
    done = subprocess.run(command, capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "out" / "wiping.cleaned.hdf5").exists()
    assert f"torch imported: {executor == 'local'}" in done.stdout, done.stdout
