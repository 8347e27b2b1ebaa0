"""Take checks (bt_teleop.take_checks) on real browser takes and on takes with the features of
real use: an approach from the home pose, pauses, uneven sample times, a loop drawn off-size.

The truth for the real takes is what their recorder did (../shared/data/browser-takes/README):
careful loops are kept unflagged; the 0.4 s take, the 3 s still take, the hostile-name probes
and the tab closed after a few moves are flagged."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bt_pipeline.data.recording import read_recording
from bt_pipeline.data.shapes import canonical_loop, similarity_transform
from bt_pipeline.data.tasks import default_plane
from bt_pipeline.exceptions import ConfigError
from bt_teleop.take_checks import TakeCheckConfig, check_take, loop_share
from bt_teleop.testing import shared_dir

TAKES = shared_dir() / "data/browser-takes/wiping"
GOOD = ("alice_", "bob_", "carol_", "dave_")
JUNK = {
    "quick_": {"too_short", "no_motion", "incomplete"},
    "still_": {"no_motion", "incomplete"},
    "erin_": {"incomplete", "closed_mid_take"},
    "script-alert-1-script_": {"no_motion", "incomplete"},
}


def checked(prefix: str):
    (path,) = sorted(TAKES.glob(f"{prefix}*.hdf5"))
    recording = read_recording(path)
    demo = recording.demos["demo_0"]
    return check_take(
        demo.ee_pos,
        demo.timestamps,
        task=recording.task,
        plane=recording.plane,
        theta_deg=demo.theta_deg,
        rho=demo.rho,
        closed_mid_take="closed_mid_take" in demo.flags,
    )


@pytest.mark.skipif(
    not TAKES.is_dir(), reason="../shared/data/browser-takes is not beside the clone"
)
@pytest.mark.parametrize("prefix", GOOD)
def test_careful_browser_loops_pass(prefix: str) -> None:
    check = checked(prefix)
    assert check.ok, check.reasons()
    assert check.loop_share > 0.9


@pytest.mark.skipif(
    not TAKES.is_dir(), reason="../shared/data/browser-takes is not beside the clone"
)
@pytest.mark.parametrize("prefix", sorted(JUNK))
def test_junk_browser_takes_are_flagged_with_reasons(prefix: str) -> None:
    check = checked(prefix)
    assert JUNK[prefix] <= set(check.flags)
    assert len(check.reasons()) == len(check.flags)
    assert check.attr == ",".join(check.flags)


def realistic_take(fraction: float, seed: int = 0, scale: float = 1.0) -> tuple[np.ndarray, ...]:
    """A wiping take: approach from off the loop, `fraction` of 2 loops with a pause, uneven
    sample times, jitter, then a retreat; world positions (T, 3) and times (T,)."""
    rng = np.random.default_rng(seed)
    plane = default_plane("wiping")
    loop = similarity_transform(canonical_loop("wiping", 200), 10.0, 1.2 * scale)
    n = max(2, int(400 * fraction))
    path = np.concatenate([loop, loop])[:n]
    approach = np.linspace([0.0, -0.15], path[0], 40)
    pause = np.repeat(path[len(path) // 2][None], 30, axis=0)
    retreat = np.linspace(path[-1], [0.05, 0.12], 30)
    half = len(path) // 2
    uv = np.concatenate([approach, path[:half], pause, path[half:], retreat])
    uv = uv + rng.normal(0.0, 0.002, uv.shape)
    times = np.cumsum(rng.uniform(0.01, 0.04, len(uv)))
    world = plane.to_world(uv) + np.array([0.0, 0.0, 0.003]) * rng.normal(size=(len(uv), 1))
    return world, times


def check_realistic(fraction: float, **kwargs):
    world, times = realistic_take(fraction, **{k: v for k, v in kwargs.items() if k == "scale"})
    config = kwargs.get("config")
    return check_take(
        world,
        times,
        task="wiping",
        plane=default_plane("wiping"),
        theta_deg=10.0,
        rho=1.2,
        config=config,
    )


def test_a_real_looking_take_with_approach_pause_and_retreat_passes() -> None:
    check = check_realistic(1.0)
    assert check.ok, check.reasons()


@pytest.mark.parametrize("scale", [0.85, 1.15])
def test_a_loop_drawn_smaller_or_larger_than_the_guide_still_covers_it(scale: float) -> None:
    assert "incomplete" not in check_realistic(1.0, scale=scale).flags


def test_a_fifth_of_a_loop_is_incomplete_and_the_share_grows_with_the_take() -> None:
    shares = [check_realistic(f).loop_share for f in (0.1, 0.25, 0.4, 0.5)]
    assert shares == sorted(shares)
    assert "incomplete" in check_realistic(0.1).flags  # a fifth of one loop
    assert "incomplete" not in check_realistic(0.5).flags  # one whole loop of two


def test_straight_drags_across_the_plane_are_incomplete() -> None:
    plane = default_plane("wiping")
    uv = np.concatenate(
        [np.linspace([-0.2, -0.1], [0.2, 0.1], 100), np.linspace([0.2, -0.1], [-0.2, 0.1], 100)]
    )
    check = check_take(
        plane.to_world(uv),
        np.linspace(0.0, 4.0, 200),
        task="wiping",
        plane=plane,
        theta_deg=0.0,
        rho=1.0,
    )
    assert check.flags == ("incomplete",)
    assert check.loop_share < 0.45


def test_thresholds_are_configurable() -> None:
    strict = TakeCheckConfig(min_duration_s=60.0, min_motion_m=1.0, min_loop_share=1.0)
    flags = check_realistic(1.0, config=strict).flags
    assert {"too_short", "no_motion"} <= set(flags)
    lenient = TakeCheckConfig(min_loop_share=0.1)
    assert "incomplete" not in check_realistic(0.25, config=lenient).flags


def test_loop_share_against_the_guide_itself() -> None:
    for task in ("wiping", "weaving", "pick_and_place"):
        guide = canonical_loop(task, 240)
        assert loop_share(guide, guide) == 1.0
        assert loop_share(np.zeros((5, 2)), guide) < 0.15
        assert 0.45 <= loop_share(guide[:120], guide) <= 0.65


@pytest.mark.parametrize(
    "bad",
    [
        {"min_duration_s": -1.0},
        {"min_motion_m": math.nan},
        {"min_loop_share": 1.5},
        {"tolerance_share": 0.0},
    ],
)
def test_bad_thresholds_are_refused_by_name(bad: dict) -> None:
    with pytest.raises(ConfigError, match=next(iter(bad))):
        TakeCheckConfig(**bad)


def test_the_soak_drivers_guide_trace_passes_the_checks_and_a_circle_does_not() -> None:
    """bench_soak.py's tabs follow `guide_uv` so that their takes are scored and cleaned: a
    take of 1.2 loops of it passes every check, and the circle the soak drew before does not."""
    from bt_teleop.testing import circle_uv, guide_uv

    plane = default_plane("wiping")
    times = np.arange(0.0, 4.8, 1.0 / 50.0)
    guide = np.stack([plane.to_world(guide_uv(t)) for t in times])
    circle = np.stack([plane.to_world(circle_uv(t)) for t in times])
    kwargs = {"task": "wiping", "plane": plane, "theta_deg": 0.0, "rho": 1.0}
    assert np.allclose(guide_uv(0.0), guide_uv(4.0))  # one loop every 4 s
    assert check_take(guide, times, **kwargs).flags == ()
    assert "incomplete" in check_take(circle, times, **kwargs).flags
