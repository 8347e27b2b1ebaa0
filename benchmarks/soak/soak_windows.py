"""Means of a soak's memory over fixed windows, from ``bench_soak.py --memory-log`` files.

A least-squares slope over a few minutes is at the mercy of one clean job; the means of the app
process's memory over each window (3 minutes by default), and the change per minute from the
second window to the last, compare two runs started side by side (an A/B pair) more fairly.
The sample taken after a run ended is left out. Per log: the 1-minute load average, the app's
RSS, its C heap in use and free but kept (``mallinfo2``), Python's arenas, the session
children's USS (summed), and the kept anon PSS (heap and anon PSS of the processes that stay).

    .venv/bin/python benchmarks/soak/soak_windows.py --minutes 3 A.jsonl B.jsonl
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

KINDS = ("app", "forkserver", "session", "reader", "other")
"""The process kinds that stay (clean jobs come and go)."""
COLUMNS = (
    "load",
    "app RSS",
    "app C heap in use",
    "app C heap free",
    "app Python arenas",
    "sessions' USS",
    "kept anon PSS",
)


def samples(path: Path) -> np.ndarray:
    """(t [s], then :data:`COLUMNS`) per sample, without the one after the run ended."""
    rows = []
    for line in path.read_text().splitlines():
        d = json.loads(line)
        app = d["app"]
        kept = sum(d[k]["pss_heap"] + d[k]["pss_anon"] for k in KINDS if k in d)
        rows.append(
            (
                d["t"],
                d["load"],
                app["rss"],
                app["heap_in_use"],
                app["heap_free"],
                app["py_arenas"],
                d["session"]["uss"],
                kept,
            )
        )
    table = np.array(rows)
    return table[:-1] if len(table) > 2 else table


def report(path: Path, window_s: float) -> None:
    """Print each column's window means and the change from the second window to the last."""
    table = samples(path)
    index = (table[:, 0] // window_s).astype(int)
    windows = sorted(set(index))
    print(f"{path}: {len(table)} samples over {table[-1, 0] / 60:.1f} min")
    for j, name in enumerate(COLUMNS, start=1):
        means = [table[index == w, j].mean() for w in windows]
        change = (
            (means[-1] - means[1]) / ((windows[-1] - windows[1]) * window_s / 60)
            if len(means) > 2
            else float("nan")
        )
        cells = " ".join(f"{m:7.1f}" for m in means)
        print(f"  {name:18s} {cells} | second window to last: {change:+.2f} /min")


def main() -> None:
    """Report every log given."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("logs", type=Path, nargs="+")
    parser.add_argument("--minutes", type=float, default=3.0, help="window [min]")
    args = parser.parse_args()
    for path in args.logs:
        report(path, 60.0 * args.minutes)


if __name__ == "__main__":
    main()
