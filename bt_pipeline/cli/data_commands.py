"""``bt score``, ``bt synth`` and ``bt clean``: parse, then dispatch to the library."""

from __future__ import annotations

import dataclasses
import json as jsonlib
from pathlib import Path
from typing import Annotated, Literal

import tyro

from bt_pipeline.cli.args import Paths, log, require_paths
from bt_pipeline.data.random_loops import LoopKind
from bt_pipeline.execute import ExecutorConfig, ExecutorName


def score(
    paths: tyro.conf.Positional[Paths],
    json: bool = False,
    samples: int = 300,
    strict: bool = False,
    max_distance: float = 10.0,
    whole_demos: bool = False,
    theta_max: float = 45.0,
    rho_min: float = 0.5,
    rho_max: float = 2.0,
) -> None:
    """Score every demo (demo utility score, paper Eq. 8) and mark the best one per task.

    Each demo is scored on its periodic part (its rest, approach and retreat left out), and the
    best demo is the one ``bt clean`` picks: the highest Ũ among the demos that follow the task's
    guide about as closely as any (docs/refinement.md). Excluded files are skipped and flagged
    demos listed with ⚠ but not ranked; unless --strict, unreadable files and demos that cannot
    be scored are skipped too, each with a note.

    Args:
        paths: Format-v1 recordings: files, directories or glob patterns.
        json: Print one JSON object on stdout instead of tables.
        samples: N, samples per demo after resampling uniformly in time.
        strict: Stop at the first unreadable file or unscorable demo instead of skipping it.
        max_distance: Largest distance [m] of a sample from its task plane's origin; farther is
            an error naming the demo.
        whole_demos: Score each whole recording with Eqs. (3)-(8) as written and pick the
            highest Ũ (the paper's selection), without finding its periodic part.
        theta_max: Largest |θ| [deg] read from a demo whose file lacks θ/ρ (NaN).
        rho_min: Smallest ρ read from such a demo.
        rho_max: Largest ρ read from such a demo.
    """
    from bt_pipeline.clean.guide_fit import PreferenceRange
    from bt_pipeline.clean.selection import Selection
    from bt_pipeline.clean.skipping import select_skipping
    from bt_pipeline.data.demo import group_by_task
    from bt_pipeline.data.limits import ReadLimits
    from bt_pipeline.data.skipping import read_usable, skip_failing
    from bt_pipeline.exceptions import DemoError
    from bt_pipeline.score.utility import TaskScores, score_demos
    from bt_pipeline.viz.tables import print_score_tables, score_json

    require_paths(paths)
    allowed = PreferenceRange(theta_max, rho_min, rho_max)
    limits = ReadLimits(max_distance_m=max_distance)
    usable = read_usable(paths, samples, strict=strict, limits=limits)
    results: list[TaskScores] = []
    selections: dict[str, Selection] = {}
    notes = list(usable.notes)
    for group in group_by_task(usable.demos).values():
        if whole_demos:
            scores, skipped = skip_failing(
                score_demos, group, lambda d: score_demos([d]), strict=strict
            )
        else:
            selection, skipped = select_skipping(group, allowed, strict=strict)
            scores = None if selection is None else selection.scores
            if selection is not None:
                selections[selection.scores.task] = selection
        notes += skipped
        if scores is not None:
            results.append(scores)
    if not results and not usable.flagged:
        raise DemoError(f"no demo could be scored: {'; '.join(notes)}")
    if json:
        print(jsonlib.dumps(score_json(results, usable.flagged, notes, selections), indent=2))
    else:
        print_score_tables(results, usable.flagged, notes, selections)


