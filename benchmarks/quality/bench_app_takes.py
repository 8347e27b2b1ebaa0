"""Cleaning quality on takes recorded through the app's own session, by a scripted operator.

The human-style generator (``bench_clean_human.py``) draws its defects and its truth itself.
This benchmark checks the cleaner on data made another way: each take is recorded by
:func:`bt_teleop.session.script.run_script` through the real session (mink IK on the light FR3, the
simulation, the recorder at 50 Hz), as the app records a browser's gizmo drags, so the robot's
lag, speed limits and dynamics are in the data. The scripted operator (this file, independent of
``bt_pipeline.data.synth_human``) moves the target from a rest 4-8 cm off the loop to the loop,
draws 1-3 loops of the task's guide under its demonstrator's θ/ρ with a varying speed and one
pause, and goes back to rest; a take whose target would leave the scene's workspace box (where
the app clamps it) is drawn again before it is recorded, as an operator would shrink or turn the
loop back. Naive operators add a wobbly hand (2-3 slow sinusoids per axis,
4-12 mm in all) and, in half of the takes, a drift growing to 1-3 cm. One operator per set has a
steady hand (the expert-like take).

Truth is the operator's intended target: the guide under θ/ρ at the operator's phase, without
wobble or drift. Per naive take, after/before ratios over its loop part (the time the script
spends on the loops) of

- **shape**: ``synth_truth.shape_distance`` (Chamfer, both curves densified) of the cleaned
  output (kept span), then of the raw take, to the intended loop;
- **timing**: mean distance, at each output sample time, to the intended target at that time
  (the raw take at the same times before; both include the robot's lag);

with θ/ρ as recorded (``given``) and removed (``hidden``, the same files), and the share of
hidden estimates within 5° and 0.05, and of sets whose best demo is the steady one. Below the
table, per task: the recorded takes with clamped samples (``clamped_samples`` in the file; 0 is
expected, the draws exclude them) and the draws per recorded take.

θ is drawn in ±30°, ρ in 0.75-1.3. Wiping's and weaving's boxes hold all of that; pick-and-place's
holds its arch at ρ = 1 only for |θ| <= 4° (its places are where the block stands), so its takes
are mostly smaller, less turned loops and take more draws.

    python benchmarks/quality/bench_app_takes.py --seeds 3
    python benchmarks/quality/bench_app_takes.py --tasks pick_and_place --closing-overlap 0
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from bt_pipeline.clean import span_fit
from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.data.demo import Demo, load_demos
from bt_pipeline.data.recording import read_recording
from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.shapes import canonical_shape, similarity_transform
from bt_pipeline.data.synth_truth import ratios_against
from bt_pipeline.data.tasks import TASKS, parse_task
from bt_teleop.session.script import run_script
from bt_teleop.sim.scene import SceneModel, load_scene

_HZ = 50.0  # Waypoint rate of the scripts [Hz].
_MAX_DRAWS = 2000  # Draws of a take's preference and path before giving up.


@dataclasses.dataclass(frozen=True)
class Take:
    """One scripted take: its script and its intended path."""

    script: dict
    times: FloatArray
    """Waypoint times [s], shape (K,)."""
    intended: FloatArray
    """Intended target at those times, without wobble or drift, shape (K, 2) [m]."""
    loop_s: tuple[float, float]
    """When the operator is on the loops [s]."""


def operator_take(
    task: str, name: str, theta_deg: float, rho: float, steady: bool, rng: np.random.Generator
) -> Take:
    """A take: rest, approach, 1-3 loops with a pause, retreat, back to the rest."""
    loops = int(rng.integers(1, 4))
    period = float(rng.uniform(3.5, 6.0))
    rest_s, move_s = float(rng.uniform(0.8, 1.5)), float(rng.uniform(1.0, 1.8))
    pause_s = float(rng.uniform(0.4, 1.2))
    # Phase rate varies ±30 % (a slow and a fast stretch each loop); one pause inside the loops.
    fine = np.arange(0.0, loops * period * 1.6, 1.0 / _HZ)
    rate = 1.0 + 0.3 * np.sin(2 * math.pi * fine / period + rng.uniform(0, 2 * math.pi))
    phase = np.concatenate([[0.0], np.cumsum(rate[:-1]) / _HZ]) * 2 * math.pi / period
    pause_at = float(rng.uniform(0.2, 0.8)) * loops * 2 * math.pi
    k = int(np.searchsorted(phase, pause_at))
    phase = np.concatenate([phase[:k], np.full(round(pause_s * _HZ), phase[k]), phase[k:]])
    phase = phase[: int(np.searchsorted(phase, loops * 2 * math.pi)) + 1]
    phase[-1] = min(phase[-1], loops * 2 * math.pi)
    start = float(rng.uniform(0, 2 * math.pi))
    loop = similarity_transform(canonical_shape(parse_task(task), start + phase), theta_deg, rho)
    # The rest: 4-8 cm from the loop's first point, across the loop's direction of travel, on
    # the side away from the shape's centre (weaving's centre lies on its guide).
    tangent = loop[1] - loop[0]
    normal = np.array([-tangent[1], tangent[0]]) / (np.linalg.norm(tangent) + 1e-12)
    if float(normal @ (loop[0] - loop.mean(axis=0))) < 0.0:
        normal = -normal
    origin = loop[0] + float(rng.uniform(0.04, 0.08)) * normal
    n_rest, n_move = round(rest_s * _HZ), round(move_s * _HZ)
    ramp = 0.5 - 0.5 * np.cos(np.linspace(0.0, math.pi, n_move))[:, None]  # smooth start, stop
    intended = np.concatenate(
        [
            np.repeat(origin[None], n_rest, axis=0),
            origin + ramp * (loop[0] - origin),
            loop,
            loop[-1] + ramp * (origin - loop[-1]),
            np.repeat(origin[None], n_rest, axis=0),
        ]
    )
    times = np.arange(intended.shape[0]) / _HZ
    target = intended.copy()
    if not steady:
        for axis in range(2):
            for _ in range(int(rng.integers(2, 4))):
                amplitude = rng.uniform(0.002, 0.005)
                freq = rng.uniform(0.2, 1.2)
                target[:, axis] += amplitude * np.sin(
                    2 * math.pi * freq * times + rng.uniform(0, 7)
                )
        if rng.random() < 0.5:
            angle = rng.uniform(0, 2 * math.pi)
            drift = rng.uniform(0.01, 0.03) * (times / times[-1]) ** rng.uniform(1.0, 2.0)
            target += drift[:, None] * np.array([math.cos(angle), math.sin(angle)])
    t0 = (n_rest + n_move) / _HZ
    script = {
        "task": task,
        "demonstrator": name,
        "theta_deg": theta_deg,
        "rho": rho,
        "robot": "light",
        "waypoints": np.column_stack([times, target]).tolist(),
        "settle_s": 0.5,
    }
    return Take(script, times, intended, (t0, t0 + (loop.shape[0] - 1) / _HZ))


def measure(task: str, seed: int, root: Path) -> dict[str, list[float]]:
    """Record one set of 4 takes (one per operator, operator `seed % 4` steady) and clean it
    with θ/ρ given and hidden."""
    rng = np.random.default_rng([seed, TASKS.index(task)])  # type: ignore[arg-type]
    scene = load_scene(task)
    steady = seed % 4
    takes, files = [], []
    out: dict[str, list[float]] = {}
    for k in range(4):
        take, draws = _drawn_take(scene, f"operator{k}", k == steady, rng)
        path = run_script(take.script, root / f"{seed}-{k}")
        clamped = read_recording(path).demos["demo_0"].ep_meta["clamped_samples"]
        out.setdefault("clamped", []).append(float(clamped > 0))
        out.setdefault("draws", []).append(float(draws))
        takes.append(take)
        files.append(path)
    demos = load_demos(files)
    for label in ("given", "hidden"):
        used = demos
        if label == "hidden":
            used = [dataclasses.replace(d, theta_deg=None, rho=None) for d in demos]
        start = time.perf_counter()
        result = clean_demos(used, CleanOptions(seed=seed, progress=False))
        out.setdefault("wall_s", []).append(time.perf_counter() - start)
        out.setdefault(f"{label}_selected", []).append(float(result.best_index == steady))
        for i, (demo, take) in enumerate(zip(demos, takes, strict=True)):
            shape, timing = _ratios(demo, take, result.on_raw_times(i))
            kind = "expert" if i == steady else "naive"
            out.setdefault(f"{label}_{kind}_shape", []).append(shape)
            out.setdefault(f"{label}_{kind}_timing", []).append(timing)
            if label == "hidden":
                p = result.preferences[i]
                theta, rho = float(take.script["theta_deg"]), float(take.script["rho"])
                ok = abs(p.theta_deg - theta) < 5.0 and abs(p.rho - rho) < 0.05
                out.setdefault("hidden_ok", []).append(float(ok))
    return out


def _drawn_take(
    scene: SceneModel, name: str, steady: bool, rng: np.random.Generator
) -> tuple[Take, int]:
    """A take whose target stays in the scene's workspace box, and how many draws it took. A
    take that would leave it (the app would clamp its target) is drawn again, as an operator
    would shrink or turn the loop back; the box is convex, so checking the waypoints suffices."""
    lo, hi = scene.workspace.lo - 1e-9, scene.workspace.hi + 1e-9
    for draw in range(1, _MAX_DRAWS + 1):
        theta, rho = float(rng.uniform(-30, 30)), float(rng.uniform(0.75, 1.3))
        take = operator_take(scene.task, name, theta, rho, steady, rng)
        world = scene.plane.to_world(np.asarray(take.script["waypoints"])[:, 1:])
        if np.all(world >= lo) and np.all(world <= hi):
            return take, draw
    raise RuntimeError(f"no {scene.task} take inside the workspace in {_MAX_DRAWS} draws")


def _ratios(demo: Demo, take: Take, cleaned: tuple[FloatArray, FloatArray]) -> tuple[float, float]:
    """(shape, timing) after/before ratios of one cleaned take against its intended path."""
    raw, raw_t = demo.raw_samples()
    t_rel = raw_t - raw_t[0]  # The recording starts at the script's t = 0.
    on = (t_rel >= take.loop_s[0]) & (t_rel <= take.loop_s[1])
    intended = np.stack([np.interp(t_rel, take.times, take.intended[:, d]) for d in range(2)], 1)
    return ratios_against(intended, on, (raw, raw_t), cleaned)


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument(
        "--closing-overlap",
        type=float,
        default=span_fit._OVERLAP,
        help="least overlap [loops] a single loop's closing gap is read over (span_fit, step 3)",
    )
    args = parser.parse_args()
    span_fit._OVERLAP = args.closing_overlap
    print(
        "| task | sets | θ/ρ | naive shape (mean / worst) | naive timing (mean / worst) | "
        "expert shape / timing (worst) | best = steady | hidden θ within 5° and ρ within 0.05 |"
    )
    print("|---|---|---|---|---|---|---|---|")
    notes = []
    with tempfile.TemporaryDirectory() as tmp:
        for task in args.tasks.split(","):
            runs: dict[str, list[float]] = {}
            for seed in range(args.seeds):
                for key, values in measure(task, seed, Path(tmp)).items():
                    runs.setdefault(key, []).extend(values)
            for label in ("given", "hidden"):

                def pair(key: str, runs: dict[str, list[float]] = runs) -> str:
                    return f"{np.mean(runs[key]):.2f} / {np.max(runs[key]):.2f}"

                hidden_ok = f"{100 * np.mean(runs['hidden_ok']):.0f}%" if label == "hidden" else "—"
                print(
                    f"| {task} | {args.seeds} | {label} | {pair(f'{label}_naive_shape')} | "
                    f"{pair(f'{label}_naive_timing')} | "
                    f"{np.max(runs[f'{label}_expert_shape']):.2f} / "
                    f"{np.max(runs[f'{label}_expert_timing']):.2f} | "
                    f"{100 * np.mean(runs[f'{label}_selected']):.0f}% | {hidden_ok} |",
                    flush=True,
                )
            notes.append(
                f"{task}: {int(np.sum(runs['clamped']))} of {len(runs['clamped'])} recorded takes "
                f"clamped; {np.mean(runs['draws']):.1f} draws per take (max "
                f"{int(np.max(runs['draws']))})"
            )
    print("\n" + "\n".join(notes))


if __name__ == "__main__":
    main()
