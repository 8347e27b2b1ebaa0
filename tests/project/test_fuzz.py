"""Fuzzing (bt_pipeline.testing.fuzz): seeded mutations of a valid recording through bt score and
bt clean. Each must exit 0 or 2 with one error line, no traceback, no hang, input unchanged. The
full suite (≥ 500 mutations) is benchmarks/faults/bench_fuzz.py."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest

from bt_pipeline.testing.fuzz import check_command, check_in_process, mutate, write_valid

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def valid(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_valid(tmp_path_factory.mktemp("fuzz") / "valid.hdf5")


def test_fifty_mutations_through_bt_score(valid, tmp_path) -> None:
    kinds: Counter[tuple[str, int | None]] = Counter()
    failures = []
    for seed in range(50):
        path = tmp_path / f"m{seed}.hdf5"
        kind, description = mutate(valid, path, seed)
        code, problems = check_in_process(["score", "--strict", str(path)], path, 60.0)
        kinds[(kind, code)] += 1
        if problems:
            failures.append(f"seed {seed} ({kind}: {description}): {problems}")
    assert not failures, "\n".join(failures)
    assert {kind for kind, _ in kinds} == {"attr", "bytes", "dataset", "names", "truncate"}
    assert kinds.total() == 50 and any(code == 2 for _, code in kinds)  # mutations do bite


def test_mutations_through_bt_clean(valid, tmp_path) -> None:
    failures = []
    for seed in range(100, 106):
        path = tmp_path / f"m{seed}.hdf5"
        kind, description = mutate(valid, path, seed)
        argv = ["clean", "--strict", "--epochs", "1", "--no-rrd", str(path), "--out"]
        code, problems = check_in_process([*argv, str(tmp_path / f"out{seed}")], path, 120.0)
        if problems:
            failures.append(f"seed {seed} ({kind}: {description}): exit {code}, {problems}")
    assert not failures, "\n".join(failures)


@pytest.mark.parametrize("seed", [3, 7, 11])
def test_mutations_through_the_real_command_line(valid, tmp_path, seed) -> None:
    path = tmp_path / "m.hdf5"
    mutate(valid, path, seed)
    code, problems = check_command(["score", "--strict", str(path)], path, 120.0, repo=REPO)
    assert not problems and code in (0, 2)


def test_the_judge_catches_what_it_must(valid, tmp_path) -> None:
    from bt_pipeline.testing.fuzz import judge, sha256

    before = sha256(valid)
    assert judge(2, "bt: error: x\n", before, valid) == ()
    assert judge(1, "Traceback (most recent call last):\nValueError: y\n", before, valid)
    assert judge(2, "bt: error: a\nbt: error: b\n", before, valid) == ("2 error lines",)
    assert judge(0, "", "0" * 64, valid) == ("the input changed",)
