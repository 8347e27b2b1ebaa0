"""``bt evaluate`` and ``bt reproduce``: parse, then dispatch to bt_pipeline.evaluate."""

from __future__ import annotations

import json as jsonlib
from pathlib import Path
from typing import Literal

from bt_pipeline.cli.args import Paths, log
from bt_pipeline.exceptions import ConfigError
from bt_pipeline.execute import ExecutorConfig, ExecutorName


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
    json_out: Path | None = None,
    quick: bool = False,
    samples: int = 300,
    steps: int | None = None,
    paper_learners: bool = False,
    workers: int = 1,
    executor: ExecutorName = "processes",
    ray_address: str | None = None,
    conditioned: bool = True,
) -> None:
    """Train imitation learners on noisy and on cleaned demos and compare their rollouts (Sec. IV).

    Per task: BC, Traj-BC, ILEED and Neural ODE are trained on each set and rolled out from
    perturbed initial states; each rollout gets the mean value-map reward R̄ (Eq. 11), the shape
    loss L4 (Eq. 9) and Ũ (Eq. 8), all measured against the noisy set's best demo
    (docs/evaluation.md). Then, per task, the same learners conditioned on each demo's θ/ρ (stated,
    else the cleaner's estimate), rolled out per demonstrator and scored against its true loop
    when the files carry the generator's truth, else against the best raw demo turned to it.

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
        json_out: Write the JSON document of --json to this file. The files of --plots, --rrd,
            --rollouts-out and --json-out appear together or not at all.
        quick: Use the learners' quick (CI-sized) presets.
        samples: N, samples per demo after resampling uniformly in time.
        steps: Override every learner's optimiser steps (smoke tests; results are not meaningful).
        paper_learners: The learners as the paper wrote them (state = 2-D position, no
            corrective data) instead of bt's (position + phase, corrective data).
        workers: Tasks evaluated in parallel (processes; with ray, the most in flight, 0: no
            limit); results do not change.
        executor: Where tasks run: "local", "processes" or "ray" (docs/scale.md).
        ray_address: Ray cluster address (with --executor ray); unset starts a local Ray.
        conditioned: Also train the conditioned learners (a second table; ``conditioned`` in
            each JSON row); --no-conditioned skips them. A task whose demos have no θ/ρ, no
            cleaner's estimate and no demonstrator keeps the unconditioned learners only.
    """
    from bt_pipeline.evaluate.driver import eval_json, evaluate_files, parse_learners, write_outputs
    from bt_pipeline.evaluate.protocol import EvalConfig
    from bt_pipeline.viz.eval_table import print_eval_table

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
    evaluations, by_demonstrator = evaluate_files(
        noisy,
        cleaned,
        config,
        n_samples=samples,
        executor=ExecutorConfig(executor, workers, ray_address),
        conditioned=conditioned,
    )
    written = write_outputs(
        evaluations,
        plots=plots,
        rrd=rrd,
        rollouts_out=rollouts_out,
        json_out=json_out,
        seed=seed,
        conditioned=by_demonstrator,
    )
    for path in written:
        log.info("wrote %s", path)
    if json:
        print(jsonlib.dumps(eval_json(evaluations, by_demonstrator), indent=2))
    else:
        print_eval_table(evaluations, conditioned=by_demonstrator)


def reproduce(
    quick: bool = False,
    out: Path = Path("reproduce"),
    seeds: int | None = None,
    workers: int = 1,
    executor: ExecutorName = "processes",
    ray_address: str | None = None,
    oracle: bool = False,
    paper_learners: bool = False,
    paper_only: bool = False,
    conditioned_seeds: int | None = None,
    crowds: tuple[Literal["independent", "shared"], ...] | None = None,
    sweeps: bool | None = None,
) -> None:
    """Reproduce the paper's Sec. IV on synthetic D1 and D2: generate, clean, evaluate, report.

    The report leads with the conditioned protocol: learners given each demonstrator's (θ, ρ),
    trained on noisy, cleaned and true demos of independent and shared-bias D1 crowds, scored
    per demonstrator against its own true loop; a truth gate and paired verdicts over seeds
    (docs/evaluation.md). The paper's protocol follows.

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
        paper_only: Only the paper's protocol (no conditioned learners).
        conditioned_seeds: Seeds of the conditioned protocol (default: 10 for the full run,
            3 with --quick; its verdicts are paired over them).
        crowds: Crowds of the conditioned protocol: independent defects, shared biases
            (default: both; shared alone with --quick).
        sweeps: Also the conditioned protocol's sweeps: 0 and 3 expert-like demos, every
            demonstrator at θ = 0, ρ = 1, and random loops (default: on for the full run, off
            with --quick).
    """
    from bt_pipeline.evaluate.crowd_sets import SWEEPS, CrowdSettings
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
    conditioned = None
    if not paper_only:
        default_seeds, per = (3, 6) if quick else (10, 12)
        kinds = crowds or (("shared",) if quick else ("independent", "shared"))
        conditioned = CrowdSettings(
            seeds=conditioned_seeds or default_seeds,
            crowds=kinds,
            per_demonstrator=per,
            sweeps=SWEEPS if (not quick if sweeps is None else sweeps) else (),
        )
    pool = ExecutorConfig(executor, workers, ray_address)
    for path in run(config, out, executor=pool, conditioned=conditioned):
        print(path)
