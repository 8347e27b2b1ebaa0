"""Stage 2 of the cleaner: LSTM refinement with adaptive β (paper Sec. III-C, Algorithm 1).

Data flow, one task, all refined demos in one batch per epoch::

    x_i, x_i^aligned ──► features: standardised x_i, pull x_i^aligned - x_i, cos/sin of 2πk/N
        ──► shared 2-layer bidirectional LSTM ──► zero-initialised linear head ─┬─► Δ_i
            pull ──► zero-initialised 2x2 linear map ───────────────────────────┘
        ──► x̂_i = x_i + Δ_i  (x̂ = x before the first step: docs/algorithms.md §7 row 15)
        ──► L1..L4 and I_KL (bt_pipeline.torch_losses) ──► frozen raw-set min-max (Eq. 7)
        ──► Ũ_i = (1 - β_i) Ĩ_i + β_i Σ_j w_j (1 - L̃_j)  (Eq. 8) ──► loss -mean_i Ũ_i ──► Adam
        ──► R̄_i = reward_fn(x̂) (mean V_E, Eq. 11) ──► β_i ← clip(β_i + η tanh(γ ΔR̄_i), 0, 1)

Two variants share this loop. ``"paper"`` is the paper's configuration as written: the LSTM sees
the demo only, the MI stand-in I_KL is maximised in the loss, normalised scores are unbounded,
β takes the full step with γ = 5, Adam at 1e-3 for 300 epochs, every demo refined.
``"default"`` keeps that structure and answers each trap measured on it (docs/algorithms.md §8):
the network also sees the pull x_i^aligned - x_i, which a 2x2 linear map adds to Δ (trap 4,
slow convergence: 30 epochs instead of 1000); L̃1-L̃3 earn nothing below the best raw demo's or
the reference's own value (trap 3, tiny ranges); I_KL is only a floor at the demo's own raw
value, checked every 5th epoch (trap 1, gamed MI); β moves at η_β = 0.1 (trap 2, swings); the
best demo is passed through (trap 5); the learning rate is annealed on a cosine.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, fields
from typing import Any, Literal, get_args

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray
from torch import nn

from bt_pipeline import torch_losses as tl
from bt_pipeline.exceptions import ConfigError, DemoError
from bt_pipeline.scoring import Normaliser

FloatArray = NDArray[np.float64]
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
    """Learning rate of the linear skip relative to `lr` (default 5)."""
    cosine_lr: bool | None = None
    """Anneal the learning rate to 0 over `epochs` on a cosine (default True; paper False)."""
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
    """K, epochs run (fewer than the maximum when the loss reached a plateau)."""
    settings: RefineSettings
    """Every setting used, variant defaults filled in."""


def update_beta(
    betas: ArrayLike, rewards: ArrayLike, previous: ArrayLike, gamma: float, rate: float = 1.0
) -> FloatArray:
    """Adaptive demonstrator ability: β ← clip(β + η tanh(γ (R̄^(k) - R̄^(k-1))), 0, 1).

    With η = 1 this is Algorithm 1 line 18 (and Sec. III-C): a rising reward raises β (more weight
    on the task losses), a falling one lowers it (more weight on I(S; A)).

    Args:
        betas: β_i^(k), shape (M,), in [0, 1].
        rewards: R̄_i^(k), shape (M,).
        previous: R̄_i^(k-1), shape (M,).
        gamma: γ, sensitivity to the reward change.
        rate: η_β ∈ (0, 1], step size of the update (1 in the paper).

    Returns:
        β_i^(k+1), a new array of shape (M,).
    """
    delta = gamma * (np.asarray(rewards, np.float64) - np.asarray(previous, np.float64))
    return np.clip(np.asarray(betas, np.float64) + rate * np.tanh(delta), 0.0, 1.0)


class _Refiner(nn.Module):
    """Shared residual seq2seq LSTM: features (B, N, F) -> Δ (B, N, 2) in standardised units."""

    def __init__(self, features: int, settings: RefineSettings) -> None:
        super().__init__()
        self.lstm = nn.LSTM(
            features,
            settings.hidden,
            num_layers=settings.layers,
            batch_first=True,
            bidirectional=settings.bidirectional,
        )
        self.head = nn.Linear(settings.hidden * (2 if settings.bidirectional else 1), 2)
        # The pull x_i^aligned - x_i (features 2:4) also reaches Δ through a 2x2 linear map: a
        # gain of 1 is the reference itself, so L4's pull is learnt in a few steps (§8 trap 4).
        use_skip = settings.linear_skip and settings.condition_on_reference
        self.skip = nn.Linear(2, 2, bias=False) if use_skip else None
        nn.init.zeros_(self.head.weight)  # x̂ = x at initialisation (§7 row 15)
        nn.init.zeros_(self.head.bias)
        if self.skip is not None:
            nn.init.zeros_(self.skip.weight)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        hidden, _ = self.lstm(features)
        delta = self.head(hidden)
        return delta if self.skip is None else delta + self.skip(features[..., 2:4])


def refine_demos(
    positions: ArrayLike,
    references: ArrayLike,
    *,
    thetas_deg: ArrayLike,
    best_index: int,
    reward_fn: RewardFn,
    normaliser: Normaliser,
    config: RefineConfig | None = None,
    on_epoch: Callable[[EpochStats], None] | None = None,
) -> RefineResult:
    """Refine the demos of one task with a shared LSTM trained on the normalised utility Ũ.

    Args:
        positions: Raw demos x_i, shape (M, N, 2), in task coordinates [m].
        references: Phase-aligned references x_i^aligned, shape (M, N, 2), in [m]:
            ``references[i, k]`` is the target of ``positions[i, k]`` (Stage 1).
        thetas_deg: Demonstrator rotations θ_i, shape (M,), in [deg] (L1 de-rotation; 0 for none).
        best_index: Index of x_best (passed through unless the settings refine it).
        reward_fn: R̄ of each demo's positions in its own frame, (M, N, 2) -> (M,) in [0, 1].
        normaliser: Frozen raw-set (min, max) holding at least the columns
            :data:`REFINE_METRICS` (see :func:`refine_normaliser`). The loss normalises the MI
            stand-in I_KL by its own raw-set range, computed here.
        config: Settings; ``RefineConfig()`` (the default variant) when None.
        on_epoch: Called after every epoch with that epoch's statistics.

    Returns:
        The refined demos and the history of β, loss and reward.

    Raises:
        DemoError: Shapes disagree, fewer than 4 samples, or values not finite.
        ConfigError: `best_index` out of range, or the normaliser lacks a column.
    """
    settings = (config or RefineConfig()).resolve()
    x, ref, thetas = _validate(positions, references, thetas_deg, best_index)
    m = x.shape[0]
    for name in REFINE_METRICS:
        normaliser.index(name)  # ConfigError naming the missing column
    refine_mask = np.ones(m, dtype=bool)
    if not settings.refine_best:
        refine_mask[best_index] = False
    betas = np.full(m, settings.beta0)
    previous_reward = _rewards(reward_fn, x)
    loss_log: list[float] = []
    beta_log: list[FloatArray] = []
    reward_log: list[FloatArray] = []
    if not refine_mask.any():  # a single demo, the best: nothing to refine
        return _result(x.copy(), betas, beta_log, loss_log, reward_log, settings)

    with _torch_session(settings.seed, settings.threads):
        dtype = torch.float32
        centre = x.reshape(-1, 2).mean(axis=0)
        scale = float(x.std()) or 1.0
        x_t = torch.as_tensor(x[refine_mask], dtype=dtype)
        ref_t = torch.as_tensor(ref[refine_mask], dtype=dtype)
        theta_t = torch.as_tensor(thetas[refine_mask], dtype=dtype)
        features = _features(x, ref, centre, scale, settings.condition_on_reference)
        features_t = torch.as_tensor(features[refine_mask], dtype=dtype)
        model = _Refiner(features_t.shape[-1], settings)
        groups: list[tuple[list[torch.Tensor], float]] = [
            ([*model.lstm.parameters(), *model.head.parameters()], settings.lr)
        ]
        if model.skip is not None:
            groups.append((list(model.skip.parameters()), settings.lr * settings.skip_lr_scale))
        optimiser = _Adam(groups)
        objective = _Objective(
            normaliser, settings, x_t, ref_t, theta_t, torch.as_tensor(x, dtype=dtype), refine_mask
        )
        stall = 0
        best_loss = math.inf
        for epoch in range(1, settings.epochs + 1):
            delta = model(features_t) * scale
            with_mi = (epoch - 1) % settings.mi_every == 0
            betas_t = torch.as_tensor(betas[refine_mask], dtype=dtype)
            loss = objective(x_t + delta, betas_t, with_mi)
            model.zero_grad(set_to_none=True)
            loss.backward()
            # Cosine annealing to 0 over the epoch budget, or a constant rate.
            anneal = 0.5 * (1.0 + math.cos(math.pi * (epoch - 1) / settings.epochs))
            optimiser.step(anneal if settings.cosine_lr else 1.0)

            output = x.copy()
            output[refine_mask] += delta.detach().numpy().astype(np.float64)
            reward = _rewards(reward_fn, output)
            betas = update_beta(betas, reward, previous_reward, settings.gamma, settings.beta_rate)
            previous_reward = reward
            loss_value = float(loss.detach())
            loss_log.append(loss_value)
            beta_log.append(betas.copy())
            reward_log.append(reward)
            if on_epoch is not None:
                on_epoch(EpochStats(epoch, loss_value, reward.copy(), betas.copy()))
            if settings.patience > 0:
                stall = 0 if loss_value < best_loss - settings.tolerance else stall + 1
                best_loss = min(best_loss, loss_value)
                if stall >= settings.patience and epoch >= settings.min_epochs:
                    break
        with torch.no_grad():
            final = model(features_t).numpy().astype(np.float64) * scale
    refined = x.copy()
    refined[refine_mask] += final
    return _result(refined, betas, beta_log, loss_log, reward_log, settings)


def refine_normaliser(normaliser: Normaliser, shape_losses: ArrayLike) -> Normaliser:
    """The selection stage's raw-set normaliser plus the shape loss L4 of the same raw demos.

    Args:
        normaliser: Raw-set normaliser of :mod:`bt_pipeline.scoring` (MI, L1, L2, L3).
        shape_losses: L4 of each raw demo against its aligned reference, shape (M,), in [m].

    Returns:
        A normaliser with the extra column ``"shape"``.
    """
    if "shape" in normaliser.names:
        raise ConfigError(f"the normaliser already has a shape column: {normaliser.names}")
    values = np.asarray(shape_losses, dtype=np.float64)
    if values.ndim != 1 or values.size == 0 or not np.all(np.isfinite(values)):
        raise DemoError(f"shape_losses must be finite with shape (M,); got {values.shape}")
    return Normaliser(
        names=(*normaliser.names, "shape"),
        min=np.append(normaliser.min, values.min()),
        max=np.append(normaliser.max, values.max()),
        delta=normaliser.delta,
    )


class _Objective:
    """-mean_i Ũ_i of the refined demos (Eq. 8) with the frozen raw-set normalisers (Eq. 7)."""

    def __init__(
        self,
        normaliser: Normaliser,
        settings: RefineSettings,
        x: torch.Tensor,
        references: torch.Tensor,
        thetas: torch.Tensor,
        all_raw: torch.Tensor,
        refined: NDArray[np.bool_],
    ) -> None:
        spans = [normaliser.affine(name) for name in REFINE_METRICS]
        self.lo = x.new_tensor([lo for lo, _ in spans])
        self.scale = x.new_tensor([scale for _, scale in spans])
        self.weights = x.new_tensor(settings.weights)
        self.references, self.thetas, self.settings = references, thetas, settings
        # I_KL is not KSG: normalise it by its own range over the raw set (§7 row 16).
        with torch.no_grad():
            mi_raw = tl.mi_kl(all_raw)
        span = float(mi_raw.max() - mi_raw.min())
        self.mi_lo = float(mi_raw.min())
        self.mi_scale = 1.0 / span if span > normaliser.delta else 0.0
        self.mi_raw = (mi_raw[torch.from_numpy(refined)] - self.mi_lo) * self.mi_scale
        self.floor: torch.Tensor | None = None
        if settings.clamp_scores:
            with torch.no_grad():
                self.floor = self.normalised_losses(references).clamp_min(0.0)
            self.floor[:, 3] = -math.inf  # L4: closer to the reference is always better

    def normalised_losses(self, out: torch.Tensor) -> torch.Tensor:
        """L̃1..L̃4 of each demo, shape (B, 4) (Eq. 7 with the frozen raw-set (min, max))."""
        losses = torch.stack(
            (
                tl.symmetry_loss(out, self.thetas),
                tl.closure_loss(out),
                tl.smoothness_loss(out),
                tl.shape_loss(out, self.references),
            ),
            dim=-1,
        )
        return (losses - self.lo) * self.scale

    def __call__(self, out: torch.Tensor, betas: torch.Tensor, with_mi: bool) -> torch.Tensor:
        """-mean_i Ũ_i; without `with_mi` a "floor" MI term is taken at its raw value."""
        norm = self.normalised_losses(out)
        if self.floor is not None:  # no reward beyond the best raw demo or the reference
            norm = torch.maximum(norm, self.floor)
        task_score = ((1.0 - norm) * self.weights).sum(dim=-1)  # Eq. (10)
        mi_score = self._mi_score(out) if with_mi else self._mi_constant(out)
        utility = (1.0 - betas) * mi_score + betas * task_score  # Eq. (8)
        return -utility.mean()

    def _mi_constant(self, out: torch.Tensor) -> torch.Tensor:
        """The MI term between checks: the floor's cap (its value whenever it is inactive)."""
        if self.settings.mi_term == "floor":
            return self.mi_raw.clamp_max(1.0) if self.settings.clamp_scores else self.mi_raw
        return self._mi_score(out)

    def _mi_score(self, out: torch.Tensor) -> torch.Tensor:
        """Ĩ_i of Eq. (8) as the settings' `mi_term` asks, shape (B,)."""
        mode = self.settings.mi_term
        if mode == "off":
            return out.new_zeros(out.shape[0])
        current = (tl.mi_kl(out) - self.mi_lo) * self.mi_scale
        if mode == "floor":  # no reward above the demo's own raw MI: only a loss is penalised
            current = torch.minimum(current, self.mi_raw)
        return current.clamp_max(1.0) if self.settings.clamp_scores else current


