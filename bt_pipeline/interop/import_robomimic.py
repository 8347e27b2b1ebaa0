"""``bt import --from robomimic``: a robomimic (robosuite-style) HDF5 file to format v1.

robomimic stores per demo ``obs/<key>``, ``actions`` (normalised, tool-specific), optional
``rewards``/``dones``/``states`` and ``num_samples``; no sample times, no task plane, no
demonstrator. The mapping (docs/interop.md)::

    obs/robot0_eef_pos | obs/ee_pos       -> obs/ee_pos        (required; or --ee-key)
    obs/robot0_eef_quat (x, y, z, w)      -> obs/ee_quat (w, x, y, z)
    obs/robot0_joint_pos (T, 7)           -> obs/joint_pos
    other obs/<key>                       -> kept as extra obs
    timestamps                            -> k / control_freq (env_kwargs, default 20 Hz)
    θ, ρ                                  -> NaN (unknown); actions -> bt's forward difference
    /mask/<key>                           -> kept
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.records import DemoRecord, Recording
from bt_pipeline.data.tasks import Task
from bt_pipeline.data.validate import sorted_demo_names
from bt_pipeline.exceptions import RecordingError
from bt_pipeline.interop.plane_fit import imported_recording

DEFAULT_CONTROL_HZ = 20.0
"""robosuite's default control frequency, used when the file does not say [Hz]."""
EE_KEYS = ("robot0_eef_pos", "ee_pos", "eef_pos")
"""obs keys taken as the end-effector position, first found wins."""


def read_robomimic(
    path: str | Path, task: Task, plane: TaskPlane | None, ee_key: str | None = None
) -> Recording:
    """Read a robomimic file as a format-v1 :class:`Recording` (source ``import``).

    Args:
        path: The robomimic .hdf5 file (read-only).
        task: The task its demos perform.
        plane: The task plane; None fits one by PCA (:func:`fit_plane`).
        ee_key: obs key of the end-effector position [m] (default: the first of EE_KEYS found).

    Raises:
        RecordingError: Not HDF5, no ``/data`` demos, no end-effector positions (named).
    """
    path = Path(path)
    where = str(path)
    if not path.is_file():
        raise RecordingError(f"{where}: no such file")
    try:
        with h5py.File(path, "r") as file:
            data = file.get("data")
            if not isinstance(data, h5py.Group) or not len(data):
                raise RecordingError(f"{where}: no /data group of demos; not a robomimic file")
            env_args = _env_args(data.attrs.get("env_args"))
            hz = float(env_args.get("env_kwargs", {}).get("control_freq", DEFAULT_CONTROL_HZ))
            names = sorted_demo_names(list(data.keys()), where)
            demos = {name: _demo(data[name], f"{where}: {name}", hz, ee_key) for name in names}
            masks = _masks(file)
    except (OSError, KeyError) as exc:  # not HDF5, truncated, broken links
        raise RecordingError(f"{where}: cannot read the file as HDF5 ({exc})") from exc
    env = env_args if _env_ok(env_args) else None
    return imported_recording(task, plane, demos, where, "robomimic", env, masks)


def _demo(group: Any, label: str, hz: float, ee_key: str | None) -> DemoRecord:
    if not isinstance(group, h5py.Group) or not isinstance(group.get("obs"), h5py.Group):
        raise RecordingError(f"{label}: no obs/ group")
    obs = group["obs"]
    assert isinstance(obs, h5py.Group)
    keys = [ee_key] if ee_key else [k for k in EE_KEYS if k in obs]
    if not keys or keys[0] not in obs:
        raise RecordingError(
            f"{label}: no end-effector position; expected obs/{' or obs/'.join(EE_KEYS)} "
            f"(found {', '.join(obs.keys()) or 'none'}); name one with --ee-key"
        )
    used = {keys[0]}
    ee_pos = _array(obs, keys[0])
    if ee_pos.ndim != 2 or ee_pos.shape[1] != 3:
        raise RecordingError(f"{label}: obs/{keys[0]} has shape {ee_pos.shape}; expected (T, 3)")
    n = ee_pos.shape[0]
    quat = joints = None
    if _array(obs, "robot0_eef_quat").shape == (n, 4):
        quat = _array(obs, "robot0_eef_quat")[:, [3, 0, 1, 2]]
        quat /= np.linalg.norm(quat, axis=1, keepdims=True)
        used.add("robot0_eef_quat")
    if _array(obs, "robot0_joint_pos").shape == (n, 7):
        joints = _array(obs, "robot0_joint_pos")
        used.add("robot0_joint_pos")
    extra = {
        key: np.asarray(item[()])
        for key, item in obs.items()
        if key not in used
        and key not in ("ee_quat", "joint_pos", "gripper", "ee_pos")
        and isinstance(item, h5py.Dataset)
        and item.shape[:1] == (n,)
    }
    attrs = group.attrs
    return DemoRecord(
        ee_pos=ee_pos,
        timestamps=np.arange(n) / hz,
        demonstrator=str(attrs.get("demonstrator", "unknown")),
        theta_deg=math.nan,
        rho=math.nan,
        source="import",
        ee_quat=quat,
        joint_pos=joints,
        extra_obs=extra,
    )


def _array(obs: h5py.Group, key: str) -> np.ndarray:
    """``obs/<key>`` as float64, or an empty array when it is absent or not a dataset."""
    item = obs.get(key)
    if not isinstance(item, h5py.Dataset):
        return np.empty((0,))
    return np.asarray(item[()], dtype=np.float64)


def _env_args(raw: Any) -> dict[str, Any]:
    if raw is None:
        return {}
    try:
        value = json.loads(raw.decode() if isinstance(raw, bytes) else str(raw))
    except json.JSONDecodeError:
        return {}
    return value if isinstance(value, dict) else {}


def _env_ok(env_args: dict[str, Any]) -> bool:
    return (
        isinstance(env_args.get("env_name"), str)
        and isinstance(env_args.get("type"), int)
        and isinstance(env_args.get("env_kwargs"), dict)
    )


def _masks(file: h5py.File) -> dict[str, list[str]]:
    group = file.get("mask")
    if not isinstance(group, h5py.Group):
        return {}
    return {
        key: [v.decode() if isinstance(v, bytes) else str(v) for v in item[()].tolist()]
        for key, item in group.items()
        if isinstance(item, h5py.Dataset) and item.ndim == 1
    }
