"""Shared fixtures: small valid recordings in memory and on disk.

* ``make_recording(task="wiping", n_demos=3, n_samples=50, seed=0, ..., plane=None)`` returns a
  valid :class:`~bt_pipeline.data.records.Recording` of circles drawn in the task's default
  plane (or `plane`: tasks without a built-in guide, such as ``"stirring"``, have none).
* ``write_example_file(directory, name="example.hdf5", **make_recording_kwargs)`` writes one to
  ``directory / name`` and returns the path.
* ``run(capsys, *args)`` runs ``bt args`` in-process and returns (exit code, stdout, stderr).
* ``make_app(**AppOptions overrides)`` starts a teleop app recording under ``tmp_path``, and
  ``tabs(app)`` opens a simulated tab on it (:mod:`bt_teleop.testing.harness`); all closed at the
  end.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.recording import write_recording
from bt_pipeline.data.records import DemoRecord, Recording, Source
from bt_pipeline.data.tasks import Task, default_plane

RADIUS_M = 0.08
"""Radius of the example circles [m]."""


def build_recording(
    task: Task = "wiping",
    n_demos: int = 3,
    n_samples: int = 50,
    seed: int = 0,
    *,
    source: Source = "synthetic",
    optional: bool = False,
    masks: dict[str, list[str]] | None = None,
    attrs: dict[str, Any] | None = None,
    plane: TaskPlane | None = None,
) -> Recording:
    """A valid recording: demo k draws one circle in `plane` (the default plane of `task`).

    Demo k is rotated by θ = 20k [deg] and scaled by ρ = 1 + 0.1k; odd demos store θ and ρ as
    NaN (unknown). Timestamps are about 20 ms apart with seeded jitter; positions carry 1 mm of
    seeded noise.

    Args:
        task: The task (and so the plane, unless `plane` is given).
        n_demos: Number of demos, named demo_0 ... demo_{n_demos - 1}.
        n_samples: Samples T per demo.
        seed: Seed of the jitter and noise.
        source: The ``source`` attr of every demo.
        optional: Also fill ee_quat, joint_pos, gripper, states, created, ep_meta and extra attrs.
        masks: robomimic filter keys.
        attrs: Extra ``/data`` attrs.
        plane: The task plane; None takes the default plane of `task` (a task without a
            built-in guide, such as ``"stirring"``, has none: give one).
    """
    rng = np.random.default_rng(seed)
    plane = default_plane(task) if plane is None else plane
    demos: dict[str, DemoRecord] = {}
    for k in range(n_demos):
        theta_deg, rho = 20.0 * k, 1.0 + 0.1 * k
        dt_s = 0.02 * (1.0 + 0.2 * (rng.random(n_samples) - 0.5))
        timestamps = np.concatenate([[0.0], np.cumsum(dt_s[1:])])
        phase = 2.0 * np.pi * timestamps / timestamps[-1] + math.radians(theta_deg)
        uv = rho * RADIUS_M * np.stack([np.cos(phase), np.sin(phase)], axis=1)
        uv = uv + 1e-3 * rng.standard_normal(uv.shape)
        extra: dict[str, Any] = {}
        if optional:
            extra = {
                "ee_quat": np.tile([1.0, 0.0, 0.0, 0.0], (n_samples, 1)),
                "joint_pos": rng.standard_normal((n_samples, 7)),
                "gripper": rng.random((n_samples, 1)),
                "states": rng.standard_normal((n_samples, 23)),
                "created": f"2025-01-{k + 1:02d}T10:00:00+00:00",
                "ep_meta": {"scene": "table", "seed": seed, "tags": ["circle", str(k)]},
                "attrs": {"score": 0.5 + 0.1 * k, "tags": ["a", "b"], "n_laps": 1, "ok": True},
            }
        demos[f"demo_{k}"] = DemoRecord(
            ee_pos=plane.to_world(uv),
            timestamps=timestamps,
            demonstrator=f"person_{k % 2}",
            theta_deg=math.nan if k % 2 else theta_deg,
            rho=math.nan if k % 2 else rho,
            source=source,
            **extra,
        )
    return Recording(
        task=task,
        plane=plane,
        demos=demos,
        env_args={"env_name": f"bt_{task}", "type": 0, "env_kwargs": {"task": task}},
        masks=masks or {},
        attrs=attrs or {},
    )


def run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    """Run ``bt args`` in-process; return (exit code, stdout, stderr)."""
    from bt_pipeline.cli import main  # the CLI's imports only where a test runs it

    code = 0
    try:
        main(list(args))
    except SystemExit as exit_:
        code = int(exit_.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def make_recording() -> Callable[..., Recording]:
    """Factory of small valid recordings; see :func:`build_recording` for the arguments."""
    return build_recording


@pytest.fixture
def write_example_file() -> Callable[..., Path]:
    """Factory writing a recording of :func:`build_recording` to ``directory / name``."""

    def write(directory: Path, name: str = "example.hdf5", **kwargs: Any) -> Path:
        return write_recording(Path(directory) / name, build_recording(**kwargs))

    return write


@pytest.fixture
def make_app(tmp_path: Path) -> Iterator[Callable[..., Any]]:
    """Teleop apps recording under ``tmp_path / "recordings"`` (stopped at the end)."""
    # teleop tests only: no viser import elsewhere
    from bt_teleop.testing.harness import app_factory

    with app_factory(tmp_path / "recordings") as make:
        yield make


@pytest.fixture
def tabs() -> Iterator[Callable[..., Any]]:
    """``tabs(app)`` opens a simulated browser tab on a teleop app (closed at the end)."""
    from bt_teleop.testing.harness import tab_factory

    with tab_factory() as open_tab:
        yield open_tab
