"""Tests of bt_pipeline.evaluate.learners: every learner fits a clean loop (a figure-eight too),
makes it attracting, stays finite, bounded and deterministic; the phase estimate is consistent;
the shared policy integrates correctly; configs and inputs are validated."""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
import pytest
import torch
from torch import nn

from bt_pipeline.data.shapes import canonical_shape, similarity_transform
from bt_pipeline.data.tasks import Task
from bt_pipeline.evaluate.distance import chamfer_distance
from bt_pipeline.evaluate.learners import (
    LEARNERS,
    BCConfig,
    LearnedPolicy,
    LearnerConfig,
    NODEConfig,
    TrajBCConfig,
    learner_config,
    parse_learner,
    train_learner,
)
from bt_pipeline.evaluate.learners.common import Standardiser, prepare_demos
from bt_pipeline.evaluate.learners.phase import estimate_phases
from bt_pipeline.evaluate.learners.policy import Integrator
from bt_pipeline.exceptions import ConfigError, DemoError

N = 300


def ellipse_loops(n_demos: int = 4, seed: int = 0, noise_m: float = 0.0) -> np.ndarray:
    """Closed ellipses 0.24 m × 0.12 m at (0.4, 0.1), each with its own small rotation, scale and
    start phase (one period over N samples), plus optional white noise; shape (M, N, 2) [m]."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_demos):
        phase = np.linspace(0.0, 2.0 * np.pi, N) + rng.uniform(0.0, 2.0 * np.pi)
        loop = np.stack([0.12 * np.cos(phase), 0.06 * np.sin(phase)], axis=1)
        theta, rho = rng.uniform(-5.0, 5.0), 1.0 + 0.05 * rng.standard_normal()
        noise = noise_m * rng.standard_normal((N, 2))
        out.append(similarity_transform(loop, theta, rho, (0.4, 0.1)) + noise)
    return np.stack(out)


def task_loops(task: Task, n_demos: int = 4, seed: int = 0) -> np.ndarray:
    """Clean closed loops of a task's canonical shape, each with its own small rotation, scale
    and start phase, at (0.4, 0.1); shape (M, N, 2) [m]."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_demos):
        phase = np.linspace(0.0, 2.0 * np.pi, N) + rng.uniform(0.0, 2.0 * np.pi)
        theta, rho = rng.uniform(-5.0, 5.0), 1.0 + 0.05 * rng.standard_normal()
        out.append(similarity_transform(canonical_shape(task, phase), theta, rho, (0.4, 0.1)))
    return np.stack(out)


def tiny(name: str, **overrides: Any) -> LearnerConfig:
    """A few-step config, for tests of properties other than fit quality."""
    return learner_config(name, quick=True, **{"steps": 12, **overrides})


@pytest.mark.parametrize("name", LEARNERS)
def test_learner_reproduces_a_clean_loop(name: str) -> None:
    # The pick-and-place arch: a high outbound arc, a low return and two sharp turns.
    demos = task_loops("pick_and_place")
    trained = train_learner(name, demos, config=learner_config(name, quick=True))
    rollouts = trained.policy.rollout(demos[:, 0], N)
    size = float(np.ptp(demos.reshape(-1, 2), axis=0).max())
    errors = [chamfer_distance(r, d) / size for r, d in zip(rollouts, demos, strict=True)]
    assert max(errors) < 0.08, errors  # measured 0.025-0.037
    # The rollout goes once around (it does not just sit near its start).
    assert np.ptp(rollouts[0], axis=0).max() > 0.8 * size
    assert trained.loss_history.shape == (trained.config.steps,)
    assert trained.loss_history[-10:].mean() < trained.loss_history[:10].mean()
    assert trained.skipped_steps == 0 and trained.seconds > 0.0


