"""A full garbage collection of the app's process, before and after ``freeze_startup_objects``.

`bt teleop` (:func:`bt_teleop.app.serve`) freezes what the app loaded at start. This starts an
app (Rerun off, no tab), times ``gc.collect()`` (all generations) ``--repeats`` times, freezes,
and times it again; it prints the medians and their ratio, and the objects the collector walks::

    python benchmarks/bench_app_gc.py --repeats 7
"""

from __future__ import annotations

import argparse
import gc
import statistics
import tempfile
import time
from pathlib import Path

from bt_teleop.app import freeze_startup_objects
from bt_teleop.testing import app_factory


def full_collections_ms(repeats: int) -> float:
    """Median time of a full collection [ms]."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        gc.collect()
        times.append(1e3 * (time.perf_counter() - start))
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp, app_factory(Path(tmp)) as make:
        make()
        walked = len(gc.get_objects())
        before = full_collections_ms(args.repeats)
        freeze_startup_objects()
        after = full_collections_ms(args.repeats)
        print(f"objects the collector walks: {walked:,} before, {len(gc.get_objects()):,} after")
        print(
            f"full collection, median of {args.repeats}: {before:.1f} ms before, "
            f"{after:.2f} ms after ({after / before:.3f}x)"
        )


if __name__ == "__main__":
    main()
