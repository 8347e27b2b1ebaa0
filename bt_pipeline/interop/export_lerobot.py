"""``bt export --format lerobot``: write a LeRobotDataset v3.0 directory with pyarrow.

LeRobot cannot be imported beside bt (it needs Python ≥ 3.12 and torch < 2.12), so the layout
of lerobot 0.6.1 (``lerobot/datasets/{utils,dataset_metadata,dataset_writer}.py``) is written
directly::

    OUT/
    ├── meta/info.json                         codebase_version "v3.0", fps, features, totals
    ├── meta/stats.json                        per-feature stats over all frames (lerobot_stats)
    ├── meta/tasks.parquet                     task (the pandas index) -> task_index
    ├── meta/episodes/chunk-000/file-000.parquet   one row per episode: length, tasks, frame
    │                                          range, data file, stats/<feature>/<stat>, bt/*
    ├── meta/bt.json                           bt sidecar: task planes, sources, field meanings
    └── data/chunk-000/file-000.parquet        one row per frame

Every demo is resampled to t_k = k / fps (:mod:`~bt_pipeline.interop.resample`). The whole
directory is built beside `out` under a hidden name and renamed into place, so a failed export
leaves nothing behind. Field meanings: docs/interop.md.
"""

from __future__ import annotations

import json
import logging
import re
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from bt_pipeline.data.atomic import publish_dir, recover_dir, temp_name
from bt_pipeline.data.tasks import GuidedTask, Task, has_guide, is_task_name
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.interop import lerobot_stats
from bt_pipeline.interop.resample import FixedRateDemo, resample_fixed_rate
from bt_pipeline.interop.sources import ExportTask, load_export_tasks

LOGGER = logging.getLogger("bt")

CODEBASE_VERSION = "v3.0"
"""LeRobot dataset format written."""
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
FILE_SIZE_MB = 100
"""LeRobot's data file size limit: a new data file starts past it."""
CHUNK_SIZE = 1000
"""LeRobot's most files per chunk folder."""
DEFAULT_TASK_TEXT: dict[GuidedTask, str] = {
    "wiping": "Wipe the surface in repeated loops.",
    "weaving": "Weave through the frame in repeated figure-eight loops.",
    "pick_and_place": "Carry the object over the arch and bring it back, repeatedly.",
}
"""The task sentence of each built-in task unless ``--task-text`` gives another."""


def default_task_text(task: Task) -> str:
    """The task sentence of `task` unless ``--task-text`` gives another: the built-in sentence,
    or for a task without one its name in words ("Perform stirring in repeated loops.")."""
    if has_guide(task):
        return DEFAULT_TASK_TEXT[task]
    return f"Perform {re.sub(r'[_-]+', ' ', task).strip()} in repeated loops."


@dataclass(frozen=True)
class LeRobotExport:
    """What :func:`export_lerobot` wrote."""

    root: Path
    """The dataset directory."""
    episodes: int
    """Episodes written."""
    frames: int
    """Frames written over all episodes."""
    state_names: tuple[str, ...]
    """The components of ``observation.state``."""


def parse_task_texts(items: Sequence[str], tasks: Sequence[Task]) -> dict[Task, str]:
    """Task sentences from ``--task-text``: ``TASK=TEXT`` items, or one TEXT for a single task.

    Raises:
        ConfigError: A TASK that is not exported, or a bare TEXT with several tasks.
    """
    texts: dict[Task, str] = {task: default_task_text(task) for task in tasks}
    by_name: dict[str, Task] = {task: task for task in tasks}
    for item in items:
        name, sep, text = item.partition("=")
        named = by_name.get(name.strip()) if sep else None
        if named is not None:
            texts[named] = text.strip()
        elif len(tasks) == 1 and not (sep and is_task_name(name.strip())):
            texts[tasks[0]] = item.strip()
        else:
            raise ConfigError(
                f"--task-text {item!r}: expected TASK=TEXT with TASK one of the exported tasks "
                f"({', '.join(tasks)})"
            )
    for task, text in texts.items():
        if not text:
            raise ConfigError(f"--task-text for {task} is empty")
    return texts


