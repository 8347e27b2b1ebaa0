"""Shared by the teleop tests: ``scenes`` (fixture), the scene of each built-in task, loaded once
a module."""

from __future__ import annotations

import pytest

from bt_pipeline.data.tasks import TASKS
from bt_teleop.sim.scene import SceneModel, load_scene


@pytest.fixture(scope="module")
def scenes() -> dict[str, SceneModel]:
    return {task: load_scene(task) for task in TASKS}
