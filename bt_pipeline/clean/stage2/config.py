"""Stage 2 settings and result records: the two variants and what a run returns."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any, Literal, get_args

import numpy as np
from numpy.typing import ArrayLike

from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError

RewardFn = Callable[[FloatArray], ArrayLike]
"""R̄ of each demo: positions (M, N, 2) [m] -> mean value-map reward, shape (M,), in [0, 1]."""

REFINE_METRICS: tuple[str, ...] = ("symmetry", "closure", "smoothness", "shape")
"""Loss columns a refinement normaliser must hold (L1..L4, in the order of the weights)."""

Variant = Literal["default", "paper"]
"""``"paper"``: the paper's configuration as written; ``"default"``: the tuned design."""
MiTerm = Literal["loss", "floor", "off"]
"""How I(S; A) enters the loss: the KL stand-in as is (paper), capped at the demo's own raw
value so only a loss of information is penalised, or not at all."""

_PRESETS: dict[str, dict[str, Any]] = {
    "default": {
        "epochs": 30,
        "lr": 1e-2,
        "hidden": 16,
        "beta_rate": 0.1,
        "mi_term": "floor",
        "mi_every": 5,
        "clamp_scores": True,
        "refine_best": False,
        "condition_on_reference": True,
        "patience": 10,
        "linear_skip": True,
        "skip_lr_scale": 5.0,
        "cosine_lr": True,
        "gate": True,
    },
    "paper": {
        "epochs": 300,
        "lr": 1e-3,
        "hidden": 64,
        "beta_rate": 1.0,
        "mi_term": "loss",
        "mi_every": 1,
        "clamp_scores": False,
        "refine_best": True,
        "condition_on_reference": False,
        "patience": 0,
        "linear_skip": False,
        "skip_lr_scale": 1.0,
        "cosine_lr": False,
        "gate": False,
    },
}


@dataclass(frozen=True)
class RefineSettings:
    """Every refinement setting, concrete (see :class:`RefineConfig` for their meaning)."""

    variant: Variant
    epochs: int
    lr: float
    hidden: int
    layers: int
    bidirectional: bool
    seed: int
    gamma: float
    beta0: float
    beta_rate: float
    weights: tuple[float, float, float, float]
    mi_term: MiTerm
    mi_every: int
    clamp_scores: bool
    refine_best: bool
    condition_on_reference: bool
    linear_skip: bool
    skip_lr_scale: float
    cosine_lr: bool
    gate: bool
    patience: int
    tolerance: float
    min_epochs: int
    threads: int


@dataclass(frozen=True)
class RefineConfig:
    """Refinement settings; None takes the variant's value (``_PRESETS``)."""

    variant: Variant = "default"
    """Which configuration: ``"default"`` (tuned) or ``"paper"`` (as written)."""
    epochs: int | None = None
    """K, most epochs (default 30, with early stopping on a plateau; paper 300)."""
    lr: float | None = None
    """Adam learning rate η (default 1e-2; paper 1e-3)."""
    hidden: int | None = None
    """LSTM hidden size per direction (default 16; paper 64)."""
    layers: int = 2
    """LSTM layers."""
    bidirectional: bool = True
    """Bidirectional LSTM (cleaning is offline, the whole demo is known)."""
    seed: int = 0
    """Seed of the network initialisation."""
    gamma: float = 5.0
    """γ of the β update (Sec. III-C)."""
    beta0: float = 0.5
    """β_i^(0) for every demo (docs/algorithms.md §7 row 9)."""
    beta_rate: float | None = None
    """η_β ∈ (0, 1], step of the β update (default 0.1; paper 1)."""
    weights: tuple[float, float, float, float] = (0.2, 0.2, 0.2, 0.4)
    """w_1..w_4 of L1 symmetry, L2 closure, L3 smoothness, L4 shape; each in [0, 1], sum 1."""
    mi_term: MiTerm | None = None
    """How the MI stand-in enters the loss (default "floor"; paper "loss")."""
    mi_every: int | None = None
    """With mi_term "floor", evaluate the MI guard on every this-many-th epoch only (its k-NN
    searches are the costliest part of an epoch, and the guard is rarely active; default 5;
    "loss" always evaluates it every epoch)."""
    clamp_scores: bool | None = None
    """Bound the normalised scores in the loss: L̃1-L̃3 earn nothing below the best raw demo's
    (0) or the reference's own value, whichever is higher, and Ĩ nothing above 1 (default True;
    paper False: unbounded)."""
    refine_best: bool | None = None
    """Refine x_best too (default False: passed through; paper True)."""
    condition_on_reference: bool | None = None
    """Feed x_i^aligned - x_i to the network (default True; paper False: the demo only)."""
    linear_skip: bool | None = None
    """With `condition_on_reference`, also map x_i^aligned - x_i linearly to Δ beside the LSTM
    (default True; paper False: the LSTM alone)."""
    skip_lr_scale: float | None = None
    """Learning rate of the pull's own path (the gain head with `gate`, else the linear skip)
    relative to `lr` (default 5)."""
    cosine_lr: bool | None = None
    """Anneal the learning rate to 0 over `epochs` on a cosine (default True; paper False)."""
    gate: bool | None = None
    """With `condition_on_reference`, the LSTM outputs a gain g ∈ (0, 1) per sample and
    x̂ = x + g (x^aligned - x): every refined sample lies between the raw sample and its
    reference, so refinement never moves a demo away from both (default True; paper False:
    a free Δ)."""
    patience: int | None = None
    """Stop after this many epochs without a loss improvement > `tolerance`; 0 never stops
    early (default 10; paper 0)."""
    tolerance: float = 1e-4
    """Smallest loss decrease that counts as progress."""
    min_epochs: int = 20
    """Never stop early before this epoch."""
    threads: int = 1
    """Torch CPU threads while refining (1 is fastest for these small batches)."""

    def __post_init__(self) -> None:
        if self.variant not in _PRESETS:
            raise ConfigError(f"variant must be one of {sorted(_PRESETS)}; got {self.variant!r}")
        for name, low in (
            ("epochs", 1),
            ("hidden", 1),
            ("layers", 1),
            ("threads", 1),
            ("min_epochs", 1),
            ("mi_every", 1),
            ("patience", 0),
            ("seed", 0),
        ):
            value = getattr(self, name)
            is_int = isinstance(value, int | np.integer) and not isinstance(value, bool)
            if value is not None and not (is_int and value >= low):
                raise ConfigError(f"{name} must be an integer ≥ {low}; got {value!r}")
        for name, low, high in (
            ("lr", 0.0, math.inf),
            ("skip_lr_scale", 0.0, math.inf),
            ("gamma", 0.0, math.inf),
            ("beta_rate", 0.0, 1.0),
        ):
            value = getattr(self, name)
            if value is not None and not (_is_real(value) and low < value <= high):
                raise ConfigError(f"{name} must lie in ({low}, {high}]; got {value!r}")
        if not (_is_real(self.beta0) and 0.0 <= self.beta0 <= 1.0):
            raise ConfigError(f"beta0 must lie in [0, 1]; got {self.beta0!r}")
        w = tuple(self.weights)
        if (
            len(w) != 4
            or not all(_is_real(v) and 0.0 <= v <= 1.0 for v in w)
            or abs(sum(w) - 1.0) > 1e-9
        ):
            raise ConfigError(
                f"weights must be 4 values (L1..L4) in [0, 1] summing to 1; got {self.weights!r}"
            )
        if self.mi_term is not None and self.mi_term not in get_args(MiTerm):
            raise ConfigError(f"mi_term must be one of {get_args(MiTerm)}; got {self.mi_term!r}")
        if not (_is_real(self.tolerance) and self.tolerance >= 0.0):
            raise ConfigError(f"tolerance must be finite and ≥ 0; got {self.tolerance!r}")

    def resolve(self) -> RefineSettings:
        """Concrete settings: this config with every None replaced by the variant's value."""
        preset = _PRESETS[self.variant]
        values = {
            f.name: preset[f.name] if getattr(self, f.name) is None else getattr(self, f.name)
            for f in fields(self)
        }
        values["weights"] = tuple(float(v) for v in self.weights)
        return RefineSettings(**values)


