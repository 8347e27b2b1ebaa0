"""Stage 2 of the cleaner: LSTM refinement with adaptive β (paper Sec. III-C, Algorithm 1).

Data flow, one task, all refined demos in one batch per epoch::

    x_i, x_i^aligned ──► features: standardised x_i, pull x_i^aligned - x_i, cos/sin of 2πk/N
        ──► shared 2-layer bidirectional LSTM ──► zero-initialised linear head
        ──► paper:   Δ_i = head                      (x̂ = x before the first step, §7 row 15)
            default: Δ_i = σ(head) ⊙ (x_i^aligned - x_i), a gain per sample in (0, 1)
        ──► x̂_i = x_i + Δ_i
        ──► L1..L4 and I_KL (bt_pipeline.clean.stage2.losses) ──► frozen raw-set min-max (Eq. 7)
        ──► Ũ_i = (1 - β_i) Ĩ_i + β_i Σ_j w_j (1 - L̃_j)  (Eq. 8) ──► loss -mean_i Ũ_i ──► Adam
        ──► R̄_i = reward_fn(x̂) (mean V_E, Eq. 11) ──► β_i ← clip(β_i + η tanh(γ ΔR̄_i), 0, 1)

Two variants share this loop. ``"paper"`` is the paper's configuration as written: the LSTM sees
the demo only, the MI stand-in I_KL is maximised in the loss, normalised scores are unbounded,
β takes the full step with γ = 5, Adam at 1e-3 for 300 epochs, every demo refined.
``"default"`` keeps that structure and answers each trap measured on it (docs/algorithms.md §8):
the network also sees the pull x_i^aligned - x_i and outputs how far to follow it, a gain per
sample (trap 4, slow convergence: 30 epochs instead of 1000; a free Δ moved a careful browser
take 5 mm away from both its raw path and its reference, docs/refinement.md); L̃1-L̃3 earn
nothing below the best raw demo's or the reference's own value (trap 3, tiny ranges); I_KL is
only a floor at the demo's own raw value, checked every 5th epoch (trap 1, gamed MI); β moves at
η_β = 0.1 (trap 2, swings); the best demo is passed through (trap 5); the learning rate is
annealed on a cosine.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Iterator

import numpy as np
import torch
from numpy.typing import ArrayLike
from torch import nn

from bt_pipeline.clean.stage2.config import (
    REFINE_METRICS,
    EpochStats,
    RefineConfig,
    RefineResult,
    RefineSettings,
    RewardFn,
    TaskScales,
)
from bt_pipeline.clean.stage2.objective import Adam, UtilityObjective
from bt_pipeline.clean.stage2.scales import task_scales
from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError, DemoError
from bt_pipeline.score.utility import Normaliser


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
        self.gate = settings.gate and settings.condition_on_reference
        outputs = 1 if self.gate else 2
        self.head = nn.Linear(settings.hidden * (2 if settings.bidirectional else 1), outputs)
        # The pull x_i^aligned - x_i (features 2:4) also reaches Δ through a 2x2 linear map: a
        # gain of 1 is the reference itself, so L4's pull is learnt in a few steps (§8 trap 4).
        use_skip = settings.linear_skip and settings.condition_on_reference and not self.gate
        self.skip = nn.Linear(2, 2, bias=False) if use_skip else None
        nn.init.zeros_(self.head.weight)  # x̂ = x at initialisation (§7 row 15)
        nn.init.zeros_(self.head.bias)
        if self.skip is not None:
            nn.init.zeros_(self.skip.weight)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        hidden, _ = self.lstm(features)
        out = self.head(hidden)
        if self.gate:  # Δ = g (x^aligned - x), g = σ(·) ∈ (0, 1): ½ at initialisation
            return torch.sigmoid(out) * features[..., 2:4]
        return out if self.skip is None else out + self.skip(features[..., 2:4])


def refine_demos(
    positions: ArrayLike,
    references: ArrayLike,
    *,
    thetas_deg: ArrayLike,
    best_index: int | None,
    reward_fn: RewardFn,
    normaliser: Normaliser,
    config: RefineConfig | None = None,
    on_epoch: Callable[[EpochStats], None] | None = None,
    scales: TaskScales | None = None,
) -> RefineResult:
    """Refine the demos of one task with a shared LSTM trained on the normalised utility Ũ.

    Args:
        positions: Raw demos x_i, shape (M, N, 2), in task coordinates [m].
        references: Phase-aligned references x_i^aligned, shape (M, N, 2), in [m]:
            ``references[i, k]`` is the target of ``positions[i, k]`` (Stage 1).
        thetas_deg: Demonstrator rotations θ_i, shape (M,), in [deg] (L1 de-rotation; 0 for none).
        best_index: Index of x_best (passed through unless the settings refine it); None when
            the batch is a chunk of a task that does not hold the best demo.
        reward_fn: R̄ of each demo's positions in its own frame, (M, N, 2) -> (M,) in [0, 1].
        normaliser: Frozen raw-set (min, max) holding at least the columns
            :data:`REFINE_METRICS` (see :func:`~bt_pipeline.clean.stage2.scales.refine_normaliser`).
            The loss normalises the MI stand-in I_KL by its own raw-set range, computed here.
        config: Settings; ``RefineConfig()`` (the default variant) when None.
        on_epoch: Called after every epoch with that epoch's statistics.
        scales: Frozen task-wide standardisation (a chunk of a larger task); None computes it
            from these demos (:func:`~bt_pipeline.clean.stage2.scales.task_scales`).

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
    if best_index is not None and not settings.refine_best:
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
        scales = scales or task_scales(x, ref, threads=settings.threads)
        scale = scales.scale
        x_t = torch.as_tensor(x[refine_mask], dtype=dtype)
        ref_t = torch.as_tensor(ref[refine_mask], dtype=dtype)
        theta_t = torch.as_tensor(thetas[refine_mask], dtype=dtype)
        features = _features(x, ref, scales, settings.condition_on_reference)
        features_t = torch.as_tensor(features[refine_mask], dtype=dtype)
        model = _Refiner(features_t.shape[-1], settings)
        if model.gate:
            scale = scales.pull_rms  # g × the pull feature, back in metres
        fast = settings.lr * settings.skip_lr_scale  # the pull's own path learns faster
        groups: list[tuple[list[torch.Tensor], float]] = [
            (list(model.lstm.parameters()), settings.lr),
            (list(model.head.parameters()), fast if model.gate else settings.lr),
        ]
        if model.skip is not None:
            groups.append((list(model.skip.parameters()), fast))
        optimiser = Adam(groups)
        objective = UtilityObjective(
            normaliser,
            settings,
            x_t,
            ref_t,
            theta_t,
            torch.as_tensor(x, dtype=dtype),
            refine_mask,
            (scales.mi_low, scales.mi_span),
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


def _features(
    x: FloatArray, ref: FloatArray, scales: TaskScales, with_reference: bool
) -> FloatArray:
    """Network input, shape (M, N, F): standardised x, optionally (ref - x), phase cos/sin."""
    m, n, _ = x.shape
    phase = 2.0 * np.pi * np.arange(n) / n
    cos_sin = np.broadcast_to(np.stack((np.cos(phase), np.sin(phase)), -1), (m, n, 2))
    parts = [(x - scales.centre) / scales.scale]
    if with_reference:
        parts.append((ref - x) / scales.pull_rms)
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
    positions: ArrayLike, references: ArrayLike, thetas_deg: ArrayLike, best_index: int | None
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
    if best_index is not None and (
        isinstance(best_index, bool) or not 0 <= int(best_index) < x.shape[0]
    ):
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
