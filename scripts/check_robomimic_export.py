"""Check a ``bt export --format robomimic`` file with robomimic 0.3.0 itself.

Runs in robomimic's venv (see verify_robomimic.sh), never in bt's: its get_dataset_info.py must
pass (actions in [-1, 1]), and SequenceDataset with its default dataset keys (actions, rewards,
dones) and load_next_obs=True must load the ``train`` filter key and give batches. Prints one
JSON object; exits 1 on the first failed check.

    python check_robomimic_export.py FILE
"""

from __future__ import annotations

import json
import subprocess
import sys

import h5py
import robomimic.utils.file_utils as FileUtils
import robomimic.utils.obs_utils as ObsUtils
import torch
from robomimic.utils.dataset import SequenceDataset


def main(path: str) -> dict:
    info = subprocess.run(
        [sys.executable, "-m", "robomimic.scripts.get_dataset_info", "--dataset", path],
        capture_output=True,
        text=True,
        check=False,
    )
    report: dict = {"get_dataset_info_exit": info.returncode}
    assert info.returncode == 0, info.stderr[-2000:]
    report["get_dataset_info_tail"] = info.stdout.strip().splitlines()[-12:]
    env_meta = FileUtils.get_env_metadata_from_dataset(path)
    report["env_type"] = env_meta["type"]
    with h5py.File(path, "r") as f:
        present = set(f["data/demo_0/obs"].keys())
    wanted = ("robot0_eef_pos", "robot0_eef_quat", "robot0_joint_pos", "plane_uv")
    obs_keys = tuple(k for k in wanted if k in present)
    report["obs_keys"] = list(obs_keys)
    ObsUtils.initialize_obs_utils_with_obs_specs(
        {"obs": {"low_dim": list(obs_keys), "rgb": [], "depth": [], "scan": []}}
    )
    shapes = FileUtils.get_shape_metadata_from_dataset(path, all_obs_keys=obs_keys)
    report["action_dim"] = shapes["ac_dim"]
    dataset = SequenceDataset(
        hdf5_path=path,
        obs_keys=obs_keys,
        dataset_keys=("actions", "rewards", "dones"),
        seq_length=10,
        filter_by_attribute="train",
    )
    report["train_demos"] = dataset.n_demos
    report["train_sequences"] = len(dataset)
    sample = dataset[0]
    report["sample_keys"] = sorted(sample)
    assert "next_obs" in sample and "rewards" in sample
    loader = torch.utils.data.DataLoader(dataset, batch_size=4, shuffle=True, num_workers=0)
    batch = next(iter(loader))
    report["batch_actions_shape"] = list(batch["actions"].shape)
    valid = SequenceDataset(
        hdf5_path=path,
        obs_keys=obs_keys,
        dataset_keys=("actions", "rewards", "dones"),
        filter_by_attribute="valid",
    )
    report["valid_demos"] = valid.n_demos
    report["ok"] = True
    return report


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1]), indent=2, default=str))