def export_lerobot(
    paths: Sequence[str | Path],
    out: str | Path,
    *,
    fps: int = 50,
    task_texts: Sequence[str] = (),
    overwrite: bool = False,
) -> LeRobotExport:
    """Export the recordings under `paths` as one LeRobotDataset v3.0 at `out`.

    Args:
        paths: Format-v1 recordings (files, directories, globs): raw or cleaned.
        out: Dataset directory to create.
        fps: Frame rate of the dataset [Hz]; every demo is resampled to it.
        task_texts: ``TASK=TEXT`` task sentences (see :func:`parse_task_texts`).
        overwrite: Replace an existing `out`.

    Raises:
        ConfigError: `out` exists (without `overwrite`), bad fps or task text.
        RecordingError, DemoError: An input cannot be read or holds no exportable demo.
    """
    out = Path(out)
    if fps < 1:
        raise ConfigError(f"--fps must be a positive integer; got {fps}")
    for line in recover_dir(out):  # a killed export's leftovers; its old dataset put back
        LOGGER.info("%s", line)
    if out.exists() and not overwrite:
        raise ConfigError(f"{out} exists; choose another --out or pass --overwrite")
    tasks = load_export_tasks(paths)
    texts = parse_task_texts(task_texts, [t.task for t in tasks])
    layout = _StateLayout.of(tasks)
    tmp = temp_name(out)
    try:
        result = _write(tmp, tasks, texts, layout, fps)
        publish_dir(tmp, out, overwrite)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return LeRobotExport(root=out, **result, state_names=layout.names)


@dataclass(frozen=True)
class _StateLayout:
    """Which optional signals go into ``observation.state`` (those every demo has)."""

    quat: bool
    joints: bool
    gripper: bool

    @staticmethod
    def of(tasks: Sequence[ExportTask]) -> _StateLayout:
        records = [d.record for t in tasks for d in t.demos]
        return _StateLayout(
            quat=all(r.ee_quat is not None for r in records),
            joints=all(r.joint_pos is not None for r in records),
            gripper=all(r.gripper is not None for r in records),
        )

    @property
    def names(self) -> tuple[str, ...]:
        names = ["ee_x", "ee_y", "ee_z"]
        if self.quat:
            names += ["ee_qw", "ee_qx", "ee_qy", "ee_qz"]
        if self.joints:
            names += [f"joint_{k}" for k in range(1, 8)]
        if self.gripper:
            names += ["gripper"]
        return tuple(names)

    def state(self, frames: FixedRateDemo) -> np.ndarray:
        parts = [frames.ee_pos]
        for use, value in (
            (self.quat, frames.ee_quat),
            (self.joints, frames.joint_pos),
            (self.gripper, frames.gripper),
        ):
            if use and value is not None:
                parts.append(value)
        return np.concatenate(parts, axis=1).astype(np.float32)


def _features(layout: _StateLayout) -> dict[str, dict[str, Any]]:
    scalar = {"shape": [1], "names": None}
    return {
        "observation.state": {
            "dtype": "float32",
            "shape": [len(layout.names)],
            "names": list(layout.names),
        },
        "observation.environment_state": {
            "dtype": "float32",
            "shape": [2],
            "names": ["plane_u", "plane_v"],
        },
        "action": {"dtype": "float32", "shape": [3], "names": ["ee_vx", "ee_vy", "ee_vz"]},
        "timestamp": {"dtype": "float32", **scalar},
        "frame_index": {"dtype": "int64", **scalar},
        "episode_index": {"dtype": "int64", **scalar},
        "index": {"dtype": "int64", **scalar},
        "task_index": {"dtype": "int64", **scalar},
    }


