"""Where independent jobs run: in this process, in local worker processes, or on a Ray cluster.

``bt clean`` (one job per task, or per chunk of a large task), ``bt evaluate`` and ``bt reproduce``
(one job per set × task × learner × seed) hand their jobs to :func:`run_jobs`. A job is a
picklable function applied to one picklable item; its result comes back to this process, which
alone writes outputs (atomically), so every executor gives the same files for the same seeds.

    items ──run_jobs(fn, items, ExecutorConfig)──▶ results, in the order of the items
    items ──iter_jobs(...)──▶ (index, result) as each job finishes, nothing kept after the yield
      local:     fn(item) in this process, one after another
      processes: a spawn-context ProcessPoolExecutor of ``workers`` processes
      ray:       one Ray task per item (``ray.init(address)``, or a private local Ray without
                 dashboard whose every socket binds to 127.0.0.1: :func:`start_local_ray`)

Fault tolerance: a worker that dies mid-job (killed, out of memory, segfault) is retried up to
``retries`` times; a job that raises a :class:`~bt_pipeline.exceptions.BtError` is not retried
(the input is wrong, and would be wrong again) and its message reaches the caller unchanged. Ray
is an optional dependency (``pip install 'bt[ray]'``); docs/scale.md says what each executor costs.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import multiprocessing
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any, Literal, TypeVar, get_args

from tqdm import tqdm

from bt_pipeline.exceptions import BtError, ConfigError

ExecutorName = Literal["local", "processes", "ray"]
"""``local``: this process; ``processes``: local worker processes; ``ray``: Ray tasks."""

T = TypeVar("T")
R = TypeVar("R")


@dataclass(frozen=True)
class ExecutorConfig:
    """How :func:`run_jobs` runs jobs."""

    kind: ExecutorName = "processes"
    """Which executor."""
    workers: int = 1
    """processes: pool size (1 runs in this process); ray: most jobs in flight (0: no limit)."""
    ray_address: str | None = None
    """ray: address of a running cluster (``ray start --head`` prints it; ``auto`` finds a local
    one); None starts a private local Ray with ``workers`` CPUs and no dashboard."""
    retries: int = 2
    """Times a job whose worker died is run again before the run fails."""

    def __post_init__(self) -> None:
        if self.kind not in get_args(ExecutorName):
            names = ", ".join(get_args(ExecutorName))
            raise ConfigError(f"unknown executor {self.kind!r}; valid: {names}")
        if self.workers < 0:
            raise ConfigError(f"workers must be >= 0; got {self.workers}")
        if self.retries < 0:
            raise ConfigError(f"retries must be >= 0; got {self.retries}")
        if self.ray_address is not None and self.kind != "ray":
            raise ConfigError("--ray-address needs --executor ray")


class WorkerLostError(BtError):
    """A job's worker died more often than the retries allow."""


def iter_jobs(
    fn: Callable[[T], R],
    items: Sequence[T],
    config: ExecutorConfig,
    *,
    desc: str = "jobs",
    progress: bool = False,
    label: Callable[[T], str] = lambda item: "",
) -> Iterator[tuple[int, R]]:
    """Apply `fn` to every item with the configured executor; yield ``(index, result)`` as each
    job finishes.

    Nothing is kept here once a result is yielded, so a caller that writes each result out and
    drops it holds one result at a time (``bt clean`` with many tasks). Order: the items' with
    ``local`` (each job runs only when the previous result has been taken), completion order
    otherwise.

    Args:
        fn: A picklable (module-level) function of one item.
        items: The jobs' inputs (picklable).
        config: Which executor, how wide, how many retries.
        desc: Name of the progress bar.
        progress: Show a bar over all jobs on stderr (plain lines when stderr is not a terminal).
        label: Names a job in error messages.

    Raises:
        BtError: A job raised it (not retried); the message names the job when `label` does.
        WorkerLostError: A job's worker died more than ``config.retries`` times.
    """
    if not items:
        return
    bar: tqdm | _LineProgress
    if progress and not sys.stderr.isatty():
        bar = _LineProgress(len(items), desc)
    else:
        bar = tqdm(total=len(items), desc=desc, unit="job", file=sys.stderr, disable=not progress)
    with bar:
        if config.kind == "ray":
            yield from _iter_ray(fn, items, config, bar, label)
        elif config.kind == "processes" and config.workers > 1 and len(items) > 1:
            yield from _iter_processes(fn, items, config, bar, label)
        else:
            for i, item in enumerate(items):
                result = fn(item)
                bar.update(1)
                yield i, result
                del result  # not held while the next job runs


def run_jobs(
    fn: Callable[[T], R], items: Sequence[T], config: ExecutorConfig, **options: Any
) -> list[R]:
    """:func:`iter_jobs`' results as one list, in the order of `items` (same keyword options:
    ``desc``, ``progress``, ``label``; same errors)."""
    results: dict[int, R] = dict(iter_jobs(fn, items, config, **options))
    return [results[i] for i in range(len(items))]


