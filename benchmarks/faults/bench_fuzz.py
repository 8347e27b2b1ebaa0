"""Fuzz suite: ≥ 500 seeded mutations of a valid recording through ``bt score`` and ``bt clean``.

Every mutation must give exit 0 or 2, exactly one ``bt: error:`` line when 2, no traceback, no
hang (each run has a time limit) and an unchanged input (sha256). ``bt score --strict`` runs on
every mutation in this process (fast); ``bt clean --strict`` on every k-th round of the
mutation kinds (so on each kind); ``bt score`` also through the real command line
(subprocesses) for the first few. Prints counts per mutation kind and exit code, and every
failure.

    nice -n 10 .venv/bin/python benchmarks/faults/bench_fuzz.py --mutations 500 --clean-every 10 \
        --cli 30
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repo root: benchmarks.common

from benchmarks.common.paths import REPO
from bt_pipeline.testing.fuzz import (
    MUTATIONS,
    check_command,
    check_in_process,
    mutate,
    write_valid,
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--mutations", type=int, default=500)
    parser.add_argument("--clean-every", type=int, default=10, help="bt clean on every k-th")
    parser.add_argument("--cli", type=int, default=30, help="mutations also run as subprocesses")
    parser.add_argument("--timeout", type=float, default=120.0, help="time limit per run [s]")
    args = parser.parse_args()
    start = time.perf_counter()
    counts: Counter[tuple[str, str, int | None]] = Counter()
    failures: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        valid = write_valid(folder / "valid.hdf5")
        for seed in range(args.mutations):
            path = folder / f"m{seed}.hdf5"
            kind, description = mutate(valid, path, seed)
            runs: list[tuple[str, list[str], bool]] = [
                ("score", ["score", "--strict", str(path)], False)
            ]
            if (seed // len(MUTATIONS)) % args.clean_every == 0:  # every kind in turn
                out = str(folder / f"out{seed}")
                clean = ["clean", "--strict", "--epochs", "1", "--no-rrd", str(path), "--out", out]
                runs.append(("clean", clean, False))
            if seed < args.cli:
                runs.append(("score-cli", ["score", "--strict", str(path)], True))
            for name, argv, subprocess in runs:
                if subprocess:
                    code, problems = check_command(argv, path, args.timeout, repo=REPO)
                else:
                    code, problems = check_in_process(argv, path, args.timeout)
                counts[(name, kind, code)] += 1
                if problems:
                    failures.append(f"{name} seed {seed} ({kind}: {description}): {problems}")
            path.unlink()
    total = sum(counts.values())
    print(f"{args.mutations} mutations, {total} runs in {time.perf_counter() - start:.0f} s")
    print("| command | mutation | exit 0 | exit 2 | other |")
    print("|---|---|---|---|---|")
    for name in ("score", "clean", "score-cli"):
        for kind in sorted({k for n, k, _ in counts if n == name}):
            zero, two = counts[(name, kind, 0)], counts[(name, kind, 2)]
            other = (
                sum(v for (n, k, c), v in counts.items() if n == name and k == kind) - zero - two
            )
            print(f"| {name} | {kind} | {zero} | {two} | {other} |")
    print(f"failures: {len(failures)} of {total} runs")
    for line in failures:
        print("  " + line)


if __name__ == "__main__":
    main()
