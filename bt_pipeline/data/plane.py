"""The task plane: the map between 3-D world positions and 2-D task coordinates."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from bt_pipeline.exceptions import ConfigError

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class TaskPlane:
    """A plane in the world frame on which a task is drawn.

    2-D task coordinates are ``(p_world - origin) @ axes.T`` and back ``origin + uv @ axes``.
    """

    origin: FloatArray
    """Origin of the plane in the world frame, shape (3,), in [m]."""
    axes: FloatArray
    """Orthonormal in-plane axes u and v as rows, shape (2, 3)."""

    def __post_init__(self) -> None:
        origin = np.asarray(self.origin, dtype=np.float64)
        axes = np.asarray(self.axes, dtype=np.float64)
        if origin.shape != (3,) or axes.shape != (2, 3):
            raise ConfigError(
                f"task plane needs origin of shape (3,) and axes of shape (2, 3); got "
                f"{origin.shape} and {axes.shape}"
            )
        if not (np.all(np.isfinite(origin)) and np.all(np.isfinite(axes))):
            raise ConfigError("task plane origin and axes must be finite")
        if not np.allclose(axes @ axes.T, np.eye(2), atol=1e-6):
            raise ConfigError(f"task plane axes must be orthonormal rows; got {axes.tolist()}")
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "axes", axes)

    @property
    def normal(self) -> FloatArray:
        """Unit normal u × v, shape (3,)."""
        return np.cross(self.axes[0], self.axes[1])

    def to_plane(self, p_world: FloatArray) -> FloatArray:
        """World positions, shape (..., 3) [m], to task coordinates, shape (..., 2) [m]."""
        return (np.asarray(p_world, dtype=np.float64) - self.origin) @ self.axes.T

    def to_world(self, uv: FloatArray) -> FloatArray:
        """Task coordinates, shape (..., 2) [m], to world positions, shape (..., 3) [m]."""
        return self.origin + np.asarray(uv, dtype=np.float64) @ self.axes
