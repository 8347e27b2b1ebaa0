"""bt export --format lerobot: a LeRobotDataset v3.0 read back with Rerun's reader and pyarrow."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from rerun.experimental import LeRobotReader

from bt_pipeline.data.recording import read_recording, write_recording
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.interop import lerobot_stats
from bt_pipeline.interop.export_lerobot import export_lerobot, parse_task_texts
from tests.pipeline.interop.conftest import full_recording

FPS = 30


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    tmp = tmp_path_factory.mktemp("lerobot")
    src = write_recording(tmp / "wiping.hdf5", full_recording())
    root = export_lerobot([src], tmp / "ds", fps=FPS).root
    return src, root


def _frames(root: Path) -> dict:
    return pq.read_table(root / "data/chunk-000/file-000.parquet").to_pydict()


def test_rerun_lerobot_reader_reads_every_episode(exported: tuple[Path, Path]) -> None:
    _, root = exported
    reader = LeRobotReader(root)
    assert reader.version == "v3"
    assert reader.episodes() == [0, 1, 2]
    entities = {chunk.entity_path for chunk in reader.stream(2)}
    assert {"/observation.state", "/action", "/observation.environment_state"} <= entities


def test_positions_are_the_recording_resampled_to_fps(exported: tuple[Path, Path]) -> None:
    src, root = exported
    frames = _frames(root)
    episodes = np.asarray(frames["episode_index"])
    state = np.asarray(frames["observation.state"], dtype=np.float64)
    for k, record in enumerate(read_recording(src).demos.values()):
        rows = episodes == k
        t = np.asarray(frames["timestamp"], dtype=np.float64)[rows]
        np.testing.assert_allclose(t, np.arange(rows.sum()) / FPS, atol=1e-6)
        t_raw = record.timestamps - record.timestamps[0]
        assert t[-1] <= t_raw[-1] < t[-1] + 1 / FPS
        truth = np.stack([np.interp(t, t_raw, record.ee_pos[:, j]) for j in range(3)], axis=1)
        np.testing.assert_allclose(state[rows, :3], truth, atol=1e-6)
        # Joints follow the quaternion (3 + 4 columns) when the recording has them.
        joints = np.stack([np.interp(t, t_raw, record.joint_pos[:, j]) for j in range(7)], axis=1)  # type: ignore[index]
        np.testing.assert_allclose(state[rows, 7:14], joints, atol=1e-5)


def test_info_tasks_and_episodes_follow_lerobot_v3(exported: tuple[Path, Path]) -> None:
    _, root = exported
    info = json.loads((root / "meta/info.json").read_text())
    frames = _frames(root)
    assert info["codebase_version"] == "v3.0"
    assert info["total_frames"] == len(frames["index"]) and info["total_episodes"] == 3
    assert info["features"]["observation.state"]["shape"] == [15]
    assert info["features"]["observation.environment_state"]["shape"] == [2]
    assert frames["index"] == list(range(len(frames["index"])))
    tasks = pq.read_table(root / "meta/tasks.parquet").to_pydict()
    assert tasks["task_index"] == [0] and "Wipe" in tasks["task"][0]
    episodes = pq.read_table(root / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [e["dataset_from_index"] for e in episodes] == [0] + [
        e["dataset_to_index"] for e in episodes[:-1]
    ]
    assert math.isnan(episodes[1]["bt/theta_deg"]) and episodes[2]["bt/theta_deg"] == 40.0
    assert sum(e["bt/best"] for e in episodes) == 1
    assert all(0.0 <= e["bt/utility"] <= 1.0 for e in episodes)


def test_stats_match_numpy_over_all_frames(exported: tuple[Path, Path]) -> None:
    _, root = exported
    stats = json.loads((root / "meta/stats.json").read_text())
    state = np.asarray(_frames(root)["observation.state"], dtype=np.float32)
    np.testing.assert_allclose(stats["observation.state"]["mean"], state.mean(axis=0), atol=1e-5)
    np.testing.assert_allclose(stats["observation.state"]["std"], state.std(axis=0), atol=1e-4)
    np.testing.assert_allclose(stats["observation.state"]["min"], state.min(axis=0))
    assert stats["observation.state"]["count"] == [len(state)]


def test_histogram_quantiles_are_within_one_bin_of_numpy() -> None:
    values = np.random.default_rng(3).normal(size=(4000, 2)).astype(np.float32)
    stats = lerobot_stats.feature_stats(values)
    width = (values.max(axis=0) - values.min(axis=0)) / lerobot_stats.QUANTILE_BINS
    for q in lerobot_stats.QUANTILES:
        expected = np.quantile(values, q, axis=0, method="inverted_cdf")
        assert np.all(np.abs(stats[lerobot_stats.quantile_key(q)] - expected) <= 2 * width + 1e-6)


def test_existing_output_is_refused_and_nothing_half_written(exported, tmp_path) -> None:
    src, root = exported
    with pytest.raises(ConfigError, match="exists"):
        export_lerobot([src], root)
    assert not [p for p in root.parent.iterdir() if p.name.startswith(".ds.tmp")]


def test_task_texts() -> None:
    assert parse_task_texts(["Clean it"], ["wiping"]) == {"wiping": "Clean it"}
    texts = parse_task_texts(["weaving=Weave"], ["wiping", "weaving"])
    assert texts["weaving"] == "Weave" and texts["wiping"]
    with pytest.raises(ConfigError, match="TASK=TEXT"):
        parse_task_texts(["Clean it"], ["wiping", "weaving"])


def test_a_task_without_a_guide_is_exported_with_a_sentence_of_its_name(capsys, tmp_path) -> None:
    from tests.conftest import run
    from tests.pipeline.conftest import STIRRING_PLANE

    src = write_recording(tmp_path / "stirring.hdf5", full_recording("stirring", STIRRING_PLANE))
    code, out, err = run(
        capsys, "export", str(src), "--format", "lerobot", "--out", str(tmp_path / "ds")
    )
    assert code == 0, err
    root = Path(out.strip())
    tasks = pq.read_table(root / "meta/tasks.parquet").to_pydict()
    assert tasks["task"] == ["Perform stirring in repeated loops."]
    episodes = pq.read_table(root / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [e["bt/task"] for e in episodes] == ["stirring"] * 3
    env = np.asarray(_frames(root)["observation.environment_state"], dtype=np.float64)
    assert np.abs(env).max() < 0.2  # the file's own plane: circles of radius 0.08-0.096 m
    assert LeRobotReader(root).episodes() == [0, 1, 2]
    code, _, err = run(
        capsys, "export", str(src), "--format", "lerobot", "--out", str(tmp_path / "ds2"),
        "--task-text", "stirring=Stir the pot clockwise.",
    )  # fmt: skip
    assert code == 0, err
    tasks = pq.read_table(tmp_path / "ds2/meta/tasks.parquet").to_pydict()
    assert tasks["task"] == ["Stir the pot clockwise."]


def test_task_texts_of_tasks_without_a_guide() -> None:
    assert parse_task_texts([], ["scrub-d_shape"]) == {
        "scrub-d_shape": "Perform scrub d shape in repeated loops."
    }
    texts = parse_task_texts(["Stir the pot: speed=slow"], ["stirring"])
    assert texts == {"stirring": "Stir the pot: speed=slow"}
    with pytest.raises(
        ConfigError, match=r"TASK=TEXT with TASK one of the exported tasks \(stirring\)"
    ):
        parse_task_texts(["buff-it=Buff"], ["stirring"])
