"""The ``bt`` command: one typed CLI over every job (tyro builds it from these signatures).

Results go to stdout (a table, or one JSON object with ``--json``); progress bars, warnings and
errors go to stderr. Errors bt raises on purpose print one line and exit with status 2.
"""

from __future__ import annotations

import json as jsonlib
import logging
import os
import sys
from pathlib import Path
from typing import Annotated, Literal

import tyro

from bt_pipeline.exceptions import BtError, ConfigError
from bt_pipeline.execute import ExecutorConfig, ExecutorName

Paths = Annotated[
    list[str], tyro.conf.arg(metavar="PATH", help_behavior_hint="(required, one or more)")
]
"""Recording files, directories or glob patterns."""
Required = tyro.conf.arg(help_behavior_hint="(required)")
"""Help hint of a required option (tyro would print "(default: )" for some)."""

log = logging.getLogger("bt")


def score(
    paths: tyro.conf.Positional[Paths],
    json: bool = False,
    samples: int = 300,
    strict: bool = False,
    max_distance: float = 10.0,
) -> None:
    """Score every demo (demo utility score, paper Eq. 8) and mark the best one per task.

    Excluded files are skipped and flagged demos listed with ⚠ but not ranked; unless --strict,
    unreadable files and demos that cannot be scored are skipped too, each with a note.

    Args:
        paths: Format-v1 recordings: files, directories or glob patterns.
        json: Print one JSON object on stdout instead of tables.
        samples: N, samples per demo after resampling uniformly in time.
        strict: Stop at the first unreadable file or unscorable demo instead of skipping it.
        max_distance: Largest distance [m] of a sample from its task plane's origin; farther is
            an error naming the demo.
    """
    from bt_pipeline.data.demo import group_by_task
    from bt_pipeline.data.limits import ReadLimits
    from bt_pipeline.data.skipping import read_usable, skip_failing
    from bt_pipeline.exceptions import DemoError
    from bt_pipeline.score.utility import score_demos
    from bt_pipeline.viz.tables import print_score_tables, score_json

    _require(paths)
    limits = ReadLimits(max_distance_m=max_distance)
    usable = read_usable(paths, samples, strict=strict, limits=limits)
    results, notes = [], list(usable.notes)
    for group in group_by_task(usable.demos).values():
        result, skipped = skip_failing(
            score_demos, group, lambda d: score_demos([d]), strict=strict
        )
        notes += skipped
        if result is not None:
            results.append(result)
    if not results and not usable.flagged:
        raise DemoError(f"no demo could be scored: {'; '.join(notes)}")
    if json:
        print(jsonlib.dumps(score_json(results, usable.flagged, notes), indent=2))
    else:
        print_score_tables(results, usable.flagged, notes)


