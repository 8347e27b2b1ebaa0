"""Tests of bt_pipeline.execute: every executor returns the same results in order, job errors
reach the caller unchanged, and a worker that dies mid-job is retried (issue 14)."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from bt_pipeline.exceptions import ConfigError, DemoError
from bt_pipeline.execute import (
    LOCAL_RAY_OBJECT_STORE_BYTES,
    LOCAL_RAY_SYSTEM_CONFIG,
    ExecutorConfig,
    WorkerLostError,
    iter_jobs,
    reuse_workers,
    run_jobs,
    start_local_ray,
)
from bt_pipeline.testing.sockets import is_loopback_address, listening


def square(item: tuple[int, str]) -> int:
    """A job: the square of item[0]; dies (kill-like exit) while item[1]'s marker is missing."""
    value, marker = item
    if marker:
        path = Path(marker)
        if not path.exists():
            path.write_text("died once")
            os._exit(3)  # the worker process dies mid-job, as under kill -9 or OOM
    return value * value


def always_dies(item: int) -> int:
    os._exit(4)


def after(item: tuple[int, str]) -> int:
    """A job: item[0], once item[1] (a file the consumer writes) exists; -1 if it never does."""
    value, marker = item
    for _ in range(3000):  # a guard against a hang only: the consumer writes it at once
        if not marker or Path(marker).exists():
            return value
        time.sleep(0.1)
    return -1


def bad_input(item: int) -> int:
    if item == 2:
        raise DemoError(f"demo_{item} does not move")
    return item


@pytest.fixture(scope="module")
def ray_local() -> Iterator[None]:
    import ray  # installed with the dev extras (bt[dev] pulls bt[ray])
    from ray import cloudpickle

    start_local_ray(2)  # what bt does: loopback only
    # Ship this test module's functions by value: Ray workers do not have tests/ on sys.path.
    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    yield
    ray.shutdown()


CONFIGS = [
    ExecutorConfig("local"),
    ExecutorConfig("processes", workers=1),
    ExecutorConfig("processes", workers=2),
]


@pytest.mark.parametrize("config", CONFIGS, ids=lambda c: f"{c.kind}-{c.workers}")
def test_results_in_order(config: ExecutorConfig) -> None:
    items = [(k, "") for k in range(7)]
    assert run_jobs(square, items, config) == [k * k for k in range(7)]
    assert run_jobs(square, [], config) == []


def test_ray_results_match_processes(ray_local: None) -> None:
    items = [(k, "") for k in range(9)]
    expected = run_jobs(square, items, ExecutorConfig("processes", workers=2))
    assert run_jobs(square, items, ExecutorConfig("ray", workers=2)) == expected
    assert run_jobs(square, items, ExecutorConfig("ray", workers=0)) == expected


def test_a_dead_worker_is_retried_with_processes(tmp_path: Path) -> None:
    marker = tmp_path / "job3.died"
    items = [(k, str(marker) if k == 3 else "") for k in range(6)]
    out = list(iter_jobs(square, items, ExecutorConfig("processes", workers=2, retries=1)))
    assert sorted(out) == [(k, k * k) for k in range(6)]  # each job handed over once
    assert marker.read_text() == "died once"  # the first attempt really died


def pid_of(item: tuple[int, str]) -> int:
    """A job: its worker's process id (after `square`'s chance to die)."""
    square(item)
    return os.getpid()


def test_rounds_of_jobs_in_a_reuse_block_share_one_pool_and_still_retry(tmp_path: Path) -> None:
    config = ExecutorConfig("processes", workers=2, retries=1)
    marker = tmp_path / "died"
    with reuse_workers(config):
        first = set(run_jobs(pid_of, [(k, "") for k in range(4)], config))
        second = set(run_jobs(pid_of, [(k, "") for k in range(4)], config))
        assert second <= first and os.getpid() not in first  # the same workers, not this one
        # A worker dies: its pool is replaced, the job rerun, and the next round uses the new one.
        third = set(
            run_jobs(pid_of, [(k, str(marker) if k == 1 else "") for k in range(3)], config)
        )
        fourth = set(run_jobs(pid_of, [(k, "") for k in range(3)], config))
    assert marker.read_text() == "died once"
    assert third - first and not fourth & first  # the rerun and the next round: a new pool
    outside = set(run_jobs(pid_of, [(k, "") for k in range(2)], config))
    assert not outside & (first | third | fourth)  # after the block: a pool of its own


def test_local_jobs_run_one_at_a_time_as_their_results_are_taken() -> None:
    events: list[str] = []

    def job(k: int) -> int:
        events.append(f"run {k}")
        return k

    for k, result in iter_jobs(job, [0, 1, 2], ExecutorConfig("local")):
        events.append(f"took {result} as {k}")
    assert events == ["run 0", "took 0 as 0", "run 1", "took 1 as 1", "run 2", "took 2 as 2"]


def test_pool_results_are_handed_over_as_each_job_finishes(tmp_path: Path) -> None:
    """Job 1 finishes only once the caller has received job 0's result: a pool that kept its
    results until every job was done would hand job 1 back as -1."""
    marker = tmp_path / "took-job-0"
    items = [(0, ""), (1, str(marker))]
    taken = []
    for k, result in iter_jobs(after, items, ExecutorConfig("processes", workers=2)):
        taken.append((k, result))
        marker.touch()
    assert taken == [(0, 0), (1, 1)]


