"""Seeded mutations of valid recordings, and the check every mutation must pass.

A mutation copies a valid format-v1 file and breaks one thing in it: an attr (deleted, retyped,
absurd), a dataset (dtype, shape, values), the demo names, or the bytes themselves (truncation,
random overwrites). :func:`check_command` then runs a ``bt`` command on the copy and reports
what went wrong, if anything. Every mutation must give exit 0 or 2, with exactly one
``bt: error:`` line on stderr when 2, no traceback, no hang (a time limit) and an unchanged input
(sha256).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

Mutation = Callable[[Path, np.random.Generator], str]
"""Breaks the file in place; returns a description of what it did."""


def _demo(file: h5py.File, rng: np.random.Generator) -> str:
    names = sorted(file["data"].keys())  # type: ignore[union-attr]
    return f"data/{names[int(rng.integers(len(names)))]}"


def _mutate_attr(path: Path, rng: np.random.Generator) -> str:
    values: list[object] = [
        np.nan, np.inf, -1e308, 1e-300, 1e300, 0, -1, "x", b"\xff\xfe", np.bytes_(b"a\x00b"),
        np.arange(5.0), True, "", "9" * 5000, 2**62,
    ]  # fmt: skip
    with h5py.File(path, "r+") as file:
        target = "data" if rng.random() < 0.3 else _demo(file, rng)
        attrs = file[target].attrs
        keys = sorted(attrs.keys())
        key = keys[int(rng.integers(len(keys)))]
        if rng.random() < 0.2:
            del attrs[key]
            return f"{target}: deleted attr {key}"
        value = values[int(rng.integers(len(values)))]
        attrs[key] = value  # type: ignore[assignment]
        return f"{target}: attr {key} = {str(value)[:30]!r}"


def _mutate_dataset(path: Path, rng: np.random.Generator) -> str:
    with h5py.File(path, "r+") as file:
        group = file[_demo(file, rng)]
        assert isinstance(group, h5py.Group)
        key = ["obs/ee_pos", "timestamps", "actions"][int(rng.integers(3))]
        data = np.asarray(group[key][()])  # type: ignore[index]
        kind = int(rng.integers(8))
        if kind == 0:
            new: np.ndarray = data.astype(["i4", "f2", "c16", "S8", "u1"][int(rng.integers(5))])
        elif kind == 1:
            new = data.T.copy() if data.ndim == 2 else data[:, None]
        elif kind == 2:
            new = data[: int(rng.integers(0, 3))]
        elif kind == 3:
            new = data[:, :-1] if data.ndim == 2 else data[:-1]
        else:
            new = data.astype(np.float64).copy()
            idx = tuple(int(rng.integers(s)) for s in new.shape)
            new[idx] = [np.nan, np.inf, 1e30, -1e200, 1e-320][int(rng.integers(5))]
            if key == "timestamps" and kind == 7:
                new = new[::-1].copy()
        del group[key]
        group.create_dataset(key, data=new)
        return f"{group.name}/{key}: {data.shape} {data.dtype} -> {new.shape} {new.dtype}"


def _mutate_names(path: Path, rng: np.random.Generator) -> str:
    names = ["demo_-1", "demo_" + "9" * 5000, "demo_01", "x", "demo_1e3", "demo_\u0663", "demo_"]
    with h5py.File(path, "r+") as file:
        source = _demo(file, rng)
        name = names[int(rng.integers(len(names)))]
        if rng.random() < 0.3:
            del file[source]
            return f"deleted {source}"
        if f"data/{name}" in file:
            del file[f"data/{name}"]
        file.move(source, f"data/{name}")
        return f"renamed {source} to {name[:20]}"


def _truncate(path: Path, rng: np.random.Generator) -> str:
    size = path.stat().st_size
    keep = int(rng.integers(0, size))
    with open(path, "r+b") as file:
        file.truncate(keep)
    return f"truncated to {keep} of {size} bytes"


def _random_bytes(path: Path, rng: np.random.Generator) -> str:
    size = path.stat().st_size
    n = int(rng.integers(1, 64))
    with open(path, "r+b") as file:
        for _ in range(n):
            file.seek(int(rng.integers(0, size)))
            file.write(bytes(rng.integers(0, 256, int(rng.integers(1, 16))).astype(np.uint8)))
    return f"overwrote {n} random byte runs"


MUTATIONS: dict[str, Mutation] = {
    "attr": _mutate_attr,
    "dataset": _mutate_dataset,
    "names": _mutate_names,
    "truncate": _truncate,
    "bytes": _random_bytes,
}
"""Every kind of mutation, by name."""


def mutate(valid: Path, out: Path, seed: int) -> tuple[str, str]:
    """Copy `valid` to `out` and apply mutation number `seed`; return (kind, description)."""
    rng = np.random.default_rng(seed)
    kind = sorted(MUTATIONS)[seed % len(MUTATIONS)]
    shutil.copyfile(valid, out)
    try:
        return kind, MUTATIONS[kind](out, rng)
    except (OSError, KeyError, ValueError, TypeError) as exc:  # h5py refused the mutation itself
        return kind, f"(mutation not applied: {type(exc).__name__})"


@dataclass(frozen=True)
class FuzzResult:
    """One command on one mutated file."""

    seed: int
    kind: str
    description: str
    command: str
    exit_code: int | None
    """None when the command was stopped at its time limit."""
    problems: tuple[str, ...]
    """Empty when the command behaved: exit 0 or 2, one error line, input unchanged."""


def sha256(path: Path) -> str:
    """Hex sha256 of a file."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def check_command(
    argv: Sequence[str], path: Path, timeout_s: float, repo: Path | None = None
) -> tuple[int | None, tuple[str, ...]]:
    """Run ``python -m bt_pipeline argv`` on a mutated `path`; the exit code and any problems."""
    before = sha256(path)
    env = {**os.environ, "PYTHONPATH": str(repo)} if repo is not None else None
    try:
        done = subprocess.run(
            [sys.executable, "-m", "bt_pipeline", *argv],
            capture_output=True,
            text=True,
            timeout=timeout_s,
            env=env,
        )
    except subprocess.TimeoutExpired:
        return None, (f"no answer within {timeout_s:g} s",)
    return done.returncode, judge(done.returncode, done.stderr, before, path)


