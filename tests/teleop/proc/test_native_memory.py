"""The C heap (bt_teleop/proc/native_memory.py): mallinfo2 sees what native code allocates,
malloc_trim gives the free pages of a fragmented heap back, and the app trims its heap
periodically (the soak's app process grew by fragmenting glibc's arenas: docs/security.md);
HDF5's free lists hold what h5py's writes freed until they are released."""

from __future__ import annotations

import ctypes
import threading

import h5py
import numpy as np
import pytest

from bt_pipeline.exceptions import ConfigError
from bt_teleop.app import AppOptions
from bt_teleop.proc.native_memory import (
    HeapTrimmer,
    hdf5_free_lists,
    heap_info,
    release_hdf5_free_lists,
    trim_heap,
)
from bt_teleop.testing.harness import app_factory, wait_until

MIB = 2**20
glibc = pytest.mark.skipif(heap_info() is None, reason="needs glibc's mallinfo2")


def _rss() -> int:
    """This process's resident set [bytes]."""
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * 4096


def _allocate(n_blocks: int, block: int) -> list[int]:
    """malloc `n_blocks` blocks of `block` bytes and touch them (resident); their pointers."""
    libc = ctypes.CDLL("libc.so.6")
    libc.malloc.restype = ctypes.c_void_p
    libc.malloc.argtypes = [ctypes.c_size_t]
    pointers = [libc.malloc(block) for _ in range(n_blocks)]
    for pointer in pointers:
        ctypes.memset(pointer, 1, block)
    return pointers


def _free_all(pointers: list[int]) -> None:
    libc = ctypes.CDLL("libc.so.6")
    libc.free.argtypes = [ctypes.c_void_p]
    for pointer in pointers:
        libc.free(pointer)


@glibc
def test_heap_info_sees_native_allocations_and_trim_returns_free_pages() -> None:
    """96 MiB in 4 KiB blocks, then 31 of every 32 freed (the rest pin the heap: no free() can
    shrink it): mallinfo2 counts them in use, then free, and the pages stay resident until
    malloc_trim(0) gives them back. Each step is compared with the one just before it: a heap
    that already has free holes fills them first, so the free bytes before the allocation say
    nothing (a run of the whole suite had 136 MiB free at the start)."""
    before = heap_info()
    assert before is not None
    pointers = _allocate(n_blocks=24_576, block=4096)
    kept = pointers[::32]
    try:
        allocated = heap_info()
        assert allocated is not None
        assert allocated.in_use - before.in_use > 90 * MIB  # malloc'ed by native code
        _free_all([p for k, p in enumerate(pointers) if k % 32])
        fragmented = heap_info()
        assert fragmented is not None
        assert fragmented.free - allocated.free > 80 * MIB  # freed, but kept by malloc
        resident = _rss()
        assert trim_heap() is True
        assert resident - _rss() > 60 * MIB  # most of the 93 MiB freed left the process
    finally:
        _free_all(kept)


def test_hdf5_keeps_the_blocks_writes_freed_until_its_free_lists_are_released(tmp_path) -> None:
    """Files of 12 sizes written with h5py: HDF5 keeps the blocks it freed on its block free
    lists (in use, to malloc) until H5garbage_collect gives them back."""
    if hdf5_free_lists() is None:
        pytest.skip("needs HDF5 >= 1.10.7 (H5get_free_list_sizes)")
    for n in range(100, 112):
        with h5py.File(tmp_path / f"{n}.h5", "w") as file:
            file["x"] = np.zeros((n, 37))
            file.attrs["a"] = "x" * n
    kept = hdf5_free_lists()
    assert kept is not None and kept.block > 0
    assert release_hdf5_free_lists() is True
    released = hdf5_free_lists()
    assert released is not None and released.block == 0 and released.total < kept.total


def test_the_trimmer_trims_every_period_until_stopped() -> None:
    calls = threading.Semaphore(0)
    trimmer = HeapTrimmer(0.01, trim=calls.release)
    for _ in range(3):
        assert calls.acquire(timeout=30.0), "the trimmer stopped trimming"
    trimmer.stop()
    assert trimmer.calls >= 3 and trimmer.seconds >= 0.0
    assert "bt-heap-trim" not in {thread.name for thread in threading.enumerate()}  # joined


def test_a_trimmer_that_never_trims_starts_no_thread() -> None:
    trims: list[None] = []
    before = set(threading.enumerate())
    trimmer = HeapTrimmer(float("inf"), trim=lambda: trims.append(None))
    assert not [t for t in set(threading.enumerate()) - before if t.name == "bt-heap-trim"]
    assert trims == [] and trimmer.calls == 0
    trimmer.trim_now()  # trimming by hand still works
    assert trims == [None] and trimmer.calls == 1
    trimmer.stop()


def test_the_trim_period_must_be_positive(tmp_path) -> None:
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ConfigError, match="must be > 0"):
            HeapTrimmer(bad)
        with pytest.raises(ConfigError, match="trim_heap_every_s must be > 0"):
            AppOptions(recordings=tmp_path, trim_heap_every_s=bad)
    assert AppOptions(recordings=tmp_path).trim_heap_every_s == 60.0


def test_the_app_trims_its_heap_and_stops_trimming_when_it_stops(tmp_path) -> None:
    with app_factory(tmp_path / "rec") as make:
        app = make(trim_heap_every_s=0.02)
        wait_until(lambda: app.heap_trimmer.calls >= 2, 30.0, "two heap trims")
        app.stop()
        assert "bt-heap-trim" not in {thread.name for thread in threading.enumerate()}