class _Adam:
    """Adam (Kingma and Ba 2015) as torch.optim.Adam computes it, without its import cost.

    torch.optim's first optimiser imports torch._dynamo, which takes seconds: more than a whole
    D1 refinement.
    """

    def __init__(
        self,
        groups: list[tuple[list[torch.Tensor], float]],
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
    ) -> None:
        self.groups = groups
        self.beta1, self.beta2 = betas
        self.eps = eps
        self.steps = 0
        self.moments = [
            [(torch.zeros_like(p), torch.zeros_like(p)) for p in params] for params, _ in groups
        ]

    @torch.no_grad()
    def step(self, lr_factor: float = 1.0) -> None:
        """One update of every parameter with a gradient, at `lr_factor` times each group's rate."""
        self.steps += 1
        correction1 = 1.0 - self.beta1**self.steps
        correction2_sqrt = math.sqrt(1.0 - self.beta2**self.steps)
        for (params, lr), moments in zip(self.groups, self.moments, strict=True):
            step_size = lr * lr_factor / correction1
            for p, (mean, square) in zip(params, moments, strict=True):
                if p.grad is None:
                    continue
                mean.mul_(self.beta1).add_(p.grad, alpha=1.0 - self.beta1)
                square.mul_(self.beta2).addcmul_(p.grad, p.grad, value=1.0 - self.beta2)
                p.addcdiv_(
                    mean, (square.sqrt() / correction2_sqrt).add_(self.eps), value=-step_size
                )