def judge(code: int | None, stderr: str, before: str, path: Path) -> tuple[str, ...]:
    """The problems of one run: its exit code, its stderr and whether `path` changed."""
    problems = []
    if code not in (0, 2):
        problems.append(f"exit {code}")
    if "Traceback" in stderr:
        problems.append("traceback: " + stderr.strip().splitlines()[-1][:200])
    errors = [line for line in stderr.splitlines() if line.startswith("bt: error:")]
    if code == 2 and len(errors) != 1:
        problems.append(f"{len(errors)} error lines")
    if sha256(path) != before:
        problems.append("the input changed")
    return tuple(problems)


def check_in_process(
    argv: Sequence[str], path: Path, timeout_s: float
) -> tuple[int | None, tuple[str, ...]]:
    """:func:`check_command` inside this process (fast; POSIX: the time limit is SIGALRM)."""
    import contextlib
    import io
    import signal
    import traceback

    from bt_pipeline.cli import main

    def expire(_signum: int, _frame: object) -> None:
        raise TimeoutError

    before, stderr, code = sha256(path), io.StringIO(), 0
    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, timeout_s)
    try:
        with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
            main(list(argv))
    except SystemExit as exit_:
        code = int(exit_.code or 0)
    except TimeoutError:
        return None, (f"no answer within {timeout_s:g} s",)
    except Exception:
        return 1, ("traceback: " + traceback.format_exc().strip().splitlines()[-1][:200],)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)
    return code, judge(code, stderr.getvalue(), before, path)


def write_valid(path: Path, seed: int = 0) -> Path:
    """A valid recording to mutate: a synthetic 3-demo wiping set with optional attrs."""
    import dataclasses

    from bt_pipeline.data.recording import write_recording
    from bt_pipeline.data.synth import make_demo_set

    recording = make_demo_set("wiping", n_demos=3, seed=seed).recording
    demos = {
        name: dataclasses.replace(
            demo, created="2026-01-01T10:00:00+00:00", ep_meta={"k": [1, 2]}, attrs={"n": 1}
        )
        for name, demo in recording.demos.items()
    }
    return write_recording(path, dataclasses.replace(recording, demos=demos), overwrite=True)
