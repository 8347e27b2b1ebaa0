"""The ``bt`` command: one typed CLI over every job (tyro builds it from these signatures).

Results go to stdout (a table, or one JSON object with ``--json``); progress bars, warnings and
errors go to stderr. Errors bt raises on purpose print one line and exit with status 2.
"""

from __future__ import annotations

import json as jsonlib
import logging
import sys
from pathlib import Path
from typing import Annotated, Literal

import tyro

from bt_pipeline.exceptions import BtError, ConfigError

Paths = Annotated[list[str], tyro.conf.arg(metavar="PATH")]
"""Recording files, directories or glob patterns."""

log = logging.getLogger("bt")


def score(paths: tyro.conf.Positional[Paths], json: bool = False, samples: int = 300) -> None:
    """Score every demo (demo utility score, paper Eq. 8) and mark the best one per task.

    Args:
        paths: Format-v1 recordings: files, directories or glob patterns.
        json: Print one JSON object on stdout instead of tables.
        samples: N, samples per demo after resampling uniformly in time.
    """
    from bt_pipeline.data.demo import group_by_task, load_demos
    from bt_pipeline.score.utility import score_demos
    from bt_pipeline.viz.tables import print_score_tables, score_json

    demos = load_demos(paths, n_samples=samples)
    results = [score_demos(group) for group in group_by_task(demos).values()]
    if json:
        print(jsonlib.dumps(score_json(results), indent=2))
    else:
        print_score_tables(results)


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
    variant: Literal["default", "paper"] = "default",
    strict: bool = False,
    json: bool = False,
) -> None:
    """Clean every task's demos (paper Algorithm 1) and write DIR/<task>.cleaned.hdf5.

    Args:
        paths: Format-v1 recordings: files, directories or glob patterns.
        out: Output directory (created if missing). Inputs are never modified.
        rrd: Also write DIR/<task>.rrd for the Rerun viewer.
        seed: Random seed (the result is deterministic for a seed).
        epochs: Refinement epochs (default: the variant's own).
        workers: Tasks cleaned in parallel (processes).
        variant: "default" (bt's design) or "paper" (the paper's configuration, for comparison).
        strict: Stop at the first unreadable file instead of skipping it with a warning.
        json: Print one JSON summary on stdout instead of tables.
    """
    from bt_pipeline.clean.driver import clean_paths
    from bt_pipeline.clean.pipeline import CleanOptions
    from bt_pipeline.viz.tables import clean_json, print_clean_summary

    options = CleanOptions(
        seed=seed, epochs=epochs, variant=variant, write_rrd=rrd, workers=workers, strict=strict
    )
    summaries = clean_paths(paths, out, options)
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
    config = EvalConfig(learners=chosen, rollouts=rollouts, quick=quick, seed=seed, steps=steps)
    evaluations = evaluate_paths(noisy, cleaned, config, n_samples=samples)
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
    seeds: int = 1,
    workers: int = 1,
    oracle: bool = False,
) -> None:
    """Reproduce the paper's Sec. IV on synthetic D1 and D2: generate, clean, evaluate, report.

    Writes DIR/report.md (tables, the paper's numbers side by side, where cleaned beats noisy
    and where not), DIR/rewards.png (Fig. 11), DIR/<set>.<task>.rollouts.png (Figs. 8-10) and
    DIR/results.json, and prints their paths.

    Args:
        quick: The CI-sized run (learners' quick presets, 20 rollouts) instead of the full one.
        out: Output directory (created if missing; its files are replaced).
        seeds: Repeat with seeds 0 .. K-1 and report the spread over seeds too.
        workers: Jobs (set × task × seed) run in parallel processes; results do not change.
        oracle: Also train on the synthetic ground truth: the upper bound of any cleaning.
    """
    from bt_pipeline.evaluate.reproduce import reproduce as run
    from bt_pipeline.evaluate.reproduce_jobs import ReproduceConfig

    config = ReproduceConfig.preset(quick, seeds=seeds, workers=workers, oracle=oracle)
    for path in run(config, out):
        print(path)


COMMANDS = {
    "teleop": teleop,
    "score": score,
    "synth": synth,
    "clean": clean,
    "evaluate": evaluate,
    "reproduce": reproduce,
}


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``bt`` console script and ``python -m bt_pipeline``."""
    logging.basicConfig(level=logging.INFO, format="bt: %(message)s", stream=sys.stderr)
    try:
        tyro.extras.subcommand_cli_from_dict(
            COMMANDS, prog="bt", description="Beyond the Teacher: score and clean demos.", args=args
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
