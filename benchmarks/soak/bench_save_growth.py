"""What one Stop & save costs the app as a task's takes grow: the library load, and each tab's view.

Every save bumps the task's version; the shared loader (:mod:`bt_teleop.library.loader`) then
loads the task's library once, and every tab on the task renders it: the recordings table
(Markdown) and the two pickers (Replay, Demo), whose option lists viser sends to the browser
in a ``GuiUpdateMessage`` each time they change. This benchmark builds a task of N takes (empty
files on disk, their tracks served from a cache as the loader's cache serves unchanged files,
so no HDF5 is read) and measures, for each N:

* the load after one more take was saved (:func:`bt_teleop.library.listing.load_library` with cached
  reads and the last library, as the loader runs it): the bytes Python allocates during it
  (tracemalloc peak) and the new bytes it still holds with the last library alive, beside the
  same load without the last library (the code before the reuse: a new object per take);
* a tab's view of it (:func:`bt_teleop.library.view.library_view`): the length of the table's
  Markdown, the number of keys each picker offers, and the size of the messages that carry
  them (msgpack, as viser encodes them), with the view the code before that module built
  (every key of the task in both pickers) beside it;
* after a save, what a tab sends again: the options of both pickers change, the table too.

The numbers do not depend on the machine's load (bytes and counts, no times)::

    .venv/bin/python benchmarks/soak/bench_save_growth.py --takes 100 1000 2000
"""

from __future__ import annotations

import argparse
import tempfile
import tracemalloc
from pathlib import Path
from typing import Any

import msgspec

from bt_teleop.library.listing import TaskLibrary, load_library
from bt_teleop.library.view import DEFAULT_LISTED, library_view
from bt_teleop.testing.harness import synthetic_task_files


def message_bytes(uuid: str, options: list[str]) -> int:
    """Bytes of a viser ``GuiUpdateMessage`` setting a dropdown's options (msgpack)."""
    message = {"type": "GuiUpdateMessage", "uuid": uuid, "updates": {"options": options}}
    return len(msgspec.msgpack.encode(message))


def _load_held(
    root: Path, cache: dict[Path, Any], previous: TaskLibrary | None
) -> tuple[TaskLibrary, float, float]:
    """A load of the task: the library, the bytes it allocated and still holds [KiB] (the
    previous library stays alive, as the tabs hold it), and the peak allocated [KiB]."""
    tracemalloc.start()
    library = load_library(root, "wiping", read=lambda path, kind: cache[path], previous=previous)
    held, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return library, held / 1024, peak / 1024


def measure(n: int, listed: int) -> dict[str, float]:
    """The costs above for a task of `n` takes."""
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        cache = synthetic_task_files(root, "wiping", n - 1)
        first, _, _ = _load_held(root, cache, None)
        cache = synthetic_task_files(root, "wiping", n)  # one more take saved
        _, held_fresh, _ = _load_held(root, cache, None)
        library, held, peak = _load_held(root, cache, first)
        tracemalloc.start()
        view = library_view(library, listed)
        view_peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    all_raw = [t.key for t in library.raw]
    all_keys = [t.key for t in library.tracks]
    uuid = "0" * 22
    return {
        "takes": n,
        "load: peak allocated [KiB]": peak,
        "load after a save: new, held [KiB]": held,
        "before: the same, no reuse [KiB]": held_fresh,
        "view: built, peak [KiB]": view_peak / 1024,
        "table [bytes]": len(view.markdown.encode()),
        "replay keys": len(view.replay_keys),
        "demo keys": len(view.moderation_keys),
        "pickers' messages [KiB]": (
            message_bytes(uuid, view.replay_keys) + message_bytes(uuid, view.moderation_keys)
        )
        / 1024,
        "before: pickers' messages [KiB]": (
            message_bytes(uuid, all_keys) + message_bytes(uuid, all_raw)
        )
        / 1024,
    }


def main() -> None:
    """Print one row per N."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("--takes", type=int, nargs="+", default=[100, 1000, 2000])
    parser.add_argument("--listed", type=int, default=DEFAULT_LISTED)
    args = parser.parse_args()
    rows = [measure(n, args.listed) for n in args.takes]
    print(f"listed (newest demos the pickers offer): {args.listed}")
    for name in rows[0]:
        cells = [
            f"{row[name]:,.1f}" if not float(row[name]).is_integer() else f"{row[name]:,.0f}"
            for row in rows
        ]
        print(f"{name:34s} " + " ".join(f"{c:>10s}" for c in cells))


if __name__ == "__main__":
    main()