def _is_real(value: object) -> bool:
    """A finite int or float, not a bool."""
    return (
        isinstance(value, int | float | np.integer | np.floating)
        and not isinstance(value, bool)
        and math.isfinite(value)
    )


@dataclass(frozen=True)
class TaskScales:
    """Stage 2's task-wide standardisation, computed once over all of a task's raw demos.

    Refining a task in chunks (:mod:`bt_pipeline.clean.stage2.chunked`) hands every chunk these
    same frozen values, so a demo's network input and the scale of its MI term do not depend on
    which other demos share its chunk.
    """

    centre: FloatArray
    """Mean of all raw samples, shape (2,), in [m] (network input centring)."""
    scale: float
    """Standard deviation of all raw sample coordinates [m] (network input and output scale)."""
    pull_rms: float
    """RMS of x_i^aligned - x_i over all demos and samples [m] (the pull feature's unit)."""
    mi_low: float
    """Smallest I_KL of the raw demos [nats] (Eq. 7's min for the MI stand-in)."""
    mi_span: float
    """Largest minus smallest I_KL of the raw demos [nats] (Eq. 7's max - min)."""


@dataclass(frozen=True)
class EpochStats:
    """What one epoch of refinement did (passed to ``on_epoch``)."""

    epoch: int
    """1-based epoch number."""
    loss: float
    """Training loss -mean_i Ũ_i of the refined demos at this epoch (before the step)."""
    rewards: FloatArray
    """R̄_i of every demo's output at this epoch, shape (M,), in [0, 1]."""
    betas: FloatArray
    """β_i after this epoch's update, shape (M,), in [0, 1]."""


@dataclass(frozen=True)
class RefineResult:
    """Output of :func:`refine_demos`."""

    refined: FloatArray
    """Refined demos x̂_i, shape (M, N, 2), in [m]; the best demo is passed through unchanged
    unless the settings refine it."""
    betas: FloatArray
    """Final β_i, shape (M,)."""
    beta_history: FloatArray
    """β_i after each epoch, shape (K, M)."""
    loss_history: FloatArray
    """Training loss per epoch, shape (K,)."""
    reward_history: FloatArray
    """R̄_i per epoch, shape (K, M)."""
    variant: Variant
    """The variant that ran."""
    epochs: int
    """K, epochs run (fewer than the maximum when the loss reached a plateau; a chunked run: the
    most of any chunk, histories holding a stopped chunk's last values after it stopped)."""
    settings: RefineSettings
    """Every setting used, variant defaults filled in (a chunked run: the first chunk's)."""
    chunk_sizes: tuple[int, ...] = ()
    """Demos per Stage 2 chunk, in input order (one network each); () for one batch."""
    chunk_epochs: tuple[int, ...] = ()
    """Epochs each chunk ran (early stopping ends chunks apart); () for one batch."""