def synth(
    out: Path,
    task: str = "wiping",
    demos: int = 4,
    seed: int = 0,
    overwrite: bool = False,
    style: Literal["single", "human"] = "single",
    shape: LoopKind = "guide",
    shape_seed: int | None = None,
    crowd: Literal["independent", "shared"] = "independent",
    experts: Annotated[int | None, tyro.conf.arg(help_behavior_hint="(default: 1)")] = None,
    same_preference: bool = False,
) -> None:
    """Write a synthetic mixed-skill demo set (one expert-like demo, the rest naive) in format v1.

    Demonstrator k % 4 has the paper's rotation θ = (5, -5, 10, -10)° and scale ρ = (1, 1.1, 1.2,
    1.3): 4 demos is the paper's D1, 20 its D2. ``--style human`` draws demos as people record
    them instead: rest, approach, 1-4 loops with pauses, retreat, uneven 30-60 Hz sample times,
    out-of-plane wobble, preferences drawn per set and hidden (NaN) in half of the seeds.
    Ground truth is stored in each demo's ``truth_*`` attrs.

    ``--shape`` other than guide draws one intended loop for the set (bt_pipeline.data.
    random_loops) and every demonstrator draws it under their own θ/ρ; the loop is stored in the
    file's env_kwargs (shape, shape_coefficients, shape_kind, shape_seed) and the truth is that
    loop.

    ``--crowd shared`` (single style) makes the naive demos share their biases instead of drawing
    defects independently: the same corner cut, the same undershot stretch, a pause at the same
    place, one demonstrator drawing backwards, the same bulged side, a drift the same way, the
    same wrong lobe of a loop that crosses itself, the same part left out
    (bt_pipeline.data.synth_crowd); ``--experts`` sets how many demos are expert-like and
    ``--same-preference`` has every demonstrator draw at θ = 0, ρ = 1.

    Args:
        out: Output file (.hdf5).
        task: wiping, weaving or pick_and_place (the tasks with a built-in guide shape); with a
            --shape other than guide or varied, any task name (it works in wiping's plane).
        demos: Number of demos.
        seed: Random seed; the same seed gives the same file.
        overwrite: Replace `out` if it exists.
        style: "single" (one loop per demo, 50 Hz, known θ/ρ) or "human".
        shape: The loop the set draws: "guide" (the task's own), "varied" (the guide as a lab
            would vary it), "random" (a loop of a random family) or a family: oval,
            rounded_polygon, d_shape, figure_eight, arch, stroke, asymmetric.
        shape_seed: Seed the loop is drawn from (default: --seed).
        crowd: "independent" (each naive demo its own defects) or "shared" (the naive demos share
            biases; single style only).
        experts: Expert-like demos in a --crowd shared set, 0..--demos.
        same_preference: In a --crowd shared set, every demonstrator draws at θ = 0, ρ = 1 (an
            ablation: the crowd shares one preference).
    """
    from bt_pipeline.data.random_loops import draw_set_loop
    from bt_pipeline.data.recording import write_recording
    from bt_pipeline.data.synth import make_demo_set
    from bt_pipeline.data.synth_crowd import make_crowd_set
    from bt_pipeline.data.synth_human import make_human_set
    from bt_pipeline.exceptions import ConfigError

    if crowd == "shared" and style == "human":
        raise ConfigError(
            "--crowd shared is not supported with --style human yet; use --style single"
        )
    if experts is not None and crowd != "shared":
        raise ConfigError("--experts needs --crowd shared (the independent sets have one expert)")
    if same_preference and crowd != "shared":
        raise ConfigError(
            "--same-preference needs --crowd shared (the independent sets keep the paper's θ/ρ)"
        )
    loop_seed = seed if shape_seed is None else shape_seed
    loop = None if shape == "guide" else draw_set_loop(shape, loop_seed, task)
    if style == "human":
        human = make_human_set(task, n_demos=demos, seed=seed, shape=loop)
        recording, expert = human.recording, human.demos[human.expert_index].name
    elif crowd == "shared":
        shared = make_crowd_set(
            task,
            demos,
            seed,
            experts=1 if experts is None else experts,
            shape=loop,
            same_preference=same_preference,
        )
        names = [d.name for d in shared.demos if d.is_expert]
        recording, expert = shared.recording, ", ".join(names) or "none"
    else:
        single = make_demo_set(task, n_demos=demos, seed=seed, shape=loop)
        recording, expert = single.recording, single.expert_name
    if loop is not None:
        kwargs = {**recording.env_args["env_kwargs"], "shape_kind": shape, "shape_seed": loop_seed}
        env_args = {**recording.env_args, "env_kwargs": kwargs}
        recording = dataclasses.replace(recording, env_args=env_args)
        log.info("intended loop: %s (%.3f m)", loop.label, loop.size_m)
    path = write_recording(out, recording, overwrite=overwrite)
    print(path)
    log.info("expert-like demo: %s", expert)


