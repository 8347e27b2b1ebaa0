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
from dataclasses import dataclass

__all__ = ["HeapInfo", "heap_info", "trim_heap"]


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