@pytest.mark.parametrize("name", LEARNERS)
def test_learner_is_deterministic_for_a_seed(name: str) -> None:
    demos = ellipse_loops(n_demos=2)
    x0 = demos[:, 0]
    first = train_learner(name, demos, config=tiny(name))
    second = train_learner(name, demos, config=tiny(name))
    other = train_learner(name, demos, config=tiny(name, seed=1))
    np.testing.assert_array_equal(first.loss_history, second.loss_history)
    np.testing.assert_array_equal(first.policy.rollout(x0, 50), second.policy.rollout(x0, 50))
    assert not np.array_equal(first.loss_history, other.loss_history)


@pytest.mark.parametrize("name", LEARNERS)
def test_learner_stays_finite_on_noisy_data(name: str) -> None:
    demos = ellipse_loops(noise_m=0.01)  # 1 cm white noise: velocities dominated by noise
    demos[1, 100:103] += 0.2  # and a 20 cm spike
    trained = train_learner(name, demos, config=tiny(name, steps=30, lr=0.05))
    assert np.all(np.isfinite(trained.loss_history))
    assert trained.skipped_steps == 0
    rollouts = trained.policy.rollout(demos[:, 0], N)
    assert np.all(np.isfinite(rollouts))
    assert all(torch.isfinite(p).all() for p in trained.policy.net.parameters())


@pytest.mark.parametrize("name", LEARNERS)
def test_rollouts_stay_in_the_padded_box_from_a_wild_start(name: str) -> None:
    demos = ellipse_loops(n_demos=2)
    trained = train_learner(name, demos, config=tiny(name))
    box = trained.policy.box
    flat = demos.reshape(-1, 2)
    pad = 0.25 * np.ptp(flat, axis=0).max()
    np.testing.assert_allclose(box, [flat.min(axis=0) - pad, flat.max(axis=0) + pad])
    x0 = np.array([[1e3, -1e3], [0.4, 0.1], [-50.0, 7.0]])
    rollouts = trained.policy.rollout(x0, 200)
    assert rollouts.shape == (3, 200, 2)
    assert np.all(rollouts >= box[0]) and np.all(rollouts <= box[1])
    np.testing.assert_allclose(rollouts[1, 0], x0[1])  # inside the box: kept as given


def test_training_leaves_inputs_and_torch_state_alone() -> None:
    demos = ellipse_loops(n_demos=2)
    copy = demos.copy()
    torch.manual_seed(123)
    state = torch.random.get_rng_state()
    threads = torch.get_num_threads()
    trained = train_learner("bc", demos, config=tiny("bc", threads=1))
    trained.policy.rollout(demos[:, 0], 10)
    np.testing.assert_array_equal(demos, copy)
    assert torch.equal(torch.random.get_rng_state(), state)
    assert torch.get_num_threads() == threads


