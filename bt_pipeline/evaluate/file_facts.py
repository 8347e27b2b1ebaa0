"""What ``bt evaluate``'s input files say about each demo beyond its samples.

A format-v1 file may carry, per demo: ``cleaned_from`` (``bt clean``: the raw demo a cleaned one
was made from), ``preference_estimated`` (``bt clean``: its θ/ρ are the cleaner's estimate) and
the generator's truth (``bt synth``: ``truth_theta_deg``, ``truth_rho``, ``truth_uv``,
``truth_on_loop``; :mod:`bt_pipeline.data.synth_truth`). A demo's true loop is rebuilt as the
generators draw it, the set's loop (``env_kwargs["shape_coefficients"]``, else the task's guide)
under the true θ/ρ about the task centre, and kept only if ``truth_uv``'s loop samples lie on it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import KDTree

from bt_pipeline.data.demo import Demo, demos_from_recording
from bt_pipeline.data.loop_shape import LoopShape
from bt_pipeline.data.records import DemoRecord, FloatArray, Recording
from bt_pipeline.data.shapes import canonical_loop, similarity_transform
from bt_pipeline.data.synth import TRUTH_SAMPLES
from bt_pipeline.exceptions import BtError

_TRUTH_TOLERANCE_M = 0.001  # truth_uv's loop samples lie this close to the rebuilt true loop.
Key = tuple[str, str]
"""(file, demo name) of a demo: ``(demo.file, demo.name)``."""


@dataclass(frozen=True, eq=False)
class FileFacts:
    """What a demo's file says about it beyond its samples."""

    cleaned_from: str | None
    """``file:demo`` of the raw demo a cleaned one was made from, or None."""
    estimated: bool
    """Whether its θ/ρ are the cleaner's estimate (``preference_estimated``)."""
    true_loop: FloatArray | None
    """The generator's loop under the true θ/ρ, shape (K, 2) [m], or None (no usable truth)."""


def read_annotated(
    paths: Sequence[str | Path], n_samples: int
) -> tuple[list[Demo], dict[Key, FileFacts]]:
    """Every demo under `paths` (as :func:`~bt_pipeline.data.demo.load_demos`, strict) and the
    :class:`FileFacts` of each.

    Raises:
        RecordingError: A path matches no recording or a file is not valid format v1.
    """
    from bt_pipeline.data.paths import expand_paths
    from bt_pipeline.data.recording import read_recordings

    demos: list[Demo] = []
    facts: dict[Key, FileFacts] = {}
    for recording in read_recordings(expand_paths(paths)):
        file_demos = demos_from_recording(recording, n_samples)
        for demo, record in zip(file_demos, recording.demos.values(), strict=True):
            source = record.attrs.get("cleaned_from")
            facts[(demo.file, demo.name)] = FileFacts(
                cleaned_from=str(source) if source is not None else None,
                estimated=bool(record.attrs.get("preference_estimated", False)),
                true_loop=true_loop(recording, record),
            )
        demos.extend(file_demos)
    return demos, facts


def true_loop(recording: Recording, record: DemoRecord) -> FloatArray | None:
    """The demo's true loop, shape (600, 2) [m] (module doc), or None: no truth attrs, or a loop
    bt's generators do not draw."""
    attrs = record.attrs
    try:
        theta, rho = float(attrs["truth_theta_deg"]), float(attrs["truth_rho"])
        on_loop = np.asarray(attrs["truth_on_loop"]).reshape(-1).astype(bool)
        intended = np.asarray(attrs["truth_uv"], dtype=np.float64).reshape(-1, 2)[on_loop]
        coefficients = recording.env_args.get("env_kwargs", {}).get("shape_coefficients")
        if coefficients is None:
            canonical = canonical_loop(recording.task, TRUTH_SAMPLES)
        else:
            c = np.asarray(coefficients, dtype=np.float64)
            canonical = LoopShape(c[:, 0] + 1j * c[:, 1], "the file's loop").points(TRUTH_SAMPLES)
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, BtError):
        return None
    if not (intended.size and math.isfinite(theta) and math.isfinite(rho) and rho > 0.0):
        return None
    loop = similarity_transform(canonical, theta, rho)
    gaps, _ = KDTree(_refined(loop)).query(intended)
    return loop if float(np.max(gaps)) <= _TRUTH_TOLERANCE_M else None


def counterparts(
    noisy: Sequence[Demo], cleaned: Sequence[Demo], facts: Mapping[Key, FileFacts]
) -> list[int | None]:
    """For each cleaned demo, the index of its raw demo in `noisy`, or None.

    By ``cleaned_from`` (the same ``file:demo``, else the same file name and demo), else by the
    demo's own name when exactly one noisy demo has it (the same file given as both sets).
    """
    by_label = {d.label: i for i, d in enumerate(noisy)}
    by_base = {(Path(d.file).name, d.name): i for i, d in enumerate(noisy)}
    names = [d.name for d in noisy]
    out: list[int | None] = []
    for demo in cleaned:
        source = facts[(demo.file, demo.name)].cleaned_from or f"{demo.file}:{demo.name}"
        file, _, name = source.rpartition(":")
        found = by_label.get(f"{file}:{name}", by_base.get((Path(file).name, name)))
        if found is None and names.count(name) == 1:
            found = names.index(name)
        out.append(found)
    return out


def _refined(loop: FloatArray, factor: int = 8) -> FloatArray:
    """A closed loop (K, 2) linearly refined to K x `factor` points."""
    closed = np.concatenate([loop, loop[:1]])
    s = np.linspace(0.0, len(loop), len(loop) * factor, endpoint=False)
    return np.stack([np.interp(s, np.arange(len(closed)), closed[:, j]) for j in range(2)], 1)
