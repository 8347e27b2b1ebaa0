"""Tests of the differentiable demo metrics (bt_pipeline.clean.stage2.losses)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial import KDTree
from scipy.special import digamma
from scipy.stats import rankdata

from bt_pipeline.clean.stage2 import losses as tl
from bt_pipeline.score.losses import closure_loss, smoothness_loss, symmetry_loss
from bt_pipeline.score.mi import mutual_information

N = 200


def loop(n: int = N, phase: float = 0.0) -> np.ndarray:
    """A figure-8-like closed loop, shape (n, 2) [m], first sample repeated at the end."""
    t = 2 * np.pi * np.linspace(0.0, 1.0, n) + phase
    return np.column_stack([0.08 * np.sin(t), 0.04 * np.sin(2 * t) + 0.01 * np.cos(t)])


def batch(seed: int = 0, m: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """M noisy, rotated, lopsided, drifting loops and their thetas [deg]."""
    rng = np.random.default_rng(seed)
    thetas = rng.uniform(-20.0, 20.0, m)
    demos = []
    for i in range(m):
        a = np.radians(thetas[i])
        rotation = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        x = loop(phase=rng.uniform(0, 6)) @ rotation.T
        x[:, 0] *= np.where(x[:, 0] > 0, 1.0 + 0.3 * i, 1.0)
        x += rng.normal(0.0, 0.001 * (i + 1), x.shape) + np.linspace(0, 0.01 * i, N)[:, None]
        demos.append(x)
    return np.stack(demos), thetas


def as_t(values: np.ndarray, grad: bool = False) -> torch.Tensor:
    return torch.tensor(values, dtype=torch.float64, requires_grad=grad)


def kl_reference(x: np.ndarray, k: int = 3) -> float:
    """Kozachenko-Leonenko I(S; A) of one demo by brute force (numpy, max-norm)."""
    actions = np.vstack([np.diff(x, axis=0), [[0.0, 0.0]]])
    s = (x - x.mean(0)) / x.std(0)
    a = (actions - actions.mean(0)) / actions.std(0)

    def mean_log_radius(z: np.ndarray) -> float:
        dist, _ = KDTree(z).query(z, k=k + 1, p=np.inf)
        return float(np.mean(np.log(dist[:, -1])))

    joint = np.hstack([s, a])
    return float(
        digamma(len(x))
        - digamma(k)
        + 2 * mean_log_radius(s)
        + 2 * mean_log_radius(a)
        - 4 * mean_log_radius(joint)
    )


def test_losses_equal_the_numpy_definitions() -> None:
    demos, thetas = batch()
    x = as_t(demos)
    got = {
        "L1": tl.symmetry_loss(x, as_t(thetas)).numpy(),
        "L2": tl.closure_loss(x).numpy(),
        "L3": tl.smoothness_loss(x).numpy(),
    }
    want = {
        "L1": [symmetry_loss(d, t) for d, t in zip(demos, thetas, strict=True)],
        "L2": [closure_loss(d) for d in demos],
        "L3": [smoothness_loss(d) for d in demos],
    }
    for name, values in want.items():
        np.testing.assert_allclose(got[name], values, rtol=1e-9, atol=1e-12, err_msg=name)
    # The de-rotation matters: without it the rotated loops look asymmetric.
    unrotated = tl.symmetry_loss(x, torch.zeros(len(demos), dtype=torch.float64)).numpy()
    np.testing.assert_allclose(unrotated, [symmetry_loss(d) for d in demos], rtol=1e-9)
    assert not np.allclose(unrotated, got["L1"])


def test_shape_loss_is_the_mean_pointwise_distance() -> None:
    demos, _ = batch()
    references = np.stack([loop()] * len(demos))
    got = tl.shape_loss(as_t(demos), as_t(references)).numpy()
    want = np.linalg.norm(demos - references, axis=-1).mean(axis=1)
    np.testing.assert_allclose(got, want, rtol=1e-9)
    assert tl.shape_loss(as_t(references), as_t(references)).abs().max() < 1e-11


def test_mi_kl_equals_a_brute_force_kozachenko_leonenko_estimate() -> None:
    demos, _ = batch()
    got = tl.mi_kl(as_t(demos)).numpy()
    np.testing.assert_allclose(got, [kl_reference(d) for d in demos], rtol=1e-9, atol=1e-9)


def test_mi_kl_ranks_demos_like_ksg() -> None:
    # Up to noise ≈ the sample spacing (here ~2.5 mm). Far beyond it I_KL climbs back towards 0
    # (its negative bias shrinks as S and A become independent): see the mi_kl docstring.
    rng = np.random.default_rng(1)
    noise = np.repeat([0.0, 0.0002, 0.0005, 0.001, 0.002], 2)
    demos = np.stack([loop() + rng.normal(0.0, s, (N, 2)) for s in noise])
    kl = tl.mi_kl(as_t(demos)).numpy()
    actions = np.concatenate([np.diff(demos, axis=1), np.zeros((len(demos), 1, 2))], axis=1)
    ksg = [mutual_information(d, a) for d, a in zip(demos, actions, strict=True)]
    assert np.corrcoef(rankdata(kl), rankdata(ksg))[0, 1] > 0.8  # Spearman's ρ
    assert kl[:2].min() > kl[-2:].max()  # smooth demos carry more information than noisy ones


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_gradients_are_finite_even_at_zero_distances(dtype: torch.dtype) -> None:
    # An exactly closed, exactly mirror-symmetric loop: L2 = 0 and every L1 distance is 0.
    t = 2 * np.pi * np.linspace(0.0, 1.0, N)
    closed = np.column_stack([0.08 * np.sin(t), 0.04 * np.cos(2 * t)])
    closed[-1] = closed[0]
    demos, thetas = batch()
    x = torch.tensor(np.stack([closed, *demos[:2]]), dtype=dtype, requires_grad=True)
    th = torch.tensor([0.0, *thetas[:2]], dtype=dtype)
    reference = x.detach().clone()
    assert float(tl.closure_loss(x.detach())[0]) < 1e-9
    assert float(tl.symmetry_loss(x.detach(), th)[0]) < 1e-6
    total = (
        tl.symmetry_loss(x, th).sum()
        + tl.closure_loss(x).sum()
        + tl.smoothness_loss(x).sum()
        + tl.shape_loss(x, reference).sum()
        + tl.mi_kl(x).sum()
    )
    total.backward()
    assert x.grad is not None
    assert torch.isfinite(x.grad).all()
    assert x.grad.abs().sum() > 0


def test_gradients_point_downhill() -> None:
    demos, thetas = batch(seed=2)
    references = np.stack([loop()] * len(demos))
    for name, fn in {
        "L1": lambda x: tl.symmetry_loss(x, as_t(thetas)),
        "L2": tl.closure_loss,
        "L3": tl.smoothness_loss,
        "L4": lambda x: tl.shape_loss(x, as_t(references)),
        "-I_KL": lambda x: -tl.mi_kl(x),
    }.items():
        x = as_t(demos, grad=True)
        value = fn(x).sum()
        value.backward()
        assert x.grad is not None
        step = x.detach() - 1e-6 * x.grad / x.grad.norm()
        assert float(fn(step).sum()) < float(value.detach()), name