def test_position_state_standardises_forward_differences_without_the_last_action() -> None:
    demos = ellipse_loops(n_demos=3)
    data = prepare_demos(demos, BCConfig(box_padding=0.0, state="position"))
    dt = 1.0 / (N - 1)
    assert data.dt == pytest.approx(dt) and data.n_features == 2
    assert tuple(data.z.shape) == (3 * N, 2) and tuple(data.v.shape) == (3 * N, 2)
    pairs = data.rows_with(1).numpy()
    assert pairs.size == 3 * (N - 1)  # a_N dropped
    velocity = data.v.double().numpy()[pairs] * data.velocities.scale + data.velocities.mean
    expected = (np.diff(demos, axis=1) / dt).reshape(-1, 2)
    np.testing.assert_allclose(velocity, expected, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(data.z.double().numpy().mean(axis=0), 0, atol=1e-5)
    np.testing.assert_allclose(data.z.double().numpy().std(axis=0), 1, atol=1e-5)


def test_phase_is_the_same_place_of_the_loop_in_every_demo() -> None:
    # Figure-eights with random start phases and uneven speed: the estimated phase must map to
    # the same point of the loop in every demo, and the canonical period is one demo.
    rng = np.random.default_rng(4)
    s = np.linspace(0.0, 1.0, N)
    demos = []
    for _ in range(4):
        warp = s + 0.4 / (2 * math.pi) * (np.sin(2 * math.pi * s + rng.uniform(0, 6)) - 0)
        warp = (warp - warp[0]) / (warp[-1] - warp[0])
        demos.append(canonical_shape("weaving", rng.uniform(0, 2 * math.pi) + 2 * math.pi * warp))
    demos = np.stack(demos)
    fit = estimate_phases(demos)
    assert fit.period == pytest.approx(1.0, abs=0.02)
    wrapped = np.mod(fit.phases, 2 * math.pi)
    spread = []
    for target in np.linspace(0.3, 6.0, 12):
        k = [int(np.argmin(np.abs(np.angle(np.exp(1j * (w - target)))))) for w in wrapped]
        points = demos[np.arange(4), k]
        spread.append(np.linalg.norm(points - points.mean(axis=0), axis=1).max())
    assert max(spread) < 0.01, spread  # the loop is 0.30 m wide; start phases are random


def test_every_learner_makes_the_loop_attracting() -> None:
    # Trained on perfect loops (which never leave the loop), a rollout from 1-3 cm off must
    # return to within 2 mm in one period: the corrective pairs make the loop attracting.
    demos = task_loops("wiping", n_demos=3)
    loop = demos[0]
    rng = np.random.default_rng(1)
    k = rng.integers(0, N, 8)
    tangent = np.gradient(loop, axis=0)[k]
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], 1) / np.linalg.norm(tangent, axis=1)[:, None]
    x0 = loop[k] + normal * rng.choice([-1, 1], (8, 1)) * rng.uniform(0.01, 0.03, (8, 1))
    for name in ("bc", "ileed"):
        trained = train_learner(name, demos[:1], config=learner_config(name, quick=True))
        ends = trained.policy.rollout(x0, N)[:, -1]
        gaps = [np.min(np.linalg.norm(loop - end, axis=1)) for end in ends]
        assert max(gaps) < 0.002, (name, gaps)
    # Without the corrective pairs the same learner keeps its offsets (the finding).
    plain = train_learner("bc", demos[:1], config=learner_config("bc", quick=True, dart_fraction=0))
    ends = plain.policy.rollout(x0, N)[:, -1]
    assert max(np.min(np.linalg.norm(loop - end, axis=1)) for end in ends) > 0.004


def _rotation_policy(integrator: Integrator, omega: float = 2.0 * math.pi) -> LearnedPolicy:
    """The exact field ẋ = ω J x (a circle per unit time) as a policy with identity scalings."""
    net = nn.Linear(2, 2, bias=False)
    with torch.no_grad():
        net.weight.copy_(torch.tensor([[0.0, -omega], [omega, 0.0]]))
    unit = Standardiser(mean=np.zeros(2), scale=np.ones(2))
    box = np.array([[-10.0, -10.0], [10.0, 10.0]])
    return LearnedPolicy(
        net, unit, unit, box, dt=1.0 / (N - 1), state="position", integrator=integrator
    )


def test_euler_rollout_matches_its_analytic_growth_and_rk4_is_exact_on_a_rotation() -> None:
    x0 = np.array([[1.0, 0.0], [0.0, 0.5]])
    h = 1.0 / (N - 1)
    euler = _rotation_policy("euler").rollout(x0, N)
    rk4 = _rotation_policy("rk4").rollout(x0, N)
    # Euler on ẋ = ωJx multiplies the radius by sqrt(1 + (ωh)²) per step.
    growth = math.sqrt(1.0 + (2.0 * math.pi * h) ** 2) ** (N - 1)
    np.testing.assert_allclose(
        np.linalg.norm(euler[:, -1], axis=1), [growth, 0.5 * growth], rtol=1e-4
    )
    # RK4 closes the circle after one period.
    np.testing.assert_allclose(rk4[:, -1], x0, atol=1e-4)
    velocity = _rotation_policy("euler").velocity(x0)
    np.testing.assert_allclose(velocity, [[0.0, 2.0 * math.pi], [-math.pi, 0.0]], atol=1e-6)


