"""kill -9 fault injection: start a writer, kill it at a chosen moment, check what it left.

The writers are bt's commands and the app's recorder, so the harness sits here, above both
packages (bt_pipeline never imports bt_teleop).

Four writers, each on small data in its own folder (:func:`prepare`):

* ``clean``: ``bt clean IN --out OUT`` over an OUT holding a previous complete run;
* ``synth``: ``bt synth --overwrite`` over an existing file;
* ``evaluate``: ``bt evaluate --plots --rrd --rollouts-out --json-out`` (quick learners) over a
  previous run's outputs: one set across four folders;
* ``take``: the app's recorder saving scripted takes (``bt_teleop.session.script.run_script``);
* ``export_lerobot``: ``bt export --format lerobot --overwrite`` (two tasks) over a previous
  dataset: a directory tree;
* ``export_robomimic``: ``bt export --format robomimic --overwrite`` into a folder (one file per
  task: a set) over a previous export.

After the kill, :func:`check` runs what the next run would run first (the recovery of
:mod:`bt_pipeline.data.output_set`, which removes stale temp files and finishes or undoes a
killed output set) and then asks: is every output complete (readable, its manifest hash
matches) or absent? Does an overwritten file hold its old or its new content, nothing else? Do
the outputs of a set all come from one run (all present, one run id in every manifest)? Is any
temporary file or staging folder left?
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bt_pipeline.data.atomic import recover_dir
from bt_pipeline.data.output_set import MANIFEST, STAGING_PREFIX, recover, verify
from bt_pipeline.data.recording import read_recording, write_recording
from bt_pipeline.data.synth import make_demo_set
from bt_pipeline.exceptions import RecordingError

SCENARIOS = ("clean", "synth", "evaluate", "take", "export_lerobot", "export_robomimic")
"""The writers :func:`run_trial` can kill."""

_TAKE_SCRIPT = """
import sys
import numpy as np
from bt_teleop.session.script import run_script
t = np.linspace(0.0, 1.0, 11)
rows = np.stack([t, 0.08 * np.cos(2 * np.pi * t), 0.04 * np.sin(2 * np.pi * t)], axis=1)
for k in range(1000):
    run_script({"task": "wiping", "demonstrator": f"k{k}", "theta_deg": 0, "rho": 1,
                "waypoints": rows.tolist()}, sys.argv[1])
"""


@dataclass(frozen=True)
class Trial:
    """One kill -9 and what it left."""

    scenario: str
    delay_s: float
    """When the kill was sent after the start [s]."""
    killed: bool
    """False when the writer had finished before the kill."""
    temps_before_recovery: int
    """Temporary files or staging folders the kill left (the next run removes them)."""
    problems: tuple[str, ...]
    """Empty when every output is complete or absent and nothing is left behind."""


def prepare(scenario: str, folder: Path, previous: bool = True) -> list[str]:
    """Make the inputs (and, with `previous`, earlier outputs) of `scenario`; its command line."""
    folder.mkdir(parents=True, exist_ok=True)
    bt = [sys.executable, "-m", "bt_pipeline"]
    if scenario == "take":
        (folder / "takes").mkdir(exist_ok=True)
        return [sys.executable, "-c", _TAKE_SCRIPT, str(folder / "takes")]
    source = folder / "in.hdf5"
    if not source.exists():
        write_recording(source, make_demo_set("wiping", n_demos=3, seed=0).recording)
    if scenario.startswith("export_"):
        other = folder / "in2.hdf5"
        if not other.exists():
            write_recording(other, make_demo_set("weaving", n_demos=3, seed=0).recording)
        kind = scenario.removeprefix("export_")
        out = folder / {"lerobot": "ds", "robomimic": "rm"}[kind]
        command = [*bt, "export", str(source), str(other), "--format", kind, "--out", str(out)]
        command.append("--overwrite")
        if previous and not out.exists():
            subprocess.run(command, check=True, capture_output=True)
        return command
    if scenario == "synth":
        write_recording(
            folder / "s.hdf5", make_demo_set("wiping", 3, seed=0).recording, overwrite=True
        )
        out = str(folder / "s.hdf5")
        return [*bt, "synth", "--out", out, "--demos", "3", "--seed", "1", "--overwrite"]
    if scenario == "clean":
        command = [*bt, "clean", str(source), "--out", str(folder / "out"), "--epochs", "3"]
        if previous and not (folder / "out" / "bt-outputs.json").exists():
            subprocess.run(command, check=True, capture_output=True)
        return command
    if scenario == "evaluate":
        command = [*bt, "evaluate", "--noisy", str(source), "--cleaned", str(source)]
        command += ["--learners", "bc", "--rollouts", "2", "--steps", "5", "--quick"]
        command += ["--rollouts-out", str(folder / "rollouts"), "--plots", str(folder / "plots")]
        command += ["--rrd", str(folder / "viz" / "eval.rrd")]
        command += ["--json-out", str(folder / "table.json")]
        if previous and not (folder / "rollouts").exists():
            subprocess.run(command, check=True, capture_output=True)
        return command
    raise ValueError(f"unknown scenario {scenario!r}; valid: {', '.join(SCENARIOS)}")


def run_trial(
    scenario: str, folder: Path, delay_s: float, repo: Path | None = None, previous: bool = True
) -> Trial:
    """Start `scenario`'s writer, SIGKILL its process group after `delay_s` [s], check."""
    command = prepare(scenario, folder, previous)
    old = snapshot(folder / "s.hdf5") if scenario == "synth" else None
    had_dataset = (folder / "ds").is_dir()
    env = {**os.environ, "PYTHONPATH": str(repo)} if repo is not None else None
    process = subprocess.Popen(
        command,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # its own process group: workers die with it
        env=env,
    )
    time.sleep(delay_s)
    killed = process.poll() is None
    if killed:
        os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    left = len(_leftovers(folder))
    problems = check(scenario, folder, old, previous_dataset=had_dataset)
    return Trial(scenario, delay_s, killed, left, problems)


