"""What reading one recording of many demos leaves in a process's memory (a high-water mark).

The app read a task's cleaned file (every usable demo of the task, with its samples) after each
Clean to list it (``bt_teleop.library.reading.read_file_tracks(path, "cleaned")``), on its reader
thread. This benchmark writes recordings of N demos (synthetic wiping demos, in a child process so
the writing leaves nothing here), then reads them on a thread, as the app does, and prints after
each read the process's RSS and glibc's heap (``mallinfo2``: in use, free but kept), after a
garbage collection and a ``malloc_trim`` (what the app's heap trimmer does every minute):

* ``grow``: files of growing N, one read each (a task that grows between Cleans);
* ``same``: the largest file read as many times (a task that does not grow);
* with ``--listing``, each file is listed as the app lists a cleaned file since
  :mod:`bt_teleop.library.cleaned_listing` (attributes and two timestamps a demo), not read in full.

Bytes, not times: the load of the machine does not change them.

    .venv/bin/python benchmarks/soak/bench_read_high_water.py grow 50 100 200 300 400
    .venv/bin/python benchmarks/soak/bench_read_high_water.py same 50 100 200 300 400
    .venv/bin/python benchmarks/soak/bench_read_high_water.py grow 50 100 200 300 400 --listing
"""

from __future__ import annotations

import argparse
import gc
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import psutil

from bt_teleop.proc.native_memory import heap_info, trim_heap

WRITE = (
    "import sys; from bt_pipeline.data.recording import write_recording; "
    "from bt_pipeline.data.synth import make_demo_set; "
    "write_recording(sys.argv[1], make_demo_set('wiping', n_demos=int(sys.argv[2]), "
    "seed=int(sys.argv[2])).recording, overwrite=True)"
)


def show(tag: str) -> None:
    """One line: RSS and the C heap after a collection and a trim [MiB]."""
    gc.collect()
    trim_heap()
    heap = heap_info()
    rss = psutil.Process().memory_info().rss / 2**20
    if heap is None:
        print(f"{tag:>24s}: RSS {rss:6.1f} MiB (no mallinfo2)")
        return
    print(
        f"{tag:>24s}: RSS {rss:6.1f}  C heap in use {heap.in_use / 2**20:5.1f}  "
        f"free but kept {heap.free / 2**20:5.1f} MiB",
        flush=True,
    )


def main() -> None:
    """Write the files, then read them as the mode says."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("mode", choices=("grow", "same"))
    parser.add_argument("demos", type=int, nargs="+", help="N of each read, in order")
    parser.add_argument(
        "--listing",
        action="store_true",
        help="list each file as the app lists a cleaned file now "
        "(bt_teleop.library.cleaned_listing: attributes and two timestamps a demo) instead of "
        "reading it in full",
    )
    args = parser.parse_args()
    from bt_pipeline.data.recording import read_recording
    from bt_teleop.library.reading import read_file_tracks

    def read(path: Path) -> None:
        if args.listing:
            read_file_tracks(path, "cleaned")
        else:
            read_recording(path)

    with tempfile.TemporaryDirectory() as tmp:
        paths = {n: Path(tmp) / f"wiping_{n}.hdf5" for n in set(args.demos)}
        for n, path in paths.items():
            subprocess.run([sys.executable, "-c", WRITE, str(path), str(n)], check=True)
        show("start")
        for n in args.demos:
            path = paths[n if args.mode == "grow" else max(args.demos)]
            thread = threading.Thread(target=read, args=(path,))
            thread.start()
            thread.join()
            show(f"read {path.name}")


if __name__ == "__main__":
    main()