def test_rollout_is_batched_consistently_and_validates_inputs() -> None:
    policy = _rotation_policy("euler")
    x0 = np.array([[1.0, 0.0], [0.3, -0.2]])
    together = policy.rollout(x0, 20)
    np.testing.assert_allclose(together[1], policy.rollout(x0[1], 20)[0], atol=1e-6)
    assert policy.rollout(x0, 1).shape == (2, 1, 2)
    with pytest.raises(ConfigError, match="n_samples"):
        policy.rollout(x0, 0)
    with pytest.raises(ConfigError, match="dt"):
        policy.rollout(x0, 5, dt=-1.0)
    with pytest.raises(ConfigError, match="x0"):
        policy.rollout(np.array([[np.nan, 0.0]]), 5)
    with pytest.raises(ConfigError, match="positions"):
        policy.velocity(np.zeros((3, 3)))


def test_curricula_grow_to_their_targets() -> None:
    node = NODEConfig(steps=100, stride=3, min_segment=0.02, max_segment=0.2)
    lengths = [node.segment_steps(k, N - 1) for k in range(100)]
    assert lengths[0] == 2 and lengths[-1] == 20
    assert all(a <= b for a, b in itertools.pairwise(lengths))
    assert NODEConfig(stride=3).segment_steps(0, 4) == 1  # never longer than the demo


def test_invalid_inputs_raise_errors_naming_the_problem() -> None:
    demos = ellipse_loops(n_demos=2)
    with pytest.raises(ConfigError, match="bc, traj_bc, ileed, node"):
        parse_learner("gail")
    with pytest.raises(ConfigError, match="needs a BCConfig"):
        train_learner("bc", demos, config=TrajBCConfig())
    with pytest.raises(ConfigError, match="steps"):
        BCConfig(steps=0)
    with pytest.raises(ConfigError, match="bad setting"):
        learner_config("bc", wings=2)
    with pytest.raises(ConfigError, match="horizon"):
        learner_config("traj_bc", horizon=0)
    with pytest.raises(DemoError, match=r"\(M, N, 2\)"):
        train_learner("bc", demos[0], config=tiny("bc"))
    with pytest.raises(DemoError, match="at least 22"):
        train_learner("traj_bc", demos[:, :21], config=tiny("traj_bc", horizon=20, execute=2))
    with pytest.raises(ConfigError, match="state"):
        BCConfig(state="velocity")  # type: ignore[arg-type]  # the error under test
    with pytest.raises(ConfigError, match="execute"):
        TrajBCConfig(horizon=4, execute=5)
    with pytest.raises(DemoError, match="NaN"):
        bad = demos.copy()
        bad[0, 5, 0] = np.nan
        train_learner("node", bad, config=tiny("node"))
    with pytest.raises(DemoError, match="do not vary"):
        train_learner("bc", np.ones((2, 50, 2)), config=tiny("bc"))
    with pytest.raises(ConfigError, match="one demonstrator name per demo"):
        train_learner("ileed", demos, ["a"], config=tiny("ileed"))


def test_a_still_demo_among_moving_ones_keeps_the_phase_bounded() -> None:
    demos = ellipse_loops(n_demos=3)
    demos[1] = demos[1, :1] + 1e-6 * np.random.default_rng(0).standard_normal((N, 2))
    fit = estimate_phases(demos)
    spans = (fit.phases[:, -1] - fit.phases[:, 0]) / (2 * math.pi)
    assert np.all(np.isfinite(fit.phases)) and spans.max() < N / 8 + 1
    trained = train_learner("bc", demos, config=tiny("bc"))
    assert np.all(np.isfinite(trained.policy.rollout(demos[:, 0], 20)))