class _LineProgress:
    """Progress as plain stderr lines (logs, pipes: no terminal to redraw): one per finished job,
    or per 5 % of the jobs when there are more than 20, and one at the end."""

    def __init__(self, total: int, desc: str) -> None:
        self.total, self.desc, self.done = total, desc, 0
        self.step = max(1, total // 20)

    def __enter__(self) -> _LineProgress:
        return self

    def __exit__(self, *_: object) -> None:
        return None

    def update(self, n: int = 1) -> None:
        before, self.done = self.done, self.done + n
        if self.done == self.total or self.done // self.step > before // self.step:
            print(f"{self.desc}: {self.done}/{self.total} jobs done", file=sys.stderr, flush=True)


def _iter_processes(
    fn: Callable[[T], R],
    items: Sequence[T],
    config: ExecutorConfig,
    bar: tqdm | _LineProgress,
    label: Callable[[T], str],
) -> Iterator[tuple[int, R]]:
    """A spawn pool; a pool broken by a dead worker is replaced and its unfinished jobs rerun."""
    finished: set[int] = set()
    attempts = dict.fromkeys(range(len(items)), 0)
    shared = config in _SHARED_POOLS
    while len(finished) < len(items):
        pending = [i for i in range(len(items)) if i not in finished]
        if shared:
            pool = _SHARED_POOLS[config] or _new_pool(config.workers)
            _SHARED_POOLS[config] = pool
        else:
            pool = _new_pool(min(config.workers, len(pending)))
        broken = False
        futures: dict[concurrent.futures.Future[R], int] = {}
        try:
            futures = {pool.submit(fn, items[i]): i for i in pending}
            for future in concurrent.futures.as_completed(futures):
                i = futures.pop(future)  # the future (and its result) is not kept here
                try:
                    result = future.result()
                except BrokenProcessPool:
                    broken = True
                    continue
                del future
                finished.add(i)
                bar.update(1)
                yield i, result
                del result
        finally:
            # On a job's error (or Ctrl-C), drop the queued jobs instead of waiting for them.
            if not shared or broken:
                pool.shutdown(wait=True, cancel_futures=True)
                if shared:
                    _SHARED_POOLS[config] = None  # a fresh pool for the jobs left
            else:
                for future in futures:  # those not handed over (an error, or the caller stopped)
                    future.cancel()
        if broken:
            for i in (i for i in pending if i not in finished):
                attempts[i] += 1
                if attempts[i] > config.retries:
                    raise WorkerLostError(
                        f"job {label(items[i]) or i}: its worker process died "
                        f"{attempts[i]} times (retries: {config.retries})"
                    )


_SHARED_POOLS: dict[ExecutorConfig, concurrent.futures.ProcessPoolExecutor | None] = {}
"""The pools of the :func:`reuse_workers` blocks open in this process (None: not started yet)."""


@contextlib.contextmanager
def reuse_workers(config: ExecutorConfig) -> Iterator[None]:
    """Within this block, every :func:`run_jobs` / :func:`iter_jobs` call with `config` uses one
    pool of worker processes, started on first use and shut down at the end of the block.

    A spawn worker pays its start-up (a fresh interpreter importing numpy, scipy and torch:
    seconds, measured in docs/scale.md) once per block instead of once per call: ``bt clean``
    makes several rounds of jobs per large task. A dead worker still gets the pool replaced and
    its jobs retried. Nothing changes for ``local`` and ``ray`` (Ray keeps its own workers).
    """
    if config.kind != "processes" or config.workers <= 1 or config in _SHARED_POOLS:
        yield
        return
    _SHARED_POOLS[config] = None
    try:
        yield
    finally:
        pool = _SHARED_POOLS.pop(config)
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)


def _new_pool(workers: int) -> concurrent.futures.ProcessPoolExecutor:
    return concurrent.futures.ProcessPoolExecutor(
        max_workers=workers, mp_context=multiprocessing.get_context("spawn")
    )


def _iter_ray(
    fn: Callable[[T], R],
    items: Sequence[T],
    config: ExecutorConfig,
    bar: tqdm | _LineProgress,
    label: Callable[[T], str],
) -> Iterator[tuple[int, R]]:
    ray = _import_ray()
    if not ray.is_initialized():
        if config.ray_address is None:
            start_local_ray(max(config.workers, 1))
        else:
            ray.init(address=config.ray_address, **_RAY_QUIET)
    # max_retries reruns a task whose worker process died; exceptions raised by the job itself
    # are not retried (retry_exceptions=False): bad input fails the same way every time.
    remote = ray.remote(max_retries=config.retries, retry_exceptions=False)(fn)
    limit = config.workers if config.workers > 0 else len(items)
    refs: dict[Any, int] = {}
    queue = list(range(len(items)))
    while queue or refs:
        while queue and len(refs) < limit:
            i = queue.pop(0)
            refs[remote.remote(items[i])] = i
        done, _ = ray.wait(list(refs), num_returns=1)
        for ref in done:
            i = refs.pop(ref)
            try:
                result = ray.get(ref)
            except ray.exceptions.RayTaskError as error:
                cause = error.cause if hasattr(error, "cause") else None
                if isinstance(cause, BtError):
                    raise cause from None
                raise
            except (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError) as error:
                raise WorkerLostError(
                    f"job {label(items[i]) or i}: its Ray worker died more than "
                    f"{config.retries} times ({type(error).__name__})"
                ) from None
            bar.update(1)
            yield i, result
            del result