def _write(
    root: Path,
    tasks: Sequence[ExportTask],
    texts: dict[Task, str],
    layout: _StateLayout,
    fps: int,
) -> dict[str, int]:
    features = _features(layout)
    episodes: list[dict[str, Any]] = []
    frames: list[dict[str, np.ndarray]] = []
    episode_stats: list[dict[str, lerobot_stats.Stats]] = []
    index = 0
    for task_index, export_task in enumerate(tasks):
        for demo_index, demo in enumerate(export_task.demos):
            grid = resample_fixed_rate(demo.record, fps)
            n = len(grid.timestamps)
            columns = {
                "observation.state": layout.state(grid),
                "observation.environment_state": export_task.plane.to_plane(grid.ee_pos).astype(
                    np.float32
                ),
                "action": grid.actions.astype(np.float32),
                "timestamp": grid.timestamps.astype(np.float32),
                "frame_index": np.arange(n, dtype=np.int64),
                "episode_index": np.full(n, len(episodes), dtype=np.int64),
                "index": np.arange(index, index + n, dtype=np.int64),
                "task_index": np.full(n, task_index, dtype=np.int64),
            }
            frames.append(columns)
            episode_stats.append({k: lerobot_stats.feature_stats(v) for k, v in columns.items()})
            episodes.append(
                {
                    "episode_index": len(episodes),
                    "tasks": [texts[export_task.task]],
                    "length": n,
                    "dataset_from_index": index,
                    "dataset_to_index": index + n,
                    "bt/task": export_task.task,
                    "bt/source_file": demo.file,
                    "bt/source_demo": demo.name,
                    "bt/demonstrator": demo.record.demonstrator,
                    "bt/theta_deg": float(demo.record.theta_deg),
                    "bt/rho": float(demo.record.rho),
                    "bt/utility": float(demo.utility),
                    "bt/best": demo_index == export_task.best_index,
                }
            )
            index += n
    _write_data(root, frames, features, episodes)
    _write_episodes(root, episodes, episode_stats)
    stats = {key: lerobot_stats.aggregate([s[key] for s in episode_stats]) for key in features}
    _write_json(root / "meta/stats.json", lerobot_stats.to_json(stats))
    _write_tasks(root, [texts[t.task] for t in tasks])
    _write_json(root / "meta/info.json", _info(features, fps, len(episodes), index, len(tasks)))
    _write_json(root / "meta/bt.json", _sidecar(tasks, fps))
    return {"episodes": len(episodes), "frames": index}


def _info(features: dict[str, Any], fps: int, episodes: int, frames: int, tasks: int) -> dict:
    return {
        "codebase_version": CODEBASE_VERSION,
        "robot_type": "franka_fr3",
        "total_episodes": episodes,
        "total_frames": frames,
        "total_tasks": tasks,
        "chunks_size": CHUNK_SIZE,
        "data_files_size_in_mb": FILE_SIZE_MB,
        "video_files_size_in_mb": 200,
        "fps": fps,
        "splits": {"train": f"0:{episodes}"},
        "data_path": DATA_PATH,
        "video_path": None,
        "features": features,
    }


def _sidecar(tasks: Sequence[ExportTask], fps: int) -> dict[str, Any]:
    return {
        "bt_export": "lerobot",
        "fps": fps,
        "tasks": {
            t.task: {
                "plane_origin": t.plane.origin.tolist(),
                "plane_axes": t.plane.axes.tolist(),
                "best_demo": f"{t.demos[t.best_index].file}:{t.demos[t.best_index].name}",
            }
            for t in tasks
        },
        "fields": {
            "observation.state": "ee position [m] world frame (+ ee quaternion w,x,y,z, joint "
            "positions [rad], gripper when every demo has them)",
            "observation.environment_state": "ee position in the task plane (u, v) [m]",
            "action": "ee velocity [m/s], forward difference on the fps grid, last frame 0",
            "bt/theta_deg": "demonstrator rotation θ [deg], NaN = unknown",
            "bt/rho": "demonstrator scale ρ, NaN = unknown",
            "bt/utility": "normalised demo utility Ũ (paper Eq. 8) among the task's demos",
        },
    }


