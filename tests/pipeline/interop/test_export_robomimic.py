"""bt export --format robomimic: what robomimic 0.3.0 checks, read back with h5py."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest

from bt_pipeline.data.recording import read_recording, write_recording
from bt_pipeline.data.synth import make_demo_set
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.interop.export_robomimic import GYM_ENV_TYPE, export_robomimic
from tests.pipeline.interop.conftest import full_recording


def _ds(file: h5py.File, key: str) -> np.ndarray:
    item = file[key]
    assert isinstance(item, h5py.Dataset), key
    return np.asarray(item[()])


def _attrs(file: h5py.File, key: str) -> dict[str, Any]:
    return dict(file[key].attrs)


def _demo_names(file: h5py.File) -> list[str]:
    data = file["data"]
    assert isinstance(data, h5py.Group)
    return list(data.keys())


@pytest.fixture(scope="module")
def synth_export(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, str]:
    tmp = tmp_path_factory.mktemp("robomimic")
    synth = make_demo_set("wiping", n_demos=6, seed=2)
    src = write_recording(tmp / "wiping.hdf5", synth.recording)
    [out] = export_robomimic([src], tmp / "w.robomimic.hdf5", valid_fraction=0.34, top_k=(1, 3))
    return src, out.path, synth.expert_name


def test_actions_in_unit_box_and_scale_undoes_them(synth_export) -> None:
    src, out, _ = synth_export
    raw = read_recording(src).demos
    with h5py.File(out) as f:
        scale = f["data"].attrs["action_scale"]
        peak = 0.0
        for k, record in enumerate(raw.values()):
            actions = _ds(f, f"data/demo_{k}/actions")
            assert np.all(np.abs(actions) <= 1.0)
            peak = max(peak, float(np.abs(actions).max()))
            np.testing.assert_allclose(actions * scale, record.resolved_actions(), atol=1e-12)
        assert peak == pytest.approx(1.0)


def test_rewards_dones_next_obs(synth_export) -> None:
    _, out, expert = synth_export
    with h5py.File(out) as f:
        means = {}
        for name in _demo_names(f):
            attrs = _attrs(f, f"data/{name}")
            n = int(attrs["num_samples"])
            rewards, dones = _ds(f, f"data/{name}/rewards"), _ds(f, f"data/{name}/dones")
            assert rewards.shape == (n,) and np.all(rewards >= 0.0)
            assert dones[-1] == 1 and dones[:-1].sum() == 0
            obs, nxt = (
                _ds(f, f"data/{name}/obs/robot0_eef_pos"),
                _ds(f, f"data/{name}/next_obs/robot0_eef_pos"),
            )
            np.testing.assert_array_equal(nxt[:-1], obs[1:])
            np.testing.assert_array_equal(obs, _ds(f, f"data/{name}/obs/ee_pos"))
            means[attrs["source_demo"]] = float(rewards.mean())
        # The generator's expert-like demo draws the canonical motion: V_E rewards it most.
        assert max(means, key=means.__getitem__) == expert


def test_masks_split_best_and_top_k(synth_export) -> None:
    _, out, _ = synth_export
    with h5py.File(out) as f:
        keys = ["train", "valid", "best", "top_1", "top_3"]
        masks = {k: [n.decode() for n in _ds(f, f"mask/{k}")] for k in keys}
        utility = {n: float(_attrs(f, f"data/{n}")["utility"]) for n in _demo_names(f)}
        env = json.loads(_attrs(f, "data")["env_args"])
    assert env["type"] == GYM_ENV_TYPE and isinstance(env["env_kwargs"], dict)
    assert sorted(masks["train"] + masks["valid"]) == sorted(utility)
    assert not set(masks["train"]) & set(masks["valid"]) and len(masks["valid"]) == 2
    assert masks["best"] == masks["top_1"] == [max(utility, key=utility.__getitem__)]
    top3 = sorted(utility, key=utility.__getitem__)[-3:]
    assert sorted(masks["top_3"]) == sorted(top3)


def test_split_is_seeded(tmp_path) -> None:
    src = write_recording(tmp_path / "w.hdf5", make_demo_set("wiping", n_demos=5).recording)
    first = export_robomimic([src], tmp_path / "a.hdf5", seed=1)[0].masks
    assert export_robomimic([src], tmp_path / "b.hdf5", seed=1)[0].masks == first


def test_quaternion_alias_is_xyzw(tmp_path) -> None:
    src = write_recording(tmp_path / "w.hdf5", full_recording())
    quat = np.array([0.5, 0.5, -0.5, 0.5])  # w, x, y, z
    record = read_recording(src).demos["demo_0"]
    with h5py.File(src, "r+") as f:  # a copy made in this test: give it a real orientation
        stored = f["data/demo_0/obs/ee_quat"]
        assert isinstance(stored, h5py.Dataset)
        stored[...] = np.tile(quat, (record.num_samples, 1))
    [written] = export_robomimic([src], tmp_path / "r.hdf5")
    out = written.path
    with h5py.File(out) as f:
        np.testing.assert_allclose(
            _ds(f, "data/demo_0/obs/robot0_eef_quat")[0], [0.5, -0.5, 0.5, 0.5]
        )
        assert _ds(f, "data/demo_0/obs/robot0_joint_pos").shape == (record.num_samples, 7)


def test_one_task_per_file_and_no_overwrite(tmp_path) -> None:
    a = write_recording(tmp_path / "a.hdf5", make_demo_set("wiping", n_demos=2).recording)
    b = write_recording(tmp_path / "b.hdf5", make_demo_set("weaving", n_demos=2).recording)
    with pytest.raises(ConfigError, match="one task"):
        export_robomimic([a, b], tmp_path / "out.hdf5")
    assert not (tmp_path / "out.hdf5").exists()
    written = export_robomimic([a, b], tmp_path / "per_task")
    assert [w.path.name for w in written] == ["wiping.robomimic.hdf5", "weaving.robomimic.hdf5"]
    export_robomimic([a], tmp_path / "out.hdf5")
    with pytest.raises(ConfigError, match="exists"):
        export_robomimic([a], tmp_path / "out.hdf5")


def test_excluded_files_and_flagged_takes_are_not_exported(tmp_path) -> None:
    from dataclasses import replace

    from bt_pipeline.data.moderation import exclude

    synth = make_demo_set("wiping", n_demos=4, seed=2).recording
    names = list(synth.demos)
    flagged = replace(synth.demos[names[1]], attrs={"flags": "too_short"})
    keep = replace(synth, demos={names[0]: synth.demos[names[0]], names[1]: flagged})
    gone = replace(synth, demos={n: synth.demos[n] for n in names[2:]})
    write_recording(tmp_path / "in" / "keep.hdf5", keep)
    exclude(write_recording(tmp_path / "in" / "gone.hdf5", gone), reason="junk")
    out = export_robomimic([tmp_path / "in"], tmp_path / "wiping.robomimic.hdf5")
    with h5py.File(out[0].path) as file:
        assert len(_demo_names(file)) == 1  # only the unflagged demo of the kept file


def test_a_task_without_a_guide_is_exported_and_imported_back(capsys, tmp_path) -> None:
    from tests.conftest import run
    from tests.pipeline.conftest import write_stirring_file

    src = write_stirring_file(tmp_path / "in", n_demos=4, n_samples=60)
    wiping = write_recording(tmp_path / "in" / "wiping.hdf5", make_demo_set("wiping", 2).recording)
    code, out, err = run(
        capsys, "export", str(src), "--format", "robomimic", "--out", str(tmp_path / "s.hdf5")
    )
    assert code == 0, err
    with h5py.File(out.strip()) as f:
        assert f["data"].attrs["task"] == "stirring"
        assert json.loads(str(f["data"].attrs["env_args"]))["env_kwargs"]["task"] == "stirring"
        assert _demo_names(f) == ["demo_0", "demo_1", "demo_2", "demo_3"]
        assert np.all(np.isfinite(_ds(f, "data/demo_0/rewards")))
    code, out, err = run(
        capsys,
        "export",
        str(src),
        str(wiping),
        "--format",
        "robomimic",
        "--out",
        str(tmp_path / "all"),
    )
    assert code == 0, err
    assert sorted(Path(p).name for p in out.split()) == [
        "stirring.robomimic.hdf5",
        "wiping.robomimic.hdf5",
    ]
    back = tmp_path / "back.hdf5"
    code, _, err = run(
        capsys, "import", str(tmp_path / "all/stirring.robomimic.hdf5"), "--from", "robomimic",
        "--task", "stirring", "--out", str(back),
    )  # fmt: skip
    assert code == 0, err
    recording = read_recording(back)
    original = read_recording(src)
    assert recording.task == "stirring" and len(recording.demos) == 4
    np.testing.assert_allclose(recording.demos["demo_2"].ee_pos, original.demos["demo_2"].ee_pos)
