"""Carry what the cleaner does not use from a raw demo onto its cleaned timeline.

Cleaning changes end-effector positions only. A cleaned demo keeps the raw demo's orientation
(``ee_quat``, slerped), gripper (linear) and every extra ``obs/<key>`` (linear for float data,
nearest sample for integer or boolean data such as images or flags), resampled from the raw
sample times to the cleaned ones. Joint positions and MuJoCo states are not carried: they
determine the raw end-effector position and would contradict the cleaned one. Filter keys
(``/mask``) are carried with demo names mapped to the output's names.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation, Slerp

from bt_pipeline.data.records import DemoRecord, FloatArray


def slerp_wxyz(t_new: FloatArray, t: FloatArray, quat_wxyz: FloatArray) -> FloatArray:
    """Spherical interpolation of unit quaternions (w, x, y, z) from times `t` to `t_new`.

    Returns:
        Unit quaternions w, x, y, z with w ≥ 0, shape (len(t_new), 4).
    """
    rotations = Rotation.from_quat(np.asarray(quat_wxyz)[:, [1, 2, 3, 0]])
    xyzw = Slerp(t, rotations)(np.clip(t_new, t[0], t[-1])).as_quat(canonical=True)
    return xyzw[:, [3, 0, 1, 2]]


def resample_any(t_new: FloatArray, t: FloatArray, values: NDArray[Any]) -> NDArray[Any]:
    """Samples of shape (T, ...) at times `t` to times `t_new`: linear for floats, else nearest."""
    values = np.asarray(values)
    if values.dtype.kind == "f":
        flat = values.reshape(len(t), -1)
        out = np.stack([np.interp(t_new, t, flat[:, j]) for j in range(flat.shape[1])], axis=1)
        return out.reshape((len(t_new), *values.shape[1:])).astype(values.dtype)
    nearest = np.clip(np.searchsorted(t, t_new), 1, len(t) - 1)
    nearest -= (t_new - t[nearest - 1]) < (t[nearest] - t_new)
    return values[nearest]


def carried_obs(record: DemoRecord, t_new: FloatArray) -> dict[str, Any]:
    """``ee_quat``, ``gripper`` and ``extra_obs`` of `record` at times `t_new`.

    Args:
        record: The raw demo.
        t_new: Output times, shape (N,), in [s] from the raw demo's first sample.

    Returns:
        Keyword arguments for a :class:`DemoRecord` (absent fields are None or empty).
    """
    t = record.timestamps - record.timestamps[0]
    return {
        "ee_quat": None if record.ee_quat is None else slerp_wxyz(t_new, t, record.ee_quat),
        "gripper": None if record.gripper is None else resample_any(t_new, t, record.gripper),
        "extra_obs": {k: resample_any(t_new, t, v) for k, v in record.extra_obs.items()},
    }


def carried_masks(
    masks_by_file: Mapping[str, Mapping[str, list[str]]], names: Mapping[tuple[str, str], str]
) -> dict[str, list[str]]:
    """Union of the inputs' filter keys, with (file, demo) mapped to output names.

    Args:
        masks_by_file: Each input file's ``/mask`` keys.
        names: (file, input demo name) -> output demo name, for every demo written.

    Returns:
        Key -> output names in output order; keys left empty are dropped.
    """
    order = {name: i for i, name in enumerate(names.values())}
    out: dict[str, list[str]] = {}
    for file, masks in masks_by_file.items():
        for key, members in masks.items():
            out.setdefault(key, []).extend(names[(file, m)] for m in members if (file, m) in names)
    return {k: sorted(set(v), key=order.__getitem__) for k, v in out.items() if v}
