"""The imitation learners of the paper's evaluation (Sec. IV): BC, Traj-BC, ILEED and Neural ODE.

Pure numerics on torch (CPU): demos in, a policy out. Demos are task coordinates of shape
(M, N, 2) [m], uniform on t ∈ [0, 1]. By default every learner sees the state (x, cos φ, sin φ),
φ the phase of a canonical oscillator estimated from each demo (:mod:`.phase`), and trains on
corrective (DART-style) pairs that make the demonstrated loop attracting (:mod:`.common`);
``state="position", dart_fraction=0`` is the paper as written (ẋ = π(x)). Rollouts integrate
with Δt = 1 / (N - 1), every state clipped to a padded box of the training data (:mod:`.policy`).

=========  ========================================================  ============  ============
learner    trained on                                                rollout       module
=========  ========================================================  ============  ============
bc         one-step velocity regression                              Euler         ``bc``
traj_bc    chunks of the next H = 10 positions (trajectory-level)    receding H    ``traj_bc``
ileed      mixture likelihood with per-demonstrator expertise        Euler         ``ileed``
node       torchdiffeq RK4 on random segments, curriculum            RK4           ``node``
=========  ========================================================  ============  ============

Usage::

    trained = train_learner("ileed", demos, demonstrators, learner_config("ileed", quick=True))
    rollouts = trained.policy.rollout(x0, n_samples=demos.shape[1])   # (R, N, 2)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, get_args

from numpy.typing import ArrayLike

from bt_pipeline.evaluate.learners.bc import BCConfig, train_bc
from bt_pipeline.evaluate.learners.common import (
    STATES,
    LearnerName,
    StateRep,
    TrainConfig,
    TrainedLearner,
)
from bt_pipeline.evaluate.learners.ileed import ILEEDConfig, train_ileed
from bt_pipeline.evaluate.learners.node import NODEConfig, train_node
from bt_pipeline.evaluate.learners.policy import LearnedPolicy
from bt_pipeline.evaluate.learners.traj_bc import TrajBCConfig, train_traj_bc
from bt_pipeline.exceptions import ConfigError

LEARNERS: tuple[LearnerName, ...] = get_args(LearnerName)
"""Every learner, in the paper's order."""

LearnerConfig = BCConfig | TrajBCConfig | ILEEDConfig | NODEConfig
"""The settings of one learner."""

_CONFIGS: dict[LearnerName, type[LearnerConfig]] = {
    "bc": BCConfig,
    "traj_bc": TrajBCConfig,
    "ileed": ILEEDConfig,
    "node": NODEConfig,
}


def parse_learner(name: str) -> LearnerName:
    """`name` as a :data:`LearnerName`.

    Raises:
        ConfigError: Not a known learner (the message lists the valid ones).
    """
    for learner in LEARNERS:
        if name == learner:
            return learner
    raise ConfigError(f"unknown learner {name!r}; valid learners: {', '.join(LEARNERS)}")


def learner_config(name: LearnerName | str, quick: bool = False, **overrides: Any) -> LearnerConfig:
    """The full (default) or CI-sized (`quick`) settings of a learner, with `overrides` applied.

    Raises:
        ConfigError: Unknown learner, unknown setting or a setting out of range.
    """
    cls = _CONFIGS[parse_learner(name)]
    try:
        return cls.quick(**overrides) if quick else cls(**overrides)
    except TypeError as error:  # an unknown keyword
        raise ConfigError(f"bad setting for learner {name!r}: {error}") from error


def train_learner(
    name: LearnerName | str,
    demos: ArrayLike,
    demonstrators: Sequence[str] | None = None,
    config: TrainConfig | None = None,
    preferences: ArrayLike | None = None,
) -> TrainedLearner:
    """Train one learner on demos (M, N, 2) [m], uniform on t ∈ [0, 1] (Δt = 1 / (N - 1)).

    Args:
        name: The learner (:data:`LEARNERS`).
        demos: Task-coordinate positions, shape (M, N, 2), in [m]; never modified.
        demonstrators: Who recorded each demo (M names); only ILEED uses them (one expertise
            embedding per distinct name, docs/algorithms.md §7 row 21). None: one per demo.
        config: That learner's settings (:func:`learner_config`); default the full preset.
        preferences: Each demo's demonstrator preference (θ [deg], ρ), shape (M, 2): an input
            of every learner, so one policy draws each demonstrator's own loop (roll it out
            with ``preferences=``); None: unconditioned (the paper's learners).

    Returns:
        The trained learner: its policy (``velocity``, ``rollout``), loss history and wall time,
        and for ILEED the learned expertise per demonstrator.

    Raises:
        ConfigError: Unknown learner, a config of another learner, or bad demonstrators.
        DemoError: The demos have the wrong shape, too few samples, or are not finite.
    """
    learner = parse_learner(name)
    config = config if config is not None else _CONFIGS[learner]()
    if type(config) is not _CONFIGS[learner]:
        raise ConfigError(
            f"learner {learner!r} needs a {_CONFIGS[learner].__name__}; "
            f"got a {type(config).__name__}"
        )
    if isinstance(config, BCConfig):
        return train_bc(demos, config, preferences)
    if isinstance(config, TrajBCConfig):
        return train_traj_bc(demos, config, preferences)
    if isinstance(config, ILEEDConfig):
        return train_ileed(demos, demonstrators, config, preferences)
    assert isinstance(config, NODEConfig)
    return train_node(demos, config, preferences)


__all__ = [
    "LEARNERS",
    "STATES",
    "BCConfig",
    "ILEEDConfig",
    "LearnedPolicy",
    "LearnerConfig",
    "LearnerName",
    "NODEConfig",
    "StateRep",
    "TrainConfig",
    "TrainedLearner",
    "TrajBCConfig",
    "learner_config",
    "parse_learner",
    "train_learner",
]
