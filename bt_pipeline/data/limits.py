"""Physical and size limits a recording must keep, checked when it is read (no hangs later).

Format v1 alone admits files that are valid but absurd: an end effector 10^30 m away, ρ = 1e-300,
a 10^7-sample demo, an hour-long gap between two samples, a 5000-digit demo index, a NUL byte in
a name. Each of these once made a later stage hang, crash inside a library, or fail after all the
work was done. The reader checks them up front, against :class:`ReadLimits`, and raises one
:class:`~bt_pipeline.exceptions.RecordingError` naming the file, the demo, the value and the bound
(``docs/recording-format.md``, "Limits").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from bt_pipeline.exceptions import ConfigError, RecordingError

MAX_INDEX_DIGITS = 9
"""Most digits of k in ``demo_<k>`` (k < 10^9; Python refuses int() of > 4300 digits)."""
MAX_TEXT_CHARS = 10_000
"""Longest free-text attr (``demonstrator``, extra string attrs); JSON attrs are not capped."""


@dataclass(frozen=True)
class ReadLimits:
    """Bounds on the magnitudes and sizes of a recording, checked at read time.

    The defaults fit any table-top robot demo with a wide margin; change them (``bt score
    --max-distance``, ``bt clean --max-distance``) for a larger workspace.
    """

    max_distance_m: float = 10.0
    """Largest distance of an end-effector sample from the task plane's origin, and of that
    origin from the world origin [m]."""
    max_samples: int = 1_000_000
    """Most samples T in one demo."""
    max_demos: int = 10_000
    """Most demos in one file."""
    max_gap_s: float = 600.0
    """Largest step between two consecutive timestamps [s]."""
    max_duration_s: float = 86_400.0
    """Longest demo, last minus first timestamp [s]."""
    max_abs_time_s: float = 1e10
    """Largest |timestamp| [s] (Unix time in seconds is about 1.8e9)."""
    max_abs_theta_deg: float = 360.0
    """Largest |θ| [deg] of a known demonstrator rotation."""
    rho_range: tuple[float, float] = (0.05, 20.0)
    """Smallest and largest known demonstrator scale ρ."""

    def __post_init__(self) -> None:
        positive = {
            "max_distance_m": self.max_distance_m,
            "max_samples": self.max_samples,
            "max_demos": self.max_demos,
            "max_gap_s": self.max_gap_s,
            "max_duration_s": self.max_duration_s,
            "max_abs_time_s": self.max_abs_time_s,
            "max_abs_theta_deg": self.max_abs_theta_deg,
        }
        for name, value in positive.items():
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ConfigError(
                    f"read limit {name} must be a positive finite number; got {value}"
                )
        lo, hi = self.rho_range
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
            raise ConfigError(f"read limit rho_range must be 0 < lo < hi, finite; got {lo}, {hi}")


DEFAULT_LIMITS = ReadLimits()
"""The limits :func:`~bt_pipeline.data.recording.read_recording` uses unless told otherwise."""


def check_text(value: str, what: str, label: str, max_chars: int | None = MAX_TEXT_CHARS) -> str:
    """Return `value` if it is storable text: no NUL, at most `max_chars` characters.

    Raises:
        RecordingError: ``<label>: <what> ...`` naming the problem.
    """
    if "\x00" in value:
        raise RecordingError(
            f"{label}: {what} contains a NUL byte at character {value.index(chr(0))}; text may "
            "not contain NUL"
        )
    if max_chars is not None and len(value) > max_chars:
        raise RecordingError(
            f"{label}: {what} is {len(value)} characters long; at most {max_chars} are allowed"
        )
    return value


def decode_utf8(value: Any, what: str, label: str) -> str:
    """`value` (str or bytes) as text without NUL; invalid UTF-8 is an error, not replaced.

    Raises:
        RecordingError: Invalid UTF-8 (with the byte offset) or a NUL byte.
    """
    if isinstance(value, bytes):
        try:
            value = value.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise RecordingError(
                f"{label}: {what} is not valid UTF-8 (byte {exc.start}: {exc.reason}); text "
                "attrs must be UTF-8"
            ) from None
    return check_text(str(value), what, label, max_chars=None)


def check_index_digits(digits: str, name: str, where: str) -> None:
    """Refuse a demo index k of more than :data:`MAX_INDEX_DIGITS` digits before int() sees it."""
    if len(digits) > MAX_INDEX_DIGITS:
        shown = name if len(name) <= 40 else f"{name[:20]}…({len(digits)} digits)"
        raise RecordingError(
            f"{where}: demo name {shown!r} has an index of {len(digits)} digits; at most "
            f"{MAX_INDEX_DIGITS} are allowed (demo_0 ... demo_999999999)"
        )


def check_demo_count(count: int, where: str, limits: ReadLimits) -> None:
    """Refuse a file with more than ``limits.max_demos`` demos."""
    if count > limits.max_demos:
        raise RecordingError(
            f"{where}: /data holds {count} demos; at most {limits.max_demos} per file are read"
        )


def check_sample_count(rows: int, label: str, limits: ReadLimits) -> None:
    """Refuse a demo longer than ``limits.max_samples`` before its datasets are loaded."""
    if rows > limits.max_samples:
        raise RecordingError(
            f"{label} has {rows} samples; at most {limits.max_samples} are read (split the demo, "
            "or downsample it)"
        )


def check_plane_origin(origin: np.ndarray, where: str, limits: ReadLimits) -> None:
    """Refuse a plane origin farther than ``limits.max_distance_m`` from the world origin."""
    distance = float(np.linalg.norm(np.asarray(origin, dtype=np.float64)))
    if not distance <= limits.max_distance_m:
        raise RecordingError(
            f"{where}: /data: attr plane_origin is {distance:.3g} m from the world origin; at most "
            f"{limits.max_distance_m:g} m is allowed (ReadLimits.max_distance_m, --max-distance)"
        )


def check_demo_magnitudes(
    ee_pos: np.ndarray,
    timestamps: np.ndarray,
    theta_deg: float,
    rho: float,
    plane_origin: np.ndarray,
    label: str,
    limits: ReadLimits,
) -> None:
    """Check one demo's magnitudes against `limits` (its arrays are already finite, shape-checked).

    Args:
        ee_pos: End-effector positions, shape (T, 3), in [m].
        timestamps: Strictly increasing times, shape (T,), in [s].
        theta_deg: θ [deg], NaN when unknown.
        rho: ρ, NaN when unknown.
        plane_origin: The task plane's origin, shape (3,), in [m].
        label: ``<file>: demo_<k>``, the start of every message.
        limits: The bounds.

    Raises:
        RecordingError: The first value out of bounds, with its index and the bound.
    """
    offsets = np.asarray(ee_pos, dtype=np.float64) - np.asarray(plane_origin, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):  # beyond ~1e154 m the norm is inf: refused
        distances = np.linalg.norm(offsets / limits.max_distance_m, axis=1)
    far = np.flatnonzero(~(distances <= 1.0))
    if far.size:
        i = int(far[0])
        raise RecordingError(
            f"{label}: obs/ee_pos[{i}] = {np.asarray(ee_pos)[i].tolist()} is "
            f"{distances[i] * limits.max_distance_m:.3g} m from the task plane's origin; at most "
            f"{limits.max_distance_m:g} m is allowed ({far.size} samples beyond; "
            "ReadLimits.max_distance_m, --max-distance)"
        )
    t = np.asarray(timestamps, dtype=np.float64)
    if not float(np.max(np.abs(t))) <= limits.max_abs_time_s:
        raise RecordingError(
            f"{label}: timestamps reach {float(np.max(np.abs(t))):.3g} s; |t| must stay below "
            f"{limits.max_abs_time_s:.3g} s"
        )
    duration = float(t[-1] - t[0])
    if not duration <= limits.max_duration_s:
        raise RecordingError(
            f"{label} lasts {duration:.3g} s; at most {limits.max_duration_s:g} s is allowed"
        )
    steps = np.diff(t)
    j = int(np.argmax(steps))
    if not steps[j] <= limits.max_gap_s:
        raise RecordingError(
            f"{label}: timestamps jump by {steps[j]:.3g} s between samples {j} and {j + 1}; at "
            f"most {limits.max_gap_s:g} s between two samples is allowed"
        )
    if not math.isnan(theta_deg) and not abs(theta_deg) <= limits.max_abs_theta_deg:
        raise RecordingError(
            f"{label}: attr theta_deg is {theta_deg:.6g}; a known θ lies in "
            f"[-{limits.max_abs_theta_deg:g}, {limits.max_abs_theta_deg:g}] deg (NaN = unknown)"
        )
    lo, hi = limits.rho_range
    if not math.isnan(rho) and not lo <= rho <= hi:
        raise RecordingError(
            f"{label}: attr rho is {rho:.6g}; a known ρ lies in [{lo:g}, {hi:g}] (NaN = unknown)"
        )