def clean(
    paths: tyro.conf.Positional[Paths],
    out: Path,
    rrd: bool = True,
    seed: int = 0,
    epochs: int | None = None,
    workers: int = 1,
    executor: ExecutorName = "processes",
    ray_address: str | None = None,
    chunk_size: int = 256,
    variant: Literal["default", "paper"] = "default",
    strict: bool = False,
    json: bool = False,
    max_distance: float = 10.0,
    theta_max: float = 45.0,
    rho_min: float = 0.5,
    rho_max: float = 2.0,
) -> None:
    """Clean every task's demos (paper Algorithm 1) and write DIR/<task>.cleaned.hdf5.

    Excluded files and flagged demos are skipped; unless --strict, so are unreadable files and
    demos that cannot be cleaned (no motion, not periodic), each with a note naming it. The
    outputs of a run appear together (staged, then published; DIR/bt-outputs.json lists them).

    Args:
        paths: Format-v1 recordings: files, directories or glob patterns.
        out: Output directory (created if missing). Inputs are never modified.
        rrd: Also write DIR/<task>.rrd for the Rerun viewer.
        seed: Random seed (the result is deterministic for a seed).
        epochs: Refinement epochs (default: the variant's own).
        workers: Tasks cleaned in parallel (processes; with ray, the most in flight, 0: no limit).
        executor: Where tasks run: "local" (this process), "processes" or "ray" (docs/scale.md).
        ray_address: Ray cluster address (with --executor ray); unset starts a local Ray.
        chunk_size: K, most demos refined by one network: a larger task's Stage 2 runs in chunks
            of at most K demos sharing its Stage 1, each chunk a job of the executor (bounded
            memory; docs/scale.md). Results depend on K, not on the executor.
        variant: "default" (bt's design) or "paper" (the paper's configuration, for comparison).
        strict: Stop at the first unreadable file or unusable demo instead of skipping it.
        json: Print one JSON summary on stdout instead of tables.
        max_distance: Largest distance [m] of a sample from its task plane's origin; farther is
            an error naming the demo.
        theta_max: Largest |θ| [deg] read from a demo whose file lacks θ/ρ (NaN).
        rho_min: Smallest ρ read from such a demo.
        rho_max: Largest ρ read from such a demo.
    """
    from bt_pipeline.clean.driver import clean_paths
    from bt_pipeline.clean.guide_fit import PreferenceRange
    from bt_pipeline.clean.pipeline import CleanOptions
    from bt_pipeline.data.limits import ReadLimits
    from bt_pipeline.viz.tables import clean_json, print_clean_summary

    require_paths(paths)
    options = CleanOptions(
        seed=seed,
        epochs=epochs,
        variant=variant,
        write_rrd=rrd,
        workers=workers,
        strict=strict,
        chunk_size=chunk_size,
        preference_range=PreferenceRange(theta_max, rho_min, rho_max),
    )
    summaries = clean_paths(
        paths,
        out,
        options,
        ReadLimits(max_distance_m=max_distance),
        ExecutorConfig(executor, workers, ray_address),
    )
    if json:
        print(jsonlib.dumps(clean_json(summaries), indent=2))
    else:
        print_clean_summary(summaries)
