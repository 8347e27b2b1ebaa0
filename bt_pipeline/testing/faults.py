"""kill -9 fault injection: start a writer, kill it at a chosen moment, check what it left.

Four writers, each on small data in its own folder (:func:`prepare`):

* ``clean``: ``bt clean IN --out OUT`` over an OUT holding a previous complete run;
* ``synth``: ``bt synth --overwrite`` over an existing file;
* ``evaluate``: ``bt evaluate --plots --rrd --rollouts-out --json-out`` (quick learners) over a
  previous run's outputs: one set across four folders;
* ``take``: the app's recorder saving scripted takes (``bt_teleop.script.run_script``).

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

from bt_pipeline.data.output_set import MANIFEST, STAGING_PREFIX, recover, verify
from bt_pipeline.data.recording import read_recording, write_recording
from bt_pipeline.data.synth import make_demo_set
from bt_pipeline.exceptions import RecordingError

SCENARIOS = ("clean", "synth", "evaluate", "take")
"""The writers :func:`run_trial` can kill."""

_TAKE_SCRIPT = """
import sys
import numpy as np
from bt_teleop.script import run_script
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
    return Trial(scenario, delay_s, killed, left, check(scenario, folder, old))


def check(
    scenario: str, folder: Path, old: tuple[np.ndarray, ...] | None = None
) -> tuple[str, ...]:
    """Recover `folder` as the next run would, then list what is wrong with its outputs."""
    problems: list[str] = []
    outputs = {
        "clean": folder / "out",
        "synth": folder,
        "evaluate": folder / "rollouts",
        "take": folder / "takes" / "wiping",
    }[scenario]
    if outputs.is_dir():
        recover(outputs)
    if scenario == "evaluate":
        problems += _check_set(folder, EVALUATE_OUTPUTS)
    for path in sorted(outputs.glob("*.hdf5")) if outputs.is_dir() else []:
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


def _leftovers(folder: Path) -> list[Path]:
    return [p for p in folder.rglob(".*") if ".tmp" in p.name or p.name.startswith(STAGING_PREFIX)]


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