def _column(values: np.ndarray, feature: dict[str, Any]) -> pa.Array:
    dtype = pa.float32() if feature["dtype"] == "float32" else pa.int64()
    if feature["shape"] == [1]:
        return pa.array(values.reshape(-1), type=dtype)
    width = int(feature["shape"][0])
    flat = pa.array(np.ascontiguousarray(values).reshape(-1), type=dtype)
    return pa.FixedSizeListArray.from_arrays(flat, width)


def _write_data(
    root: Path,
    frames: Sequence[dict[str, np.ndarray]],
    features: dict[str, Any],
    episodes: list[dict[str, Any]],
) -> None:
    bytes_per_frame = sum(
        4 * int(f["shape"][0]) if f["dtype"] == "float32" else 8 for f in features.values()
    )
    budget = FILE_SIZE_MB * 1024 * 1024 // bytes_per_frame
    file_index, in_file, writer = 0, 0, None
    try:
        for columns, episode in zip(frames, episodes, strict=True):
            n = episode["length"]
            if writer is not None and in_file + n > budget:
                writer.close()
                writer, file_index, in_file = None, file_index + 1, 0
            table = pa.table({key: _column(columns[key], f) for key, f in features.items()})
            if writer is None:
                path = root / DATA_PATH.format(
                    chunk_index=file_index // CHUNK_SIZE, file_index=file_index % CHUNK_SIZE
                )
                path.parent.mkdir(parents=True, exist_ok=True)
                writer = pq.ParquetWriter(path, table.schema, compression="snappy")
            writer.write_table(table)
            episode["data/chunk_index"] = file_index // CHUNK_SIZE
            episode["data/file_index"] = file_index % CHUNK_SIZE
            in_file += n
    finally:
        if writer is not None:
            writer.close()


def _write_episodes(
    root: Path, episodes: list[dict[str, Any]], stats: list[dict[str, lerobot_stats.Stats]]
) -> None:
    rows = []
    for episode, episode_stats in zip(episodes, stats, strict=True):
        row = dict(episode)
        for feature, values in episode_stats.items():
            for key, value in values.items():
                row[f"stats/{feature}/{key}"] = np.asarray(value).reshape(-1).tolist()
        row["meta/episodes/chunk_index"] = 0
        row["meta/episodes/file_index"] = 0
        rows.append(row)
    path = root / EPISODES_PATH.format(chunk_index=0, file_index=0)
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pylist(rows), path, compression="snappy")


def _write_tasks(root: Path, texts: Sequence[str]) -> None:
    """``meta/tasks.parquet`` as pandas writes it: column task_index, index ``task``."""
    table = pa.table(
        {
            "task_index": pa.array(range(len(texts)), type=pa.int64()),
            "task": pa.array(list(texts), type=pa.string()),
        }
    )
    pandas_meta = {
        "index_columns": ["task"],
        "column_indexes": [
            {
                "name": None,
                "field_name": None,
                "pandas_type": "unicode",
                "numpy_type": "object",
                "metadata": {"encoding": "UTF-8"},
            }
        ],
        "columns": [
            {
                "name": "task_index",
                "field_name": "task_index",
                "pandas_type": "int64",
                "numpy_type": "int64",
                "metadata": None,
            },
            {
                "name": "task",
                "field_name": "task",
                "pandas_type": "unicode",
                "numpy_type": "object",
                "metadata": None,
            },
        ],
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.3",
    }
    table = table.replace_schema_metadata({"pandas": json.dumps(pandas_meta)})
    pq.write_table(table, root / "meta/tasks.parquet")


def _write_json(path: Path, value: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(value, indent=4, allow_nan=True) + "\n", encoding="utf-8")
