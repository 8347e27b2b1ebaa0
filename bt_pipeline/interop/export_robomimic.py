"""``bt export --format robomimic``: a robomimic 0.3 low-dim dataset that its tools accept as is.

What robomimic 0.3.0 checks, and what this writes for it (docs/interop.md has the mapping)::

    /data                 attrs total, env_args (type 2 = gym: robomimic's EnvType.GYM_TYPE),
                          action_scale (3,), action_space, task, plane_origin, plane_axes
    /data/demo_<i>        attrs num_samples (+ bt metadata: demonstrator, θ, ρ, Ũ, source)
        actions   (T, 3)  ee velocity / action_scale, in [-1, 1] (get_dataset_info.py checks)
        rewards   (T,)    V_E of the task's Stage 1 at each sample (Eq. 11, per step)
        dones     (T,)    1 at the last sample
        obs/, next_obs/   ee_pos, robot0_eef_pos, plane_uv (+ ee_quat wxyz, robot0_eef_quat
                          xyzw, joint_pos, robot0_joint_pos when every demo has them);
                          next_obs is obs one step ahead (the last row repeated)
    /mask/{train,valid,best,top_<k>}  + the inputs' own filter keys

Each file is written to a hidden temporary file beside the destination (``.<name>.tmp-<pid>-<hex>``;
a killed export's is removed by the next one), fsynced and renamed into place. Into a folder
(several tasks) the files are one output set (:class:`~bt_pipeline.data.output_set.OutputSet`):
all of them appear, or none.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import h5py
import numpy as np

from bt_pipeline.clean.stage1.extract import run_stage1
from bt_pipeline.data.atomic import remove_stale_temps, temp_name
from bt_pipeline.data.output_set import OutputSet, recover
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.interop.sources import ExportTask, load_export_tasks, top_k_indices

log = logging.getLogger("bt")
GYM_ENV_TYPE = 2
"""robomimic's ``EnvType.GYM_TYPE``: a type its env utilities know (bt scenes are no robosuite
environments; rollouts in robomimic need the env registered under ``env_name``)."""
ACTION_SPACE = "ee_velocity_m_per_s"
"""What an un-normalised action is: end-effector velocity [m/s] in the world frame."""


@dataclass(frozen=True)
class RobomimicExport:
    """What :func:`export_robomimic` wrote."""

    path: Path
    """The file."""
    demos: int
    """Demos written."""
    masks: dict[str, list[str]]
    """Filter keys written."""
    action_scale: tuple[float, float, float]
    """Per-axis scale [m/s]: raw action = normalised action × scale."""


def export_robomimic(
    paths: Sequence[str | Path],
    out: str | Path,
    *,
    valid_fraction: float = 0.1,
    top_k: Sequence[int] = (3,),
    seed: int = 0,
    overwrite: bool = False,
) -> list[RobomimicExport]:
    """Export the recordings under `paths` as robomimic datasets, one file per task.

    Args:
        paths: Format-v1 recordings (raw or cleaned).
        out: Output file (``.hdf5``/``.h5``) when the inputs hold one task; otherwise a
            directory that gets ``<task>.robomimic.hdf5`` per task.
        valid_fraction: Share of demos in ``mask/valid`` (at least one when there are ≥ 2 demos).
        top_k: Write ``mask/top_<k>``: the k demos of highest Ũ, for each k.
        seed: Seed of the train/valid split and of Stage 1's value map.
        overwrite: Replace existing outputs.

    Raises:
        ConfigError: Several tasks into one file, an existing output, or bad options. Nothing
            is written then.
        RecordingError, DemoError: An input cannot be read or holds no exportable demo.
    """
    out = Path(out)
    if not 0.0 <= valid_fraction < 1.0:
        raise ConfigError(f"--valid-fraction must be in [0, 1); got {valid_fraction}")
    if any(k < 1 for k in top_k):
        raise ConfigError(f"--top-k values must be ≥ 1; got {list(top_k)}")
    tasks = load_export_tasks(paths)
    if out.suffix in (".hdf5", ".h5"):
        if len(tasks) != 1:
            raise ConfigError(
                f"a robomimic file holds one task; the inputs hold "
                f"{', '.join(t.task for t in tasks)}: give a directory as --out to write one "
                "file per task"
            )
        remove_stale_temps(out)  # a killed export's temporary file
        _refuse_existing([out], overwrite)
        return [_export_task(tasks[0], out, valid_fraction, top_k, seed)]
    if out.is_dir():
        recover(out)  # finish or undo a killed export into this folder first
    targets = [(t, f"{t.task}.robomimic.hdf5") for t in tasks]
    _refuse_existing([out / name for _, name in targets], overwrite)
    with OutputSet(out) as outputs:  # one file per task: all of them or none
        staged = [
            _export_task(task, outputs.path(name), valid_fraction, top_k, seed)
            for task, name in targets
        ]
        outputs.commit()
    return [replace(e, path=out / name) for e, (_, name) in zip(staged, targets, strict=True)]


def _refuse_existing(paths: list[Path], overwrite: bool) -> None:
    for path in paths:
        if path.is_dir() or (path.exists() and not overwrite):
            raise ConfigError(f"{path} exists; choose another --out or pass --overwrite")


def _export_task(
    task: ExportTask, out: Path, valid_fraction: float, top_k: Sequence[int], seed: int
) -> RobomimicExport:
    actions = [d.record.resolved_actions() for d in task.demos]
    scale = np.max(np.abs(np.concatenate(actions)), axis=0)
    scale = np.where(scale > 0.0, scale, 1.0)
    masks = _masks(task, valid_fraction, top_k, seed)
    rewards = step_rewards(task, seed)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_name(out)
    try:
        with h5py.File(tmp, "w") as file:
            _write(file, task, actions, scale, masks, rewards)
        with open(tmp, "rb+") as written:
            os.fsync(written.fileno())
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)
    return RobomimicExport(
        path=out,
        demos=len(task.demos),
        masks=masks,
        action_scale=(float(scale[0]), float(scale[1]), float(scale[2])),
    )


def step_rewards(task: ExportTask, seed: int = 0) -> list[np.ndarray]:
    """Per-step reward r_k = V_E(x_i(t_k)) of every demo, from the task's Stage 1 (Eq. 11).

    Stage 1 runs on the demos as scored (best = highest Ũ); each demo's samples are mapped into
    the best demo's frame (θ/ρ) before the value map is read, as the cleaner's R̄ does.

    Returns:
        One array per demo, shape (T_i,), in V_E's units (1 on the canonical motion).
    """
    stage1 = run_stage1([d.demo for d in task.demos], task.best_index, seed=seed)
    rewards = []
    for i, demo in enumerate(task.demos):
        uv = task.plane.to_plane(demo.record.ee_pos)
        rewards.append(np.asarray(stage1.value_map(stage1.to_best_frame(i, uv)), dtype=np.float64))
    return rewards


def _masks(
    task: ExportTask, valid_fraction: float, top_k: Sequence[int], seed: int
) -> dict[str, list[str]]:
    names = [f"demo_{i}" for i in range(len(task.demos))]
    n_valid = (
        0 if valid_fraction == 0 or len(names) < 2 else max(1, round(valid_fraction * len(names)))
    )
    chosen = set(np.random.default_rng(seed).permutation(len(names))[:n_valid].tolist())
    masks = {
        "train": [n for i, n in enumerate(names) if i not in chosen],
        "valid": [n for i, n in enumerate(names) if i in chosen],
        "best": [names[task.best_index]],
    }
    utilities = [d.utility for d in task.demos]
    for k in top_k:
        masks[f"top_{k}"] = [names[i] for i in top_k_indices(utilities, k)]
    for key, members in task.masks.items():
        name = key if key not in masks else f"input_{key}"
        if name != key:
            log.info("input filter key %r kept as %r (bt writes its own %r)", key, name, key)
        masks[name] = members
    return masks


def _obs(task: ExportTask, i: int) -> dict[str, np.ndarray]:
    record = task.demos[i].record
    records = [d.record for d in task.demos]
    obs = {
        "ee_pos": record.ee_pos,
        "robot0_eef_pos": record.ee_pos,
        "plane_uv": task.plane.to_plane(record.ee_pos),
    }
    if all(r.ee_quat is not None for r in records) and record.ee_quat is not None:
        obs["ee_quat"] = record.ee_quat
        obs["robot0_eef_quat"] = record.ee_quat[:, [1, 2, 3, 0]]  # robosuite: x, y, z, w
    if all(r.joint_pos is not None for r in records) and record.joint_pos is not None:
        obs["joint_pos"] = record.joint_pos
        obs["robot0_joint_pos"] = record.joint_pos
    if all(r.gripper is not None for r in records) and record.gripper is not None:
        obs["gripper"] = record.gripper
    return obs


def _write(
    file: h5py.File,
    task: ExportTask,
    actions: list[np.ndarray],
    scale: np.ndarray,
    masks: dict[str, list[str]],
    rewards: list[np.ndarray],
) -> None:
    data = file.create_group("data")
    data.attrs["total"] = sum(d.record.num_samples for d in task.demos)
    data.attrs["env_args"] = json.dumps(
        {
            "env_name": f"bt-{task.task}-v0",
            "type": GYM_ENV_TYPE,
            "env_kwargs": {"task": task.task},
        }
    )
    data.attrs["action_scale"] = scale
    data.attrs["action_space"] = ACTION_SPACE
    data.attrs["task"] = task.task
    data.attrs["plane_origin"] = task.plane.origin
    data.attrs["plane_axes"] = task.plane.axes
    data.attrs["exported_by"] = "bt export --format robomimic"
    for i, demo in enumerate(task.demos):
        record = demo.record
        group = data.create_group(f"demo_{i}")
        group.attrs["num_samples"] = record.num_samples
        group.attrs["demonstrator"] = record.demonstrator
        group.attrs["theta_deg"] = float(record.theta_deg)
        group.attrs["rho"] = float(record.rho)
        group.attrs["utility"] = float(demo.utility)
        group.attrs["source"] = record.source
        group.attrs["source_file"] = demo.file
        group.attrs["source_demo"] = demo.name
        group.create_dataset("actions", data=actions[i] / scale)
        group.create_dataset("rewards", data=rewards[i])
        dones = np.zeros(record.num_samples, dtype=np.int64)
        dones[-1] = 1
        group.create_dataset("dones", data=dones)
        group.create_dataset("timestamps", data=record.timestamps - record.timestamps[0])
        if record.states is not None:
            group.create_dataset("states", data=record.states)
        for key, value in _obs(task, i).items():
            value = np.asarray(value, dtype=np.float64)
            group.create_dataset(f"obs/{key}", data=value)
            group.create_dataset(f"next_obs/{key}", data=np.concatenate([value[1:], value[-1:]]))
    group = file.create_group("mask")
    for key, members in masks.items():
        group.create_dataset(key, data=np.array(members, dtype="S"))
