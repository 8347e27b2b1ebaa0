"""``bt export``, ``bt import`` and ``bt view``: parse, then dispatch to the library."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import tyro

from bt_pipeline.cli.args import Paths, Required, log, require_paths


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
    require_paths(paths)
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
        task: The task its demos perform: any name of 1-64 letters, digits, '_' and '-'
            (e.g. stirring); wiping, weaving and pick_and_place have built-in guides.
        out: The format-v1 file to write.
        plane: "auto" (fit by PCA of the end-effector positions; the default for every task,
            and the way to a plane for a task without a built-in one) or 9 numbers
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
    port: int = 9878,
    web_port: int = 9092,
    samples: int = 300,
) -> None:
    """Scrub demos in time in Rerun: 3-D end-effector paths, the task plane, 2-D view, scores.

    Without --out or --serve, opens the bundled Rerun viewer (it needs a display; without one,
    use --serve and open the printed URL in a browser). A PATH ending in .rrd (bt clean's
    <task>.rrd) is shown as it is, beside the timeline of the other PATHs.

    Args:
        paths: Format-v1 recordings (raw or cleaned) and .rrd files: files, directories or glob
            patterns.
        out: Write a .rrd file instead of opening a viewer.
        serve: Serve the web viewer on 127.0.0.1 only (until Ctrl-C); prints the URL. Works
            without a display.
        port: gRPC port of --serve (a free one if busy; not Rerun's 9876, where `rerun FILE`
            looks for a viewer).
        web_port: HTTP port of --serve's web viewer (a free one if busy).
        samples: N, samples per demo for scoring.
    """
    from bt_pipeline.exceptions import ConfigError
    from bt_pipeline.viz.view import open_viewer, save_view_rrd, serve_view, split_rrd

    require_paths(paths)
    if out is not None:
        rrds, recordings = split_rrd(paths)
        if rrds:
            raise ConfigError(f"--out writes recordings' timeline; {rrds[0]} is a Rerun file")
        print(save_view_rrd(recordings, out, n_samples=samples))
    elif serve:
        serve_view(paths, port=port, web_port=web_port, n_samples=samples)
    else:
        open_viewer(paths, n_samples=samples)
