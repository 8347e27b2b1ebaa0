"""A process's memory as ``/proc`` gives it."""

from __future__ import annotations

KIB = 1024.0
"""Bytes in a KiB (``/proc`` reports kB meaning KiB)."""


def smaps_rollup(pid: int) -> dict[str, float]:
    """``/proc/<pid>/smaps_rollup`` [bytes] by field (Rss, Pss, Pss_Anon, ...)."""
    out: dict[str, float] = {}
    with open(f"/proc/{pid}/smaps_rollup") as lines:
        for line in lines:
            parts = line.split()
            if len(parts) == 3 and parts[0].endswith(":") and parts[2] == "kB":
                out[parts[0][:-1]] = KIB * int(parts[1])
    return out