def test_a_dead_worker_is_retried_with_ray(ray_local: None, tmp_path: Path) -> None:
    marker = tmp_path / "job1.died"
    items = [(k, str(marker) if k == 1 else "") for k in range(4)]
    out = run_jobs(square, items, ExecutorConfig("ray", workers=2, retries=1))
    assert out == [0, 1, 4, 9]
    assert marker.exists()


def test_a_worker_that_keeps_dying_fails_the_run() -> None:
    with pytest.raises(WorkerLostError, match=r"job [ab]: its worker process died 2 times"):
        run_jobs(
            always_dies,
            [0, 1],
            ExecutorConfig("processes", workers=2, retries=1),
            label=lambda i: "ab"[i],
        )


def test_ray_worker_that_keeps_dying_fails_the_run(ray_local: None) -> None:
    with pytest.raises(WorkerLostError, match="job 0: its Ray worker died"):
        run_jobs(always_dies, [0], ExecutorConfig("ray", workers=1, retries=0))


@pytest.mark.parametrize("kind", ["local", "processes"])
def test_job_errors_are_not_retried_and_keep_their_message(kind: str) -> None:
    config = ExecutorConfig(kind, workers=2)  # type: ignore[arg-type]
    with pytest.raises(DemoError, match="demo_2 does not move"):
        run_jobs(bad_input, [0, 1, 2, 3], config)


def test_ray_job_errors_keep_their_type_and_message(ray_local: None) -> None:
    with pytest.raises(DemoError, match="demo_2 does not move"):
        run_jobs(bad_input, [0, 1, 2, 3], ExecutorConfig("ray", workers=2))


def test_config_is_validated() -> None:
    with pytest.raises(ConfigError, match="unknown executor 'dask'; valid: local, processes, ray"):
        ExecutorConfig("dask")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="needs --executor ray"):
        ExecutorConfig("processes", ray_address="auto")
    with pytest.raises(ConfigError, match="retries"):
        ExecutorConfig("ray", retries=-1)


def test_the_local_ray_listens_on_loopback_only(ray_local: None) -> None:
    """Ray's GCS, raylet, agents and workers of the private local Ray bt starts."""
    run_jobs(square, [(1, ""), (2, "")], ExecutorConfig("ray", workers=2))  # workers are up
    sockets = listening(os.getpid())
    assert len(sockets) >= 3, sockets  # GCS, raylet (2), agents, workers
    exposed = [s for s in sockets if not is_loopback_address(s[1])]
    assert not exposed, f"Ray sockets on non-loopback interfaces: {exposed}"


def test_the_local_ray_is_sized_for_bt(ray_local: None) -> None:
    """bt's local Ray: its small object store and settings reached Ray, and the services bt
    does not use are gone while the ones it needs run (docs/scale.md, memory)."""
    import psutil
    import ray
    from ray._private.state import state

    run_jobs(square, [(1, ""), (2, "")], ExecutorConfig("ray", workers=2))  # the node works
    assert ray.cluster_resources()["object_store_memory"] == LOCAL_RAY_OBJECT_STORE_BYTES
    config = state.get_system_config()  # what the GCS runs with
    for key, value in LOCAL_RAY_SYSTEM_CONFIG.items():
        assert config[key] == value, key
    commands = []
    for child in psutil.Process().children(recursive=True):
        with contextlib.suppress(psutil.Error):
            commands.append(" ".join([child.name(), *child.cmdline()]))
    for needed in ("gcs_server", "raylet", "ray::DashboardAgent", "ray::RuntimeEnvAgent"):
        assert any(needed in c for c in commands), (needed, commands)
    for unused in ("dashboard/dashboard.py", "autoscaler/_private/monitor.py", "log_monitor.py"):
        assert not any(unused in c for c in commands), (unused, commands)


def test_bt_clean_with_ray_listens_on_loopback_only(tmp_path, write_example_file) -> None:
    """Every listening socket of `bt clean --executor ray` and its children, sampled while the
    command runs (Ray's services come and go with it)."""
    source = write_example_file(tmp_path, task="wiping", n_demos=3, n_samples=60)
    command = [sys.executable, "-m", "bt_pipeline", "clean", str(source), "--out"]
    command += [str(tmp_path / "out"), "--epochs", "2", "--executor", "ray", "--workers", "2"]
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    log = tmp_path / "stderr.txt"
    with open(log, "wb") as stderr:
        process = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=stderr)
        seen: set[tuple[int, str, int]] = set()
        while process.poll() is None:
            seen.update(listening(process.pid))
            time.sleep(0.2)
    assert process.returncode == 0, log.read_text()
    assert len(seen) >= 3, f"saw too few of Ray's sockets to judge: {seen}"
    exposed = [s for s in seen if not is_loopback_address(s[1])]
    assert not exposed, f"sockets on non-loopback interfaces: {exposed}"


def test_progress_is_plain_lines_when_stderr_is_not_a_terminal(capsys) -> None:
    local = ExecutorConfig("local")
    run_jobs(square, [(k, "") for k in range(3)], local, desc="few", progress=True)
    items = [(k, "") for k in range(100)]
    run_jobs(square, items, local, desc="many", progress=True)
    run_jobs(square, items, local, desc="quiet")
    lines = capsys.readouterr().err.splitlines()
    assert lines[:3] == [f"few: {k}/3 jobs done" for k in (1, 2, 3)]
    assert lines[3:] == [f"many: {k}/100 jobs done" for k in range(5, 101, 5)]  # every 5 %