def _features(
    x: FloatArray, ref: FloatArray, centre: FloatArray, scale: float, with_reference: bool
) -> FloatArray:
    """Network input, shape (M, N, F): standardised x, optionally (ref - x), phase cos/sin."""
    m, n, _ = x.shape
    phase = 2.0 * np.pi * np.arange(n) / n
    cos_sin = np.broadcast_to(np.stack((np.cos(phase), np.sin(phase)), -1), (m, n, 2))
    parts = [(x - centre) / scale]
    if with_reference:
        # Unit RMS, so Adam's ~lr-sized first steps already move a sizeable part of the way.
        pull = ref - x
        parts.append(pull / max(float(np.sqrt(np.mean(pull**2))), 1e-12))
    parts.append(cos_sin)
    return np.concatenate(parts, axis=-1)


def _rewards(reward_fn: RewardFn, positions: FloatArray) -> FloatArray:
    """reward_fn on a copy of `positions`, checked to be M finite values."""
    rewards = np.asarray(reward_fn(positions.copy()), dtype=np.float64)
    if rewards.shape != (positions.shape[0],) or not np.all(np.isfinite(rewards)):
        raise DemoError(
            f"reward_fn must return {positions.shape[0]} finite values; got shape {rewards.shape}"
        )
    return rewards


