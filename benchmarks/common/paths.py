"""Where the benchmarks find the repo and the data shared beside it."""

from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
"""The repo's root (the folder holding ``benchmarks/``)."""

SHARED = REPO.parent / "shared"
"""The shared folder beside the checkout (browser takes, foreign loops), when present."""
