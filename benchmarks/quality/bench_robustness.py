"""Cleaning quality on recordings our generator never makes: other sample rates and speeds.

Held-out data comes from other people's tools: 10 Hz logs, 120 Hz logs, slower or faster
demonstrators. Each human-style set (``make_human_set``) is transformed the same way for every
demo, ground truth included, and cleaned:

* ``asis``: unchanged (30-60 Hz, loops of 3-7 s);
* ``everyK``: every K-th sample kept (``every5``: 6-12 Hz);
* ``hz120``: the samples and the truth read at 120 Hz (linear, between the stored samples);
* ``slow`` / ``fast``: every time stretched by 2 / by 0.5 (loops of 6-14 s / 1.5-3.5 s).

Reported per transform and task (naive demos: mean and worst after/before ratios of the shape and
timing distances of ``bench_clean_human.py``; the expert-like demo's worst ratio; the share of
sets whose best demo is the expert). ``--linear`` runs the same sets a second time with the span
demos resampled linearly (the resampling before 2026-12-02), in the same process, for comparison.

    python benchmarks/quality/bench_robustness.py --transforms asis,every5,hz120,slow,fast --seeds 3
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

import bt_pipeline.clean.periodic
import bt_pipeline.data.demo
from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.records import DemoRecord, FloatArray
from bt_pipeline.data.synth_human import make_human_set
from bt_pipeline.data.synth_truth import truth_of, truth_ratios
from bt_pipeline.data.tasks import TASKS


def transform(record: DemoRecord, kind: str) -> DemoRecord:
    """The demo (and its stored truth) as another tool would have recorded it."""
    stored = truth_of(record)
    assert stored is not None
    truth, on = stored
    t, x = record.timestamps, record.ee_pos
    if kind.startswith("every"):
        keep = np.arange(0, t.size, int(kind[len("every") :]))
        t, x, truth, on = t[keep], x[keep], truth[keep], on[keep]
    elif kind == "hz120":
        fine = np.arange(t[0], t[-1], 1.0 / 120.0)
        x, truth = _interp(fine, t, x), _interp(fine, t, truth)
        on, t = np.interp(fine, t, on.astype(np.float64)) > 0.5, fine
    elif kind in ("slow", "fast"):
        t = t[0] + (2.0 if kind == "slow" else 0.5) * (t - t[0])
    elif kind != "asis":
        raise SystemExit(f"unknown transform {kind!r}")
    attrs = dict(record.attrs, truth_uv=truth.astype(np.float32), truth_on_loop=on.astype(np.uint8))
    return dataclasses.replace(
        record,
        ee_pos=x,
        timestamps=t,
        attrs=attrs,
        actions=None,
        ee_quat=None,
        joint_pos=None,
        gripper=None,
        states=None,
        extra_obs={},
    )


def _interp(at: FloatArray, t: FloatArray, values: FloatArray) -> FloatArray:
    return np.stack([np.interp(at, t, values[:, d]) for d in range(values.shape[1])], axis=1)


def measure(task: str, n: int, seed: int, kind: str) -> dict[str, list[float]]:
    """Ratios of one transformed, cleaned set."""
    synth = make_human_set(task, n, seed)
    records = {k: transform(v, kind) for k, v in synth.recording.demos.items()}
    recording = dataclasses.replace(synth.recording, demos=records)
    demos = demos_from_recording(recording)
    result = clean_demos(demos, CleanOptions(seed=seed, progress=False))
    out: dict[str, list[float]] = {"selected": [float(result.best_index == synth.expert_index)]}
    for i, record in enumerate(records.values()):
        shape, timing = truth_ratios(record, demos[i].raw_samples(), result.on_raw_times(i))
        if i == synth.expert_index:
            out.setdefault("expert", []).append(max(shape, timing))
        else:
            out.setdefault("shape", []).append(shape)
            out.setdefault("timing", []).append(timing)
    return out


@contextmanager
def linear_resampling() -> Iterator[None]:
    """The span demos resampled linearly (np.interp), as before PCHIP."""

    def linear(values: FloatArray, timestamps: FloatArray, n_samples: int) -> FloatArray:
        t_new = np.linspace(timestamps[0], timestamps[-1], n_samples)
        return _interp(t_new, timestamps, values)

    modules = (bt_pipeline.data.demo, bt_pipeline.clean.periodic)
    saved = [m.resample_uniform for m in modules]
    for m in modules:
        m.resample_uniform = linear  # type: ignore[assignment]
    try:
        yield
    finally:
        for m, f in zip(modules, saved, strict=True):
            m.resample_uniform = f  # type: ignore[assignment]


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--transforms", default="asis,every5,hz120,slow,fast")
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument("--demos", type=int, default=8)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--linear", action="store_true", help="also run with linear resampling")
    args = parser.parse_args()
    print(
        "| resampling | transform | task | naive shape (mean / worst) | naive timing "
        "(mean / worst) | expert (worst) | best = expert |"
    )
    print("|---|---|---|---|---|---|---|")
    for label in ("pchip", "linear") if args.linear else ("pchip",):
        for kind in args.transforms.split(","):
            for task in args.tasks.split(","):
                rows: dict[str, list[float]] = {}
                with linear_resampling() if label == "linear" else _nothing():
                    for seed in range(args.seeds):
                        for key, values in measure(task, args.demos, seed, kind).items():
                            rows.setdefault(key, []).extend(values)
                print(
                    f"| {label} | {kind} | {task} | {_mean_worst(rows['shape'])} | "
                    f"{_mean_worst(rows['timing'])} | {max(rows['expert']):.2f} | "
                    f"{np.mean(rows['selected']):.0%} |",
                    flush=True,
                )


@contextmanager
def _nothing() -> Iterator[None]:
    yield


def _mean_worst(values: list[float]) -> str:
    return f"{np.mean(values):.2f} / {np.max(values):.2f}"


if __name__ == "__main__":
    main()