def _validate(
    positions: ArrayLike, references: ArrayLike, thetas_deg: ArrayLike, best_index: int
) -> tuple[FloatArray, FloatArray, FloatArray]:
    x = np.array(positions, dtype=np.float64)
    ref = np.array(references, dtype=np.float64)
    thetas = np.array(thetas_deg, dtype=np.float64).reshape(-1)
    if x.ndim != 3 or x.shape[2] != 2 or x.shape[0] == 0 or x.shape[1] < 4:
        raise DemoError(f"positions must have shape (M, N, 2) with M ≥ 1, N ≥ 4; got {x.shape}")
    if ref.shape != x.shape:
        raise DemoError(f"references must have the shape of positions {x.shape}; got {ref.shape}")
    if thetas.shape != (x.shape[0],):
        raise DemoError(f"thetas_deg must have shape ({x.shape[0]},); got {thetas.shape}")
    for name, values in (("positions", x), ("references", ref), ("thetas_deg", thetas)):
        if not np.all(np.isfinite(values)):
            raise DemoError(f"{name} contain NaN or infinite values")
    if isinstance(best_index, bool) or not 0 <= int(best_index) < x.shape[0]:
        raise ConfigError(f"best_index must be in [0, {x.shape[0] - 1}]; got {best_index!r}")
    return x, ref, thetas


def _result(
    refined: FloatArray,
    betas: FloatArray,
    beta_log: list[FloatArray],
    loss_log: list[float],
    reward_log: list[FloatArray],
    settings: RefineSettings,
) -> RefineResult:
    m = refined.shape[0]
    return RefineResult(
        refined=refined,
        betas=betas.copy(),
        beta_history=np.array(beta_log, dtype=np.float64).reshape(-1, m),
        loss_history=np.array(loss_log, dtype=np.float64),
        reward_history=np.array(reward_log, dtype=np.float64).reshape(-1, m),
        variant=settings.variant,
        epochs=len(loss_log),
        settings=settings,
    )


@contextlib.contextmanager
def _torch_session(seed: int, threads: int) -> Iterator[None]:
    """Seed torch's RNG and set its thread count for the block, restoring both afterwards."""
    saved_threads = torch.get_num_threads()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        torch.set_num_threads(threads)
        try:
            yield
        finally:
            torch.set_num_threads(saved_threads)
