"""The C heap of this process (glibc malloc): what it holds, and giving its free pages back.

Python's own memory is visible to ``tracemalloc``; what MuJoCo, HDF5, the websocket stack and
numpy's small temporaries get from ``malloc`` is not. glibc's ``mallinfo2`` tells how much of
the C heap is in use and how much is free but still mapped (``fordblks``): a heap that grows
in ``fordblks`` while ``uordblks`` stays flat is fragmentation, not a leak. ``malloc_trim(0)``
returns the free pages of every arena to the system.

HDF5 (h5py's library) keeps the blocks it frees on free lists of its own, one per block size
(by default up to 1 MiB a list and 16 MiB for all block lists): to glibc they stay in use.
Every take of a new length leaves blocks of new sizes there. :func:`hdf5_free_lists` reads
what they hold and :func:`release_hdf5_free_lists` gives it back to ``malloc``
(``H5garbage_collect``).

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

__all__ = [
    "Hdf5FreeLists",
    "HeapInfo",
    "HeapTrimmer",
    "hdf5_free_lists",
    "heap_info",
    "release_free_memory",
    "release_hdf5_free_lists",
    "trim_heap",
]


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


@dataclass(frozen=True)
class Hdf5FreeLists:
    """What HDF5's free lists hold (``H5get_free_list_sizes``) [bytes], by kind of list."""

    regular: int
    """Fixed-size objects (HDF5's own structures)."""
    array: int
    """Arrays of objects."""
    block: int
    """Blocks of any size (data and metadata buffers: one list per size)."""
    factory: int
    """Factory lists (sizes chosen at run time)."""

    @property
    def total(self) -> int:
        """All four [bytes]."""
        return self.regular + self.array + self.block + self.factory


@functools.cache
def _hdf5() -> ctypes.CDLL | None:
    """h5py's HDF5 library (the one h5py calls, bundled or the system's), or None."""
    try:
        import h5py.h5

        # dlsym on an extension module's handle also searches the libraries it links.
        library = ctypes.CDLL(h5py.h5.__file__)
        library.H5get_free_list_sizes.argtypes = [ctypes.POINTER(ctypes.c_size_t)] * 4
        library.H5garbage_collect.argtypes = []
    except (ImportError, OSError, AttributeError):
        return None
    return library


def hdf5_free_lists() -> Hdf5FreeLists | None:
    """What HDF5's free lists hold now; None without h5py or HDF5 ≥ 1.10.7's call."""
    library = _hdf5()
    if library is None:
        return None
    sizes = [ctypes.c_size_t() for _ in range(4)]
    if library.H5get_free_list_sizes(*(ctypes.byref(size) for size in sizes)) < 0:
        return None
    return Hdf5FreeLists(*(int(size.value) for size in sizes))


def release_hdf5_free_lists() -> bool | None:
    """Give the blocks on HDF5's free lists back to ``malloc`` (``H5garbage_collect``): whether
    HDF5 did; None without h5py."""
    library = _hdf5()
    if library is None:
        return None
    return library.H5garbage_collect() >= 0


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


def release_free_memory() -> None:
    """:func:`release_hdf5_free_lists`, then :func:`trim_heap`: what HDF5 kept goes back to
    ``malloc``, and the free pages to the system (a session child after each take it saved or
    dropped)."""
    release_hdf5_free_lists()
    trim_heap()


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
