"""``bt import --from lerobot``: a LeRobotDataset v3.0 directory to format v1 (pyarrow only).

The end-effector position is found by the feature names of ``meta/info.json``: the components
``ee_x, ee_y, ee_z`` (or ``x, y, z``) of any feature, or a feature named like
``observation.ee_pos`` / ``observation.eef_pos`` of shape (3,); ``--ee-key FEATURE[:START]``
picks three components by hand. Sample times are the ``timestamp`` column. bt's own per-episode
columns (``bt/demonstrator``, ``bt/theta_deg``, ``bt/rho``) come back when present; otherwise
θ/ρ are NaN (unknown). Quaternion (``ee_qw..ee_qz``), joints (``joint_1..joint_7``) and gripper
components come back when named so.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.records import DemoRecord, Recording
from bt_pipeline.data.tasks import Task
from bt_pipeline.exceptions import RecordingError
from bt_pipeline.interop.plane_fit import imported_recording

_EE_NAMES = (("ee_x", "ee_y", "ee_z"), ("x", "y", "z"), ("eef_x", "eef_y", "eef_z"))
_EE_FEATURES = ("observation.ee_pos", "observation.eef_pos", "observation.robot0_eef_pos")
_QUAT = ("ee_qw", "ee_qx", "ee_qy", "ee_qz")
_JOINTS = tuple(f"joint_{k}" for k in range(1, 8))


def read_lerobot(
    root: str | Path, task: Task, plane: TaskPlane | None, ee_key: str | None = None
) -> Recording:
    """Read every episode of a LeRobot v3.0 dataset as a format-v1 :class:`Recording`.

    Raises:
        RecordingError: Not a v3.0 dataset, or no end-effector position can be found (named).
    """
    root = Path(root)
    info_path = root / "meta" / "info.json"
    if not info_path.is_file():
        raise RecordingError(f"{root}: no meta/info.json; not a LeRobot dataset directory")
    try:
        info = json.loads(info_path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise RecordingError(f"{info_path}: unreadable ({exc})") from None
    if info.get("codebase_version") != "v3.0":
        raise RecordingError(
            f"{info_path}: codebase_version {info.get('codebase_version')!r}; bt reads v3.0 "
            "(convert older datasets with LeRobot's convert_dataset_v21_to_v30 first)"
        )
    features: dict[str, Any] = info.get("features", {})
    feature, columns = _ee_columns(features, ee_key, str(info_path))
    files = sorted((root / "data").glob("*/*.parquet"))
    if not files:
        raise RecordingError(f"{root}: no data/chunk-*/file-*.parquet files")
    try:
        table = _concat(files)
        episodes = np.asarray(table["episode_index"], dtype=np.int64)
        meta = _episode_meta(root)
    except (OSError, KeyError, pa.ArrowException) as exc:
        raise RecordingError(
            f"{root}: cannot read the dataset's parquet files ({type(exc).__name__}: {exc})"
        ) from None
    demos = {}
    wanted = [e for e in np.unique(episodes) if meta.get(int(e), {}).get("bt/task", task) == task]
    if not wanted:
        raise RecordingError(f"{root}: no episode of task {task} (column bt/task)")
    for k, ep in enumerate(wanted):
        rows = np.flatnonzero(episodes == ep)
        rows = rows[np.argsort(np.asarray(table["frame_index"])[rows], kind="stable")]
        demos[f"demo_{k}"] = _demo(table, features, feature, columns, rows, meta.get(int(ep), {}))
    return imported_recording(task, plane, demos, str(root), "lerobot")


def _ee_columns(features: dict[str, Any], ee_key: str | None, where: str) -> tuple[str, list[int]]:
    if ee_key:
        name, _, start = ee_key.partition(":")
        if name not in features:
            raise RecordingError(
                f"{where}: --ee-key {name!r} is no feature ({', '.join(features)})"
            )
        first = int(start or 0)
        return name, [first, first + 1, first + 2]
    for name, feature in features.items():
        names = feature.get("names") or []
        if isinstance(names, dict):  # older datasets: {"motors": [...]}
            names = next(iter(names.values()), [])
        for triple in _EE_NAMES:
            if all(n in names for n in triple):
                return name, [names.index(n) for n in triple]
    for name in _EE_FEATURES:
        if name in features and list(features[name].get("shape", [])) == [3]:
            return name, [0, 1, 2]
    raise RecordingError(
        f"{where}: no end-effector position found (components ee_x, ee_y, ee_z of a feature, or "
        f"a feature {', '.join(_EE_FEATURES)}); name one with --ee-key FEATURE[:START]"
    )


def _demo(
    table: dict[str, list[Any]],
    features: dict[str, Any],
    feature: str,
    columns: list[int],
    rows: np.ndarray,
    meta: dict[str, Any],
) -> DemoRecord:
    values = np.asarray([table[feature][r] for r in rows], dtype=np.float64).reshape(len(rows), -1)
    names = features[feature].get("names") or []
    names = names if isinstance(names, list) else []

    def pick(wanted: tuple[str, ...]) -> np.ndarray | None:
        if all(n in names for n in wanted):
            return values[:, [names.index(n) for n in wanted]]
        return None

    quat = pick(_QUAT)
    timestamps = np.asarray([table["timestamp"][r] for r in rows], dtype=np.float64)
    return DemoRecord(
        ee_pos=values[:, columns],
        timestamps=timestamps - timestamps[0],
        demonstrator=str(meta.get("bt/demonstrator", "unknown")),
        theta_deg=float(meta.get("bt/theta_deg", math.nan)),
        rho=float(meta.get("bt/rho", math.nan)),
        source="import",
        ee_quat=None if quat is None else quat / np.linalg.norm(quat, axis=1, keepdims=True),
        joint_pos=pick(_JOINTS),
        gripper=pick(("gripper",)),
    )


def _concat(files: list[Path]) -> dict[str, list[Any]]:
    merged: dict[str, list[Any]] = {}
    for path in files:
        for key, column in pq.read_table(path).to_pydict().items():
            merged.setdefault(key, []).extend(column)
    return merged


def _episode_meta(root: Path) -> dict[int, dict[str, Any]]:
    files = sorted((root / "meta" / "episodes").glob("*/*.parquet"))
    out: dict[int, dict[str, Any]] = {}
    for path in files:
        for row in pq.read_table(path).to_pylist():
            out[int(row["episode_index"])] = {k: v for k, v in row.items() if k.startswith("bt/")}
    return out
