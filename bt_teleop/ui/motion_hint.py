"""The live hint of a take in progress where nothing moves: "drag the gizmo's handle".

A person new to the page presses Record, then presses beside the gizmo: viser turns the view
instead, the robot stays, and the take is saved flagged ``no_motion``
(:mod:`bt_teleop.takes.checks`, which judges a saved take). While a take records, the status
line says how to move the robot once the end effector has stayed put for a few seconds::

    trail of the take in progress (T, 3) [m], one sample every 1 / record_hz [s]
        -> still_for_s: how long it has stayed within STILL_TOLERANCE_M of where it is now
        -> motion_hint: the hint when that is at least IDLE_HINT_S, else None
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["IDLE_HINT_S", "STILL_TOLERANCE_M", "motion_hint", "still_for_s"]

IDLE_HINT_S = 3.0
"""Seconds [s] without motion in a take in progress before the hint shows."""
STILL_TOLERANCE_M = 0.005
"""An end effector that stays within this distance [m] of where it is counts as still."""


def still_for_s(
    ee_positions: ArrayLike, sample_period_s: float, tol_m: float = STILL_TOLERANCE_M
) -> float:
    """How long [s] the path has stayed within `tol_m` [m] of its last sample.

    Args:
        ee_positions: End-effector positions of the take so far, shape (T, 3), in [m].
        sample_period_s: Time between two samples [s].
        tol_m: Distance [m] below which a sample counts as where it is now.
    """
    p = np.asarray(ee_positions, dtype=np.float64).reshape(-1, 3)
    if len(p) < 2:
        return 0.0
    moved = np.flatnonzero(np.linalg.norm(p - p[-1], axis=1) > tol_m)
    first_still = 0 if len(moved) == 0 else int(moved[-1]) + 1
    return (len(p) - 1 - first_still) * float(sample_period_s)


def motion_hint(
    ee_positions: ArrayLike, sample_period_s: float, idle_s: float = IDLE_HINT_S
) -> str | None:
    """The status line's hint for a take in progress that has not moved for `idle_s` [s] (None:
    it moves, or not for that long yet); see :func:`still_for_s` for the arguments."""
    still = still_for_s(ee_positions, sample_period_s)
    if still < idle_s:
        return None
    return (
        f"👉 Nothing moved for {still:.0f} s: drag the gizmo's handle to move the robot "
        "(an arrow or a square at the tool; a press beside it turns the view)"
    )