def synth(
    out: Path,
    task: str = "wiping",
    demos: int = 4,
    seed: int = 0,
    overwrite: bool = False,
    style: Literal["single", "human"] = "single",
) -> None:
    """Write a synthetic mixed-skill demo set (one expert-like demo, the rest naive) in format v1.

    Demonstrator k % 4 has the paper's rotation θ = (5, -5, 10, -10)° and scale ρ = (1, 1.1, 1.2,
    1.3): 4 demos is the paper's D1, 20 its D2. ``--style human`` draws demos as people record
    them instead: rest, approach, 1-4 loops with pauses, retreat, uneven 30-60 Hz sample times,
    out-of-plane wobble, preferences drawn per set and hidden (NaN) in half of the seeds.
    Ground truth is stored in each demo's ``truth_*`` attrs.

    Args:
        out: Output file (.hdf5).
        task: wiping, weaving or pick_and_place.
        demos: Number of demos.
        seed: Random seed; the same seed gives the same file.
        overwrite: Replace `out` if it exists.
        style: "single" (one loop per demo, 50 Hz, known θ/ρ) or "human".
    """
    from bt_pipeline.data.recording import write_recording
    from bt_pipeline.data.synth import make_demo_set
    from bt_pipeline.data.synth_human import make_human_set
    from bt_pipeline.data.tasks import parse_task

    if style == "human":
        human = make_human_set(parse_task(task), n_demos=demos, seed=seed)
        recording, expert = human.recording, human.demos[human.expert_index].name
    else:
        single = make_demo_set(parse_task(task), n_demos=demos, seed=seed)
        recording, expert = single.recording, single.expert_name
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
    variant: Literal["default", "paper"] = "default",
    strict: bool = False,
    json: bool = False,
    max_distance: float = 10.0,
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
        variant: "default" (bt's design) or "paper" (the paper's configuration, for comparison).
        strict: Stop at the first unreadable file or unusable demo instead of skipping it.
        json: Print one JSON summary on stdout instead of tables.
        max_distance: Largest distance [m] of a sample from its task plane's origin; farther is
            an error naming the demo.
    """
    from bt_pipeline.clean.driver import clean_paths
    from bt_pipeline.clean.pipeline import CleanOptions
    from bt_pipeline.data.limits import ReadLimits
    from bt_pipeline.viz.tables import clean_json, print_clean_summary

    _require(paths)
    options = CleanOptions(
        seed=seed, epochs=epochs, variant=variant, write_rrd=rrd, workers=workers, strict=strict
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


def teleop(
    host: str = "127.0.0.1",
    port: int = 8080,
    robot: Literal["light", "menagerie"] = "light",
    recordings: Path = Path("recordings"),
    rerun: Literal["serve", "save", "off"] = "serve",
    max_sessions: int = 8,
    operator_token: str | None = None,
    script: Path | None = None,
) -> None:
    """Open the teleoperation web app: drag a target, a simulated FR3 follows; record demos.

    Args:
        host: Interface to bind. 127.0.0.1 (this machine only) unless you mean to expose it,
            e.g. 0.0.0.0 for every interface.
        port: Port of the web app (the next free one if busy; the real URL is printed).
        robot: "light" (bundled FR3 model, no download) or "menagerie" (MuJoCo Menagerie's FR3
            with meshes; downloaded once, or read from $MENAGERIE_ROOT).
        recordings: Root folder of recordings; demos go to <recordings>/<task>/.
        rerun: "serve" streams to Rerun's web viewer on localhost, "save" writes .rrd files next
            to the recordings, "off" disables Rerun.
        max_sessions: Most browser tabs at once; more get a "full, try later" message.
        operator_token: A secret (at least 8 characters); a tab that types it in the Recordings
            panel may exclude or restore anyone's demo. Without it, a tab moderates only its own
            demos. $BT_OPERATOR_TOKEN is used when the flag is not given.
        script: Run a scripted operator (JSON) without a browser: record, save, print the path.
    """
    if script is not None:
        from bt_teleop.script import run_script

        print(run_script(script, recordings))
        return
    from bt_teleop.app import AppOptions, serve

    serve(
        AppOptions(
            host=host,
            port=port,
            robot=robot,
            recordings=recordings,
            rerun=rerun,
            max_sessions=max_sessions,
            operator_token=operator_token or os.environ.get("BT_OPERATOR_TOKEN") or None,
        )
    )


def evaluate(
    noisy: Paths,
    cleaned: Paths,
    learners: str = "bc,traj_bc,ileed,node",
    rollouts: int = 50,
    seed: int = 0,
    json: bool = False,
    plots: Path | None = None,
    rrd: Path | None = None,
    rollouts_out: Path | None = None,
    quick: bool = False,
    samples: int = 300,
    steps: int | None = None,
    paper_learners: bool = False,
    workers: int = 1,
    executor: ExecutorName = "processes",
    ray_address: str | None = None,
) -> None:
    """Train imitation learners on noisy and on cleaned demos and compare their rollouts (Sec. IV).

    Per task: BC, Traj-BC, ILEED and Neural ODE are trained on each set and rolled out from
    perturbed initial states; each rollout gets the mean value-map reward R̄ (Eq. 11), the shape
    loss L4 (Eq. 9) and Ũ (Eq. 8), all measured against the noisy set's best demo
    (docs/evaluation.md).

    Args:
        noisy: Raw recordings (files, directories or glob patterns).
        cleaned: Their cleaned versions, e.g. DIR/<task>.cleaned.hdf5 from ``bt clean``.
        learners: Comma-separated learners: bc, traj_bc, ileed, node.
        rollouts: Rollouts per trained learner (paper: 50).
        seed: Seed of training and of the initial states.
        json: Print one JSON object on stdout instead of the table.
        plots: Write Figs. 8-10-style rollout plots and a Fig. 11-style bar chart (PNG) here.
        rrd: Write the rollouts and the table to this Rerun recording (.rrd).
        rollouts_out: Write each learner's rollouts here (format v1, replayable on the FR3).
        quick: Use the learners' quick (CI-sized) presets.
        samples: N, samples per demo after resampling uniformly in time.
        steps: Override every learner's optimiser steps (smoke tests; results are not meaningful).
        paper_learners: The learners as the paper wrote them (state = 2-D position, no
            corrective data) instead of bt's (position + phase, corrective data).
        workers: Tasks evaluated in parallel (processes; with ray, the most in flight, 0: no
            limit); results do not change.
        executor: Where tasks run: "local", "processes" or "ray" (docs/scale.md).
        ray_address: Ray cluster address (with --executor ray); unset starts a local Ray.
    """
    from bt_pipeline.evaluate.driver import (
        eval_json,
        evaluate_paths,
        parse_learners,
        print_eval_table,
        write_plots,
        write_rollouts,
    )
    from bt_pipeline.evaluate.protocol import EvalConfig
    from bt_pipeline.viz.rerun_eval import save_eval_rrd

    if rrd is not None and rrd.suffix != ".rrd":
        raise ConfigError(f"--rrd must end in .rrd; got {rrd}")
    chosen = parse_learners(learners)
    config = EvalConfig(
        learners=chosen,
        rollouts=rollouts,
        quick=quick,
        seed=seed,
        steps=steps,
        state="position" if paper_learners else "phase",
        corrective=not paper_learners,
    )
    evaluations = evaluate_paths(
        noisy,
        cleaned,
        config,
        n_samples=samples,
        executor=ExecutorConfig(executor, workers, ray_address),
    )
    written = []
    if plots is not None:
        written += write_plots(evaluations, plots)
    if rrd is not None:
        written.append(save_eval_rrd(evaluations, rrd))
    if rollouts_out is not None:
        written += write_rollouts(evaluations, rollouts_out, seed=seed)
    for path in written:
        log.info("wrote %s", path)
    if json:
        print(jsonlib.dumps(eval_json(evaluations), indent=2))
    else:
        print_eval_table(evaluations)


def reproduce(
    quick: bool = False,
    out: Path = Path("reproduce"),
    seeds: int | None = None,
    workers: int = 1,
    executor: ExecutorName = "processes",
    ray_address: str | None = None,
    oracle: bool = False,
    paper_learners: bool = False,
) -> None:
    """Reproduce the paper's Sec. IV on synthetic D1 and D2: generate, clean, evaluate, report.

    Writes DIR/report.md (tables, the paper's numbers side by side, where cleaned beats noisy
    and where not), DIR/rewards.png (Fig. 11), DIR/<set>.<task>.rollouts.png (Figs. 8-10) and
    DIR/results.json, and prints their paths.

    Args:
        quick: The CI-sized run (learners' quick presets, 20 rollouts) instead of the full one.
        out: Output directory (created if missing; its files are replaced).
        seeds: Repeat with seeds 0 .. K-1 and report the spread over seeds too (default: 3 for
            the full run, 1 with --quick).
        workers: Jobs (set × task × seed) run in parallel; results do not change.
        executor: Where jobs run: "local", "processes" or "ray" (docs/scale.md).
        ray_address: Ray cluster address (with --executor ray); unset starts a local Ray.
        oracle: Also train on the synthetic ground truth: the upper bound of any cleaning.
        paper_learners: The learners as the paper wrote them (2-D position, no corrective data).
    """
    from bt_pipeline.evaluate.reproduce import reproduce as run
    from bt_pipeline.evaluate.reproduce_jobs import ReproduceConfig

    overrides: dict[str, object] = {
        "workers": workers,
        "oracle": oracle,
        "paper_learners": paper_learners,
    }
    if seeds is not None:
        overrides["seeds"] = seeds
    config = ReproduceConfig.preset(quick, **overrides)
    for path in run(config, out, executor=ExecutorConfig(executor, workers, ray_address)):
        print(path)


def export(
    paths: tyro.conf.Positional[Paths],
    format: Annotated[Literal["lerobot", "robomimic"], Required],
    out: Annotated[Path, Required],
    fps: int = 50,
    task_text: Annotated[list[str], tyro.conf.arg(help_behavior_hint="(default: built-in)")] = [],  # noqa: B006
    valid_fraction: float = 0.1,
    top_k: list[int] = [3],  # noqa: B006  # tyro reads the default; never mutated
    seed: int = 0,
    overwrite: bool = False,
) -> None:
    """Export recordings (raw or cleaned) for LeRobot or robomimic (docs/interop.md).

    Args:
        paths: Format-v1 recordings: files, directories or glob patterns.
        format: "lerobot" (a LeRobotDataset v3.0 directory) or "robomimic" (one .hdf5 per task).
        out: lerobot: the dataset directory. robomimic: the .hdf5 file (one task), or a
            directory that gets <task>.robomimic.hdf5 per task.
        fps: lerobot: frame rate [Hz]; every demo is resampled to it.
        task_text: lerobot: task sentences, TASK=TEXT (or TEXT alone for one task).
        valid_fraction: robomimic: share of demos in mask/valid (seeded split).
        top_k: robomimic: write mask/top_<k>, the k demos of highest Ũ, for each k.
        seed: robomimic: seed of the split and of Stage 1's value map (the rewards).
        overwrite: Replace an existing output.
    """
    _require(paths)
    if format == "lerobot":
        from bt_pipeline.interop.export_lerobot import export_lerobot

        done = export_lerobot(paths, out, fps=fps, task_texts=task_text, overwrite=overwrite)
        print(done.root)
        log.info("%d episodes, %d frames at %d fps", done.episodes, done.frames, fps)
    else:
        from bt_pipeline.interop.export_robomimic import export_robomimic

        for written in export_robomimic(
            paths, out, valid_fraction=valid_fraction, top_k=top_k, seed=seed, overwrite=overwrite
        ):
            print(written.path)
            log.info("%d demos; filter keys %s", written.demos, ", ".join(written.masks))


def import_(
    file: tyro.conf.Positional[Annotated[Path, tyro.conf.arg(metavar="FILE")]],
    from_: Annotated[Literal["robomimic", "lerobot"], tyro.conf.arg(name="from"), Required],
    task: Annotated[str, Required],
    out: Annotated[Path, Required],
    plane: str = "auto",
    ee_key: str | None = None,
    overwrite: bool = False,
) -> None:
    """Turn another tool's demos (robomimic file, LeRobot v3.0 dataset) into a format-v1 file.

    θ and ρ are unknown (NaN) unless the file is a bt export; bt estimates them when cleaning.

    Args:
        file: The robomimic .hdf5 file or the LeRobot dataset directory.
        from_: Its format.
        task: The task its demos perform: wiping, weaving or pick_and_place.
        out: The format-v1 file to write.
        plane: "auto" (fit by PCA of the end-effector positions) or 9 numbers
            ox,oy,oz,ux,uy,uz,vx,vy,vz: the plane's origin and in-plane axes [m].
        ee_key: The end-effector position: an obs key (robomimic) or FEATURE[:START] (lerobot).
        overwrite: Replace an existing `out`.
    """
    from bt_pipeline.data.recording import write_recording
    from bt_pipeline.data.tasks import parse_task
    from bt_pipeline.interop.plane_fit import parse_plane

    chosen, given = parse_task(task), parse_plane(plane)
    if from_ == "robomimic":
        from bt_pipeline.interop.import_robomimic import read_robomimic

        recording = read_robomimic(file, chosen, given, ee_key)
    else:
        from bt_pipeline.interop.import_lerobot import read_lerobot

        recording = read_lerobot(file, chosen, given, ee_key)
    print(write_recording(out, recording, overwrite=overwrite))
    log.info("%d demos; task plane origin %s", len(recording.demos), recording.plane.origin)


def view(
    paths: tyro.conf.Positional[Paths],
    out: Path | None = None,
    serve: bool = False,
    port: int = 9090,
    web_port: int = 9091,
    samples: int = 300,
) -> None:
    """Scrub demos in time in Rerun: 3-D end-effector paths, the task plane, 2-D view, scores.

    Without --out or --serve, opens the bundled Rerun viewer.

    Args:
        paths: Format-v1 recordings (raw or cleaned): files, directories or glob patterns.
        out: Write a .rrd file instead of opening a viewer.
        serve: Serve the web viewer on 127.0.0.1 only (until Ctrl-C); prints the URL.
        port: gRPC port of --serve.
        web_port: HTTP port of --serve's web viewer.
        samples: N, samples per demo for scoring.
    """
    from bt_pipeline.viz.view import open_viewer, save_view_rrd, serve_view

    _require(paths)
    if out is not None:
        print(save_view_rrd(paths, out, n_samples=samples))
    elif serve:
        serve_view(paths, port=port, web_port=web_port, n_samples=samples)
    else:
        open_viewer(paths, n_samples=samples)


def _require(paths: list[str]) -> None:
    if not paths:
        raise ConfigError("give at least one PATH (a recording file, directory or glob pattern)")


COMMANDS = {
    "teleop": teleop,
    "score": score,
    "synth": synth,
    "clean": clean,
    "evaluate": evaluate,
    "reproduce": reproduce,
    "export": export,
    "import": import_,
    "view": view,
}


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``bt`` console script and ``python -m bt_pipeline``."""
    logging.basicConfig(level=logging.INFO, format="bt: %(message)s", stream=sys.stderr)
    argv = sys.argv[1:] if args is None else args
    if argv[:1] in (["--version"], ["-V"]):
        from importlib.metadata import PackageNotFoundError, version

        try:
            print(f"bt {version('bt')}")
        except PackageNotFoundError:  # run from a source tree that was never installed
            print("bt (not installed; source tree)")
        return
    try:
        tyro.extras.subcommand_cli_from_dict(
            COMMANDS,
            prog="bt",
            description="Beyond the Teacher: score and clean demos. `bt --version` prints the "
            "version.",
            args=args,
        )
    except (BtError, ConfigError) as error:
        print(f"bt: error: {error}", file=sys.stderr)
        raise SystemExit(2) from None
    except BrokenPipeError:
        # stdout closed early (e.g. piped into `head`): not an error of ours.
        sys.stderr.close()
        raise SystemExit(0) from None
    except KeyboardInterrupt:
        print("bt: interrupted; no partial output was written", file=sys.stderr)
        raise SystemExit(130) from None