def check(
    scenario: str,
    folder: Path,
    old: tuple[np.ndarray, ...] | None = None,
    previous_dataset: bool = False,
) -> tuple[str, ...]:
    """Recover `folder` as the next run would, then list what is wrong with its outputs
    (`old`: the synth file's content before; `previous_dataset`: a LeRobot export existed)."""
    problems: list[str] = []
    outputs = {
        "clean": folder / "out",
        "synth": folder,
        "evaluate": folder / "rollouts",
        "take": folder / "takes" / "wiping",
        "export_lerobot": folder,
        "export_robomimic": folder / "rm",
    }[scenario]
    if outputs.is_dir():
        recover(outputs)
    if scenario == "evaluate":
        problems += _check_set(folder, EVALUATE_OUTPUTS)
    if scenario == "export_lerobot":
        recover_dir(folder / "ds")
        if (folder / "ds").exists():
            problems += _check_lerobot(folder / "ds")
        elif previous_dataset:
            problems.append("the previous lerobot dataset is gone")
    if scenario == "export_robomimic":
        problems += _check_set(folder, ROBOMIMIC_OUTPUTS)
        problems += [p for name in ROBOMIMIC_OUTPUTS for p in _check_robomimic(folder / name)]
    hdf5 = (
        sorted(outputs.glob("*.hdf5"))
        if outputs.is_dir() and scenario != "export_robomimic"
        else []
    )
    for path in hdf5:
        try:
            read_recording(path)
        except RecordingError as exc:
            problems.append(f"incomplete output: {exc}")
    if scenario == "clean":
        problems += [f"{name} does not match the manifest" for name in verify(outputs)]
        for rrd in outputs.glob("*.rrd"):
            if rrd.stat().st_size == 0:
                problems.append(f"empty {rrd.name}")
    if scenario == "synth" and old is not None:
        now = snapshot(folder / "s.hdf5")
        new = _snapshot_of(make_demo_set("wiping", 3, seed=1).recording.demos)
        if now is None or not (_same(now, old) or _same(now, new)):
            problems.append("s.hdf5 holds neither its old nor its new content")
    problems += [f"left behind: {p.name}" for p in _leftovers(folder)]
    return tuple(problems)


EVALUATE_OUTPUTS = (
    "plots/rewards.png",
    "plots/wiping.rollouts.png",
    "viz/eval.rrd",
    "table.json",
    "rollouts/wiping.bc.noisy.rollouts.hdf5",
    "rollouts/wiping.bc.cleaned.rollouts.hdf5",
)
"""The outputs of the evaluate scenario, relative to its folder: one set."""


