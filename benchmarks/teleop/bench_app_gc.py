"""A full garbage collection of the app's process, before and after ``freeze_startup_objects``.

`bt teleop` (:func:`bt_teleop.app.serve`) freezes what the app loaded at start. This starts an
app (Rerun off, no tab), times ``gc.collect()`` (all generations) ``--repeats`` times, freezes,
and times it again; it prints the medians and their ratio, and the objects the collector walks::

    python benchmarks/teleop/bench_app_gc.py --repeats 7
"""

from __future__ import annotations

import argparse
import gc
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repo root: benchmarks.common

from benchmarks.common.timing import median_s
from bt_teleop.app import freeze_startup_objects
from bt_teleop.testing.harness import app_factory


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp, app_factory(Path(tmp)) as make:
        make()
        walked = len(gc.get_objects())
        before = 1e3 * median_s(gc.collect, args.repeats)
        freeze_startup_objects()
        after = 1e3 * median_s(gc.collect, args.repeats)
        print(f"objects the collector walks: {walked:,} before, {len(gc.get_objects()):,} after")
        print(
            f"full collection, median of {args.repeats}: {before:.1f} ms before, "
            f"{after:.2f} ms after ({after / before:.3f}x)"
        )


if __name__ == "__main__":
    main()
