"""bt_pipeline: score and clean mixed-skill demonstrations ("Beyond the Teacher").

Pure numerics with HDF5 and Rerun I/O at the edges; never imports viser. Torch-based modules
(:mod:`bt_pipeline.clean.stage2.refiner`, :mod:`bt_pipeline.clean.pipeline`) are imported on use, so
scoring stays light.
"""

from bt_pipeline.data.demo import DEFAULT_SAMPLES, Demo, group_by_task, load_demos
from bt_pipeline.data.plane import TaskPlane
from bt_pipeline.data.recording import read_recording, write_recording
from bt_pipeline.data.records import DemoRecord, Recording
from bt_pipeline.data.tasks import (
    TASKS,
    GuidedTask,
    Task,
    has_guide,
    parse_guided_task,
    parse_task,
)
from bt_pipeline.exceptions import (
    BtError,
    ConfigError,
    DemoError,
    RecordingError,
    UnknownTaskError,
)
from bt_pipeline.score.losses import closure_loss, smoothness_loss, symmetry_loss
from bt_pipeline.score.mi import mutual_information
from bt_pipeline.score.utility import ScoreConfig, TaskScores, score_demos, select_best

__all__ = [
    "DEFAULT_SAMPLES",
    "TASKS",
    "BtError",
    "ConfigError",
    "Demo",
    "DemoError",
    "DemoRecord",
    "GuidedTask",
    "Recording",
    "RecordingError",
    "ScoreConfig",
    "Task",
    "TaskPlane",
    "TaskScores",
    "UnknownTaskError",
    "closure_loss",
    "group_by_task",
    "has_guide",
    "load_demos",
    "mutual_information",
    "parse_guided_task",
    "parse_task",
    "read_recording",
    "score_demos",
    "select_best",
    "smoothness_loss",
    "symmetry_loss",
    "write_recording",
]
