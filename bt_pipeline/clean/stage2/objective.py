"""The training objective of Stage 2: the batched utility score Ũ (Eq. 8) and its optimiser."""

from __future__ import annotations

import math

import numpy as np
import torch
from numpy.typing import NDArray

from bt_pipeline.clean.stage2 import losses as tl
from bt_pipeline.clean.stage2.config import REFINE_METRICS, RefineSettings
from bt_pipeline.score.utility import Normaliser


class UtilityObjective:
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
        mi_range: tuple[float, float],
    ) -> None:
        """The objective of one batch.

        Args:
            normaliser: Frozen raw-set (min, max) of L1..L4 (Eq. 7).
            settings: Refinement settings.
            x: Raw demos refined in this batch, shape (B, N, 2), in [m].
            references: Their aligned references, shape (B, N, 2), in [m].
            thetas: Their θ_i, shape (B,), in [deg].
            all_raw: Every raw demo of the batch, refined or not, shape (M, N, 2), in [m].
            refined: Which of `all_raw` are refined, shape (M,) (bool).
            mi_range: (min, max - min) of I_KL over the task's raw demos [nats]
                (:class:`~bt_pipeline.clean.stage2.config.TaskScales`).
        """
        spans = [normaliser.affine(name) for name in REFINE_METRICS]
        self.lo = x.new_tensor([lo for lo, _ in spans])
        self.scale = x.new_tensor([scale for _, scale in spans])
        self.weights = x.new_tensor(settings.weights)
        self.references, self.thetas, self.settings = references, thetas, settings
        # I_KL is not KSG: normalise it by its own range over the raw set (§7 row 16).
        with torch.no_grad():
            mi_raw = tl.mi_kl(all_raw)
        self.mi_lo, span = mi_range
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


class Adam:
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
