"""Check a ``bt export --format lerobot`` dataset with lerobot 0.6.1's own LeRobotDataset.

Runs in LeRobot's venv (Python ≥ 3.12; see verify_lerobot.sh), never in bt's. Loads the dataset
offline, indexes frames, draws DataLoader batches with delta_timestamps, and recomputes every
episode's statistics with LeRobot's compute_episode_stats to compare with those bt wrote.
Prints one JSON object; exits 1 on the first failed check.

    python check_lerobot_export.py EXPORT_DIR
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import numpy as np
import torch
from lerobot.datasets.compute_stats import compute_episode_stats
from lerobot.datasets.lerobot_dataset import LeRobotDataset


def main(root: Path) -> dict:
    ds = LeRobotDataset("bt/export", root=root)
    fps = ds.fps
    report: dict = {
        "lerobot_dataset": "loaded",
        "episodes": ds.num_episodes,
        "frames": ds.num_frames,
        "fps": fps,
        "features": sorted(ds.features),
        "tasks": list(ds.meta.tasks.index),
    }
    frame = ds[0]
    report["frame0_keys"] = sorted(frame)
    assert frame["observation.state"].dtype == torch.float32
    last = ds[len(ds) - 1]
    assert int(last["index"]) == len(ds) - 1, "index column out of order"
    assert isinstance(frame["task"], str) and frame["task"], "no task sentence"
    delta = {
        "observation.state": [-1 / fps, 0.0],
        "observation.environment_state": [0.0],
        "action": [k / fps for k in range(10)],
    }
    seq = LeRobotDataset("bt/export", root=root, delta_timestamps=delta)
    loader = torch.utils.data.DataLoader(seq, batch_size=8, shuffle=True, num_workers=0)
    batch = next(iter(loader))
    report["batch_shapes"] = {k: list(v.shape) for k, v in batch.items() if hasattr(v, "shape")}
    assert list(batch["action"].shape)[:2] == [8, 10]
    assert "action_is_pad" in batch, "delta_timestamps padding mask missing"
    worst = 0.0
    for ep in range(ds.num_episodes):
        start = int(ds.meta.episodes[ep]["dataset_from_index"])
        stop = int(ds.meta.episodes[ep]["dataset_to_index"])
        rows = ds.hf_dataset.select(range(start, stop)).with_format("numpy")
        data = {k: np.stack(rows[k]) for k in ("observation.state", "action", "timestamp")}
        ours = _episode_stats(root, ep)
        theirs = compute_episode_stats(data, {k: ds.features[k] for k in data})
        for key, stats in theirs.items():
            for name, value in stats.items():
                mine = np.asarray(ours[f"stats/{key}/{name}"], dtype=np.float64)
                worst = max(worst, float(np.max(np.abs(mine.reshape(-1) - value.reshape(-1)))))
    report["episode_stats_max_abs_diff"] = worst
    assert worst < 1e-5, f"episode stats differ from LeRobot's by {worst}"
    report["bt_columns"] = sorted(k for k in ds.meta.episodes.column_names if k.startswith("bt/"))
    report["ok"] = True
    return report


def _episode_stats(root: Path, episode: int) -> dict:
    import pyarrow.parquet as pq

    for path in sorted((root / "meta" / "episodes").glob("*/*.parquet")):
        for row in pq.read_table(path).to_pylist():
            if row["episode_index"] == episode:
                return row
    raise KeyError(episode)


if __name__ == "__main__":
    print(json.dumps(main(Path(sys.argv[1])), indent=2))
