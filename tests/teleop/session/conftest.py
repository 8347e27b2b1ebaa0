"""Shared by the session's tests: ``scene`` (fixture), the wiping scene, loaded once a module."""

from __future__ import annotations

import pytest

from bt_teleop.sim.scene import SceneModel, load_scene


@pytest.fixture(scope="module")
def scene() -> SceneModel:
    return load_scene("wiping")