def _check_set(folder: Path, names: tuple[str, ...]) -> list[str]:
    """Recover every folder of a set, then: all of `names` present or none, each matching its
    folder's manifest, and every one written by the same run."""
    folders = sorted({(folder / name).parent for name in names})
    for out in folders:
        if out.is_dir():
            recover(out)
    present = [name for name in names if (folder / name).is_file()]
    if not present:
        return []
    problems = []
    if len(present) != len(names):
        problems.append(f"only part of the set: {sorted(set(names) - set(present))} missing")
    runs: set[object] = set()
    for name in present:
        path = folder / name
        entry = _manifest(path.parent).get(path.name)
        if entry is None:
            problems.append(f"{name} is not in its folder's manifest")
        else:
            runs.add(entry.get("run"))
    for out in folders:
        problems += [f"{out.name}/{bad} does not match the manifest" for bad in verify(out)]
    if len(runs) != 1:
        problems.append(f"the set mixes runs: {sorted(map(str, runs))}")
    return problems


def _manifest(out: Path) -> dict[str, dict]:
    try:
        return json.loads((out / MANIFEST).read_text(encoding="utf-8"))["files"]
    except (OSError, ValueError, KeyError):
        return {}


ROBOMIMIC_OUTPUTS = ("rm/wiping.robomimic.hdf5", "rm/weaving.robomimic.hdf5")
"""The outputs of the export_robomimic scenario, relative to its folder: one set."""


def _check_lerobot(root: Path) -> list[str]:
    """A LeRobot v3.0 dataset is complete: its info, stats and tasks exist, and its data and
    episode tables (read with pyarrow) hold the frames and episodes info.json counts."""
    import pyarrow.parquet as pq

    try:
        info = json.loads((root / "meta" / "info.json").read_text(encoding="utf-8"))
        frames = sum(pq.read_table(p).num_rows for p in (root / "data").glob("*/*.parquet"))
        episodes = sum(
            pq.read_table(p).num_rows for p in (root / "meta" / "episodes").glob("*/*.parquet")
        )
        for name in ("stats.json", "tasks.parquet"):
            if not (root / "meta" / name).is_file():
                return [f"lerobot dataset without meta/{name}"]
    except (OSError, ValueError) as exc:
        return [f"incomplete lerobot dataset: {exc}"]
    if frames != info.get("total_frames") or episodes != info.get("total_episodes"):
        return [
            f"lerobot dataset holds {frames} frames / {episodes} episodes; info says "
            f"{info.get('total_frames')} / {info.get('total_episodes')}"
        ]
    return []


def _check_robomimic(path: Path) -> list[str]:
    """A robomimic file, when present, opens and holds the demos its ``total`` counts."""
    import h5py

    if not path.exists():
        return []
    try:
        with h5py.File(path, "r") as file:
            data = file["data"]
            assert isinstance(data, h5py.Group)
            total = sum(int(np.asarray(data[name].attrs["num_samples"])) for name in data)
            if total != int(np.asarray(data.attrs["total"])):
                return [f"{path.name}: {total} samples, total says {data.attrs['total']}"]
    except (OSError, KeyError) as exc:
        return [f"incomplete output: {path.name}: {exc}"]
    return []


def _leftovers(folder: Path) -> list[Path]:
    return [
        p
        for p in folder.rglob(".*")
        if ".tmp" in p.name or ".old-" in p.name or p.name.startswith(STAGING_PREFIX)
    ]


def snapshot(path: Path) -> tuple[np.ndarray, ...] | None:
    """The positions of every demo of the recording at `path`, or None when it is unreadable."""
    try:
        return _snapshot_of(read_recording(path).demos)
    except RecordingError:
        return None


def _snapshot_of(demos: dict) -> tuple[np.ndarray, ...]:
    return tuple(np.asarray(demos[name].ee_pos) for name in sorted(demos))


def _same(a: tuple[np.ndarray, ...], b: tuple[np.ndarray, ...] | None) -> bool:
    return (
        b is not None
        and len(a) == len(b)
        and all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    )