_RAY_QUIET = {"include_dashboard": False, "log_to_driver": False, "configure_logging": False}
RAY_LOCAL_ONLY_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
"""Ray's switch between "a local Ray only" (0) and "may join a cluster" (Linux default)."""

LOCAL_RAY_OBJECT_STORE_BYTES = 256 * 2**20
"""Object store of the private local Ray [bytes]. Ray's default is 30 % of the RAM; bt's objects
are chunk jobs and their results (a few MB each, a few in flight), and anything beyond this
spills to disk instead of failing (docs/scale.md)."""
LOCAL_RAY_SYSTEM_CONFIG: dict[str, Any] = {"enable_metrics_collection": False}
"""Ray settings of the private local Ray: no metrics are collected (nothing scrapes them here)."""
LOCAL_RAY_UNUSED_SERVICES = ("dashboard", "monitor", "log_monitor")
"""Services of the private local Ray that bt stops once it is up, as Ray's ``Node.kill_<name>``:
the dashboard's API server (with the dashboard off it only reports usage stats, which are off),
the autoscaler monitor (one fixed node: nothing to scale) and the log monitor (it streams worker
logs to the driver, and ``log_to_driver`` is off). Each is a Python process of 45-80 MiB PSS
(docs/scale.md); the GCS, raylet, dashboard agent and runtime-env agent stay (the raylet starts
and uses its agents)."""


def start_local_ray(num_cpus: int) -> None:
    """Start a private single-node Ray whose every socket binds to 127.0.0.1, sized for bt.

    ``ray.init(_node_ip_address="127.0.0.1")`` alone is not enough: Ray 2.60 replaces a loopback
    node address by the machine's address (``ray/_private/services.py``,
    ``resolve_ip_for_localhost`` -> ``get_node_ip_address``) unless clusters are disabled
    (``ray_constants.ENABLE_RAY_CLUSTER``, set from ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER``), and
    its GCS, raylet, workers and agents then listen on every interface. With clusters disabled
    for this start, they all get node address 127.0.0.1 and bind to it (docs/security.md).

    Memory: a small object store (:data:`LOCAL_RAY_OBJECT_STORE_BYTES`), no metrics
    (:data:`LOCAL_RAY_SYSTEM_CONFIG`), and the services bt does not use stopped
    (:data:`LOCAL_RAY_UNUSED_SERVICES`); docs/scale.md measures what each costs.

    Args:
        num_cpus: CPUs the local Ray may use.
    """
    ray = _import_ray()
    from ray._private import ray_constants

    saved_env, saved_flag = os.environ.get(RAY_LOCAL_ONLY_ENV), ray_constants.ENABLE_RAY_CLUSTER
    os.environ[RAY_LOCAL_ONLY_ENV] = "0"  # what Ray's own processes read when they start
    ray_constants.ENABLE_RAY_CLUSTER = False  # the same, for a Ray imported before
    try:
        ray.init(
            num_cpus=num_cpus,
            object_store_memory=LOCAL_RAY_OBJECT_STORE_BYTES,
            _node_ip_address="127.0.0.1",
            _system_config=dict(LOCAL_RAY_SYSTEM_CONFIG),
            **_RAY_QUIET,
        )
    finally:  # later connections of this process (e.g. to a cluster) are not affected
        ray_constants.ENABLE_RAY_CLUSTER = saved_flag
        if saved_env is None:
            os.environ.pop(RAY_LOCAL_ONLY_ENV, None)
        else:
            os.environ[RAY_LOCAL_ONLY_ENV] = saved_env
    _stop_unused_services(ray)


def _stop_unused_services(ray: Any) -> None:
    """Stop :data:`LOCAL_RAY_UNUSED_SERVICES` of the local Ray this process started.

    Ray has no ``ray.init`` option for them (``ray start`` has ``--no-monitor`` and
    ``--include-log-monitor``); its node object, which ``ray.shutdown`` uses to stop the rest,
    has a ``kill_<name>`` method for each. A Ray without them keeps its services.
    """
    node = getattr(getattr(ray, "_private", None), "worker", None)
    node = getattr(node, "_global_node", None)
    for service in LOCAL_RAY_UNUSED_SERVICES:
        kill = getattr(node, f"kill_{service}", None)
        if kill is not None:
            kill(check_alive=False)


def _import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise ConfigError(
            "--executor ray needs Ray: pip install 'bt[ray]' (or pip install ray)"
        ) from None
    return ray
