"""Tests of bt_pipeline.clean.fan_out: a large task's per-demo steps as jobs give the serial
results, bit for bit, in input order (issue 14)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest

from bt_pipeline.clean.fan_out import per_demo, segment_step
from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.synth_human import make_human_set
from bt_pipeline.execute import ExecutorConfig

LOCAL = ExecutorConfig("local")


def same(a: Any, b: Any) -> bool:
    """Equal field by field, arrays bit for bit (NaN equal to NaN)."""
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        return type(a) is type(b) and all(
            same(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a)
        )
    if isinstance(a, np.ndarray | np.generic | float):
        return np.array_equal(a, b, equal_nan=True)
    if isinstance(a, list | tuple):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def tagged(items: Sequence[int], shared: str) -> list[str]:
    """A step: each item tagged with the shared value and the size of the chunk it ran in."""
    return [f"{shared}{item}/{len(items)}" for item in items]


@pytest.mark.parametrize(("m", "k", "sizes"), [(7, 3, [3, 2, 2]), (4, 4, [4]), (1, 256, [1])])
def test_chunks_are_contiguous_at_most_k_and_results_in_order(m, k, sizes) -> None:
    out = per_demo(tagged, list(range(m)), "d", executor=LOCAL, chunk_size=k)
    expected = [f"d{i}/{size}" for i, size in zip(range(m), np.repeat(sizes, sizes), strict=True)]
    assert out == expected
    # No executor: one call over every demo, whatever K.
    assert per_demo(tagged, list(range(m)), "d", executor=None, chunk_size=k) == [
        f"d{i}/{m}" for i in range(m)
    ]


@pytest.fixture(scope="module")
def demos():
    # Human-style: approach and retreat, pauses, uneven times, θ/ρ hidden in some demos.
    return demos_from_recording(make_human_set("weaving", 7, seed=3).recording)


def test_segmentation_in_worker_processes_is_the_serial_one(demos) -> None:
    serial = per_demo(segment_step, demos, (None, None, None), executor=None, chunk_size=3)
    pooled = per_demo(
        segment_step,
        demos,
        (None, None, None),
        executor=ExecutorConfig("processes", 2),
        chunk_size=3,
    )
    assert len(pooled) == len(demos)
    assert same(pooled, serial)  # every field, bit for bit
    assert not same(serial[0], serial[1])  # the demos differ: order is checked too


def test_a_task_cleaned_with_fanned_out_steps_is_the_serial_one(demos) -> None:
    options = CleanOptions(epochs=2, progress=False, chunk_size=3)
    serial = clean_demos(demos, options)
    fanned = clean_demos(demos, dataclasses.replace(options, chunk_executor=LOCAL))
    assert same(serial.segments, fanned.segments)
    assert np.array_equal(serial.stage1.aligned, fanned.stage1.aligned)
    assert np.array_equal(serial.positions, fanned.positions)
    assert serial.raw == fanned.raw and serial.cleaned == fanned.cleaned
    assert fanned.refine.chunk_sizes == (3, 2, 2)
