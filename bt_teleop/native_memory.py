"""The C heap of this process (glibc malloc): what it holds, and giving its free pages back.

Python's own memory is visible to ``tracemalloc``; what MuJoCo, HDF5, the websocket stack and
numpy's small temporaries get from ``malloc`` is not. glibc's ``mallinfo2`` tells how much of
the C heap is in use and how much is free but still mapped (``fordblks``): a heap that grows
in ``fordblks`` while ``uordblks`` stays flat is fragmentation, not a leak. ``malloc_trim(0)``
returns the free pages of every arena to the system.

Everything here is a no-op returning None on a C library without these calls (musl, macOS).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from bt_pipeline.exceptions import ConfigError

__all__ = ["HeapInfo", "HeapTrimmer", "heap_info", "trim_heap"]


class _Mallinfo2(ctypes.Structure):
    _fields_ = [
        (name, ctypes.c_size_t)
        for name in (
            "arena",
            "ordblks",
            "smblks",
            "hblks",
            "hblkhd",
            "usmblks",
            "fsmblks",
            "uordblks",
            "fordblks",
            "keepcost",
        )
    ]


@dataclass(frozen=True)
class HeapInfo:
    """glibc's ``mallinfo2``, summed over all arenas [bytes]."""

    arena: int
    """Bytes the arenas have from the system (sbrk and the threads' mmapped heaps)."""
    mmapped: int
    """Bytes in large blocks mmapped one by one (``hblkhd``; given back when freed)."""
    in_use: int
    """Bytes of the arenas allocated to the program (``uordblks``)."""
    free: int
    """Bytes of the arenas free but kept (``fordblks``): fragmentation and reusable space."""


@functools.cache
def _libc() -> ctypes.CDLL | None:
    try:
        library = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        library.mallinfo2.restype = _Mallinfo2
        library.malloc_trim.argtypes = [ctypes.c_size_t]
        library.malloc_trim.restype = ctypes.c_int
    except (OSError, AttributeError):
        return None
    return library


def heap_info() -> HeapInfo | None:
    """The C heap of this process now; None without glibc's ``mallinfo2`` (glibc < 2.33)."""
    library = _libc()
    if library is None:
        return None
    info = library.mallinfo2()
    return HeapInfo(int(info.arena), int(info.hblkhd), int(info.uordblks), int(info.fordblks))


def trim_heap() -> bool | None:
    """Give the free pages of every arena back to the system (``malloc_trim(0)``): whether any
    were; None without glibc."""
    library = _libc()
    if library is None:
        return None
    return bool(library.malloc_trim(0))


class HeapTrimmer:
    """Calls :func:`trim_heap` every `every_s` seconds in a daemon thread, until :meth:`stop`.

    Args:
        every_s: Period [s]; ``inf`` starts no thread (never trims).
        trim: What to call (tests); :func:`trim_heap` by default.
    """

    def __init__(self, every_s: float, trim: Callable[[], object] = trim_heap) -> None:
        if not every_s > 0.0:
            raise ConfigError(f"the heap trim period must be > 0 s (inf: never); got {every_s}")
        self.every_s = float(every_s)
        self.calls = 0
        """Trims done so far."""
        self.seconds = 0.0
        """Time spent in them [s] (each holds every malloc arena's lock while it walks it)."""
        self._trim = trim
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if math.isfinite(self.every_s):
            self._thread = threading.Thread(target=self._run, name="bt-heap-trim", daemon=True)
            self._thread.start()

    def trim_now(self) -> None:
        """Trim once (also what the thread does every period)."""
        start = time.perf_counter()
        self._trim()
        self.seconds += time.perf_counter() - start
        self.calls += 1

    def stop(self) -> None:
        """Stop the thread (a trim under way finishes first)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()

    def _run(self) -> None:
        while not self._stop.wait(self.every_s):
            self.trim_now()