def test_rk4_grid_is_torchdiffeqs_rk4_bit_for_bit_states_and_gradients() -> None:
    """NODE training's own RK4 loop against torchdiffeq's, and the detached phase against the
    phase carried through autograd: equal states and parameter gradients, not merely close."""
    from torchdiffeq import odeint

    from bt_pipeline.evaluate.learners.common import make_mlp, phase_features
    from bt_pipeline.evaluate.learners.node import _Field, rk4_grid

    demos = task_loops("weaving", n_demos=3)
    torch.manual_seed(0)
    data = prepare_demos(demos, learner_config("node"))
    net = make_mlp(data.n_features, 2, 16, 2)
    field = _Field(net, data)
    y0 = torch.cat([data.z[:32] + 0.05 * torch.randn(32, 2), data.phase[:32, None]], dim=1)
    times = torch.arange(9, dtype=torch.float32) * (4 * data.dt)

    def attached(t: torch.Tensor, y: torch.Tensor) -> torch.Tensor:  # the phase not detached
        del t
        rate = net(phase_features(y[:, :2], y[:, 2], "phase")) * field.ratio + field.offset
        return torch.cat([rate, torch.full_like(y[:, 2:], data.omega)], dim=1)

    def states_and_grads(states: object) -> list[torch.Tensor]:
        assert isinstance(states, torch.Tensor)
        net.zero_grad()
        torch.mean((states[1:, :, :2] - 0.1) ** 2).backward()
        grads = [p.grad for p in net.parameters()]
        return [states.detach().clone(), *(g.clone() for g in grads if g is not None)]

    ours = states_and_grads(rk4_grid(field.rate, y0, times))
    theirs = states_and_grads(odeint(attached, y0, times, method="rk4"))
    assert len(ours) == len(theirs) == 1 + 2 * 3
    for a, b in zip(ours, theirs, strict=True):
        assert torch.equal(a, b)
    assert ours[1].abs().sum() > 0.0  # gradients flowed


def test_clip_grad_norm_is_torchs_bit_for_bit() -> None:
    from bt_pipeline.evaluate.learners.training import clip_grad_norm

    torch.manual_seed(1)
    for scale in (1e-3, 1.0, 50.0):  # below, near and above the clipping norm
        ours = [nn.Parameter(torch.randn(5, 3)), nn.Parameter(torch.randn(7))]
        theirs = [nn.Parameter(p.detach().clone()) for p in ours]
        for a, b in zip(ours, theirs, strict=True):
            a.grad = scale * torch.randn_like(a)
            b.grad = a.grad.clone()
        norm = clip_grad_norm(ours, 1.0)
        assert torch.equal(norm, nn.utils.clip_grad_norm_(theirs, 1.0))
        clipped = [p.grad for p in ours]
        for a, b in zip(clipped, (p.grad for p in theirs), strict=True):
            assert a is not None and b is not None and torch.equal(a, b)
        total = float(np.sqrt(sum(float(torch.sum(g**2)) for g in clipped if g is not None)))
        assert total <= 1.0 + 1e-5 and (scale < 0.1) == (float(norm) < 1.0)


@pytest.mark.parametrize("short", [0.97, 0.98])
@pytest.mark.parametrize("warp", [0.0, 0.3])
def test_a_loop_that_ends_just_short_of_its_start_is_phased_as_one_loop(
    short: float, warp: float
) -> None:
    """A cleaned figure-eight whose end lies 2-3 % of the loop short of its start never returns;
    read as one loop its phase is 2-3 % long, while the spectral guess had read it 4-11 %
    long (its phase 2π landed 95 mm from its start and the rollouts left the loop)."""
    s = np.linspace(0.0, 1.0, 300)
    phase = 0.7 + 2.0 * np.pi * short * (s + warp / (2.0 * np.pi) * np.sin(2.0 * np.pi * s))
    demo = 1.4 * canonical_shape("weaving", phase)
    fit = estimate_phases(demo[None])
    loops = (fit.phases[0, -1] - fit.phases[0, 0]) / (2.0 * np.pi)
    assert abs(loops - short) < 0.035
