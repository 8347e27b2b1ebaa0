"""Cleaning demos of loops no guide draws, end to end: learned loop, any task name, guide sets.

Truth is the generators' (the intended path at each sample, ``truth_uv``), never the cleaner's
learned loop or references. The loops come from ``bt_pipeline.data.random_loops`` (random
Fourier curves and families no guide draws) and from a hand-made oval built here.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.cli import main
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.random_loops import draw_set_loop, family_loop
from bt_pipeline.data.recording import read_recording, write_recording
from bt_pipeline.data.records import forward_difference_actions
from bt_pipeline.data.synth_crowd import make_crowd_set
from bt_pipeline.data.synth_human import make_human_set
from bt_pipeline.data.synth_truth import ratios_against, truth_ratios
from bt_pipeline.evaluate.distance import distance_to_truth
from bt_pipeline.testing.operator_sets import operator_set

FAST = CleanOptions(epochs=30, progress=False, write_rrd=False)


def bt(*args: str) -> int:
    """Run ``bt args`` in-process; its exit code."""
    try:
        main(list(args))
    except SystemExit as stopped:
        return int(stopped.code or 0)
    return 0


def _ratios(synth, result) -> tuple[list[float], float]:
    demos = result.demos
    naive, expert = [], 1.0
    for i, record in enumerate(synth.recording.demos.values()):
        raw = demos_from_recording(synth.recording)[i].raw_samples()
        shape, _ = truth_ratios(record, raw, result.on_raw_times(i))
        if i == synth.expert_index:
            expert = shape
        else:
            naive.append(shape)
    assert len(demos) == len(synth.recording.demos)
    return naive, expert


RANDOM_SETS = [
    ("asymmetric", 2), ("d_shape", 4), ("oval", 3), ("rounded_polygon", 1), ("arch", 5),
    ("figure_eight", 6), ("stroke", 7), ("asymmetric", 8), ("oval", 9), ("d_shape", 10),
]  # fmt: skip


def test_random_loops_are_cleaned_closer_to_their_truth() -> None:
    """Human-style sets (approach, loops, pauses, retreat, uneven times, θ/ρ hidden or given)
    of ten loops no guide draws: the loop is learned in each, the expert-like demo is the best
    and kept, and the naive demos come out closer to the loops their demonstrators meant.
    Measured over the ten, as the capability stands (docs/quality.md lists the misses: single
    loops whose span takes in part of the approach or loses a side)."""
    selected, kept, naive = 0, 0, []
    for kind, seed in RANDOM_SETS:
        synth = make_human_set("stirring", 4, seed, shape=draw_set_loop(kind, seed, "stirring"))  # type: ignore[arg-type]
        result = clean_demos(demos_from_recording(synth.recording), FAST)
        assert result.loop is not None and result.loop.source == "learned", (kind, seed)
        ratios, expert = _ratios(synth, result)
        selected += result.best_index == synth.expert_index
        kept += expert <= 1.1
        naive += ratios
    assert selected >= 8, selected
    assert kept >= 7, kept
    assert float(np.median(naive)) < 0.6, naive
    assert np.mean(np.array(naive) < 1.0) >= 0.6, naive


def test_guide_shaped_sets_keep_the_guide() -> None:
    """Demos drawn on bt's own guides are measured against the guide as before: the learned
    consensus agrees with it, so nothing of the guide-based cleaning changes."""
    for task, seed in (("wiping", 0), ("weaving", 1), ("pick_and_place", 2)):
        synth = make_human_set(task, 4, seed)
        result = clean_demos(demos_from_recording(synth.recording), FAST)
        assert result.loop is not None and result.loop.source == "guide", (task, seed)
        assert result.loop.guide_misfit < 0.12


def test_an_oval_filed_as_wiping_is_cleaned_against_its_own_loop(tmp_path: Path) -> None:
    """Another lab's wiping: an oval, not bt's rounded rectangle. The cleaned file says which
    loop was used and how far the guide was off."""
    oval = draw_set_loop("oval", 1, "wiping")
    synth = make_human_set("wiping", 4, 1, shape=oval)
    path = tmp_path / "oval.hdf5"
    write_recording(path, synth.recording)
    out = tmp_path / "out"
    assert bt("clean", str(path), "--out", str(out), "--epochs", "20", "--no-rrd") == 0
    cleaned = read_recording(out / "wiping.cleaned.hdf5")
    assert cleaned.attrs["loop_source"] == "learned"
    assert float(cleaned.attrs["loop_guide_misfit"]) > 0.04
    assert len(cleaned.demos) == 4


def test_a_task_named_stirring_is_imported_scored_and_cleaned(capsys, tmp_path: Path) -> None:
    """A rhythmic task bt has no guide for: written by another tool (robomimic), imported with
    ``bt import --task stirring`` (plane fitted), scored and cleaned."""
    robomimic = pytest.importorskip("h5py")
    loop = draw_set_loop("rounded_polygon", 5, "stirring")
    synth = make_human_set("stirring", 4, 5, shape=loop)
    source = tmp_path / "theirs.hdf5"
    with robomimic.File(source, "w") as f:
        data = f.create_group("data")
        for k, record in enumerate(synth.recording.demos.values()):
            demo = data.create_group(f"demo_{k}")
            demo.create_dataset("obs/robot0_eef_pos", data=record.ee_pos)
            demo.create_dataset("actions", data=np.zeros((record.ee_pos.shape[0], 7)))
    imported = tmp_path / "stirring.hdf5"
    assert (
        bt(
            "import",
            str(source),
            "--from",
            "robomimic",
            "--task",
            "stirring",
            "--out",
            str(imported),
        )
        == 0
    )
    capsys.readouterr()
    assert read_recording(imported).task == "stirring"
    assert bt("score", str(imported), "--json") == 0
    scored = json.loads(capsys.readouterr().out)
    assert [t["task"] for t in scored["tasks"]] == ["stirring"]
    out = tmp_path / "out"
    assert bt("clean", str(imported), "--out", str(out), "--epochs", "20", "--no-rrd") == 0
    cleaned = read_recording(out / "stirring.cleaned.hdf5")
    assert cleaned.task == "stirring" and cleaned.attrs["loop_source"] == "learned"


def _human(kind: str, seed: int, n: int = 4):
    return make_human_set("stirring", n, seed, shape=draw_set_loop(kind, seed, "stirring"))  # type: ignore[arg-type]


def test_two_shapes_mixed_in_one_task_name_the_odd_demos(tmp_path: Path) -> None:
    """Demos of two different loops filed under one task: the loop is learned from the larger
    group, the others are named in a note, and every demo is still cleaned."""
    main_set, other = _human("asymmetric", 6, 4), _human("stroke", 7, 3)
    demos = demos_from_recording(main_set.recording)
    strays = demos_from_recording(other.recording)
    strays = [dataclasses.replace(d, name=f"odd_{k}") for k, d in enumerate(strays)]
    repeated = [d for d in strays if own_repeats(d) >= 2.0]
    result = clean_demos(demos + strays, FAST)
    assert result.loop is not None and result.loop.source == "learned"
    assert len(result.demos) == len(demos) + len(strays)
    assert repeated  # The strokes repeat, so they would take part in the consensus.
    note = next(n for n in result.notes if "left out of the task's learned loop" in n)
    assert all(d.label in note for d in repeated)
    assert not any(d.label in note for d in demos)


def own_repeats(demo) -> float:
    from bt_pipeline.clean.recurrence import own_loop

    found = own_loop(*demo.raw_samples())
    return found.loops if found.closes else 0.0


def test_no_demo_closes_a_loop_is_one_clear_error(capsys, tmp_path: Path) -> None:
    """Demos that each hold a fraction of a loop of a task with no guide: nothing to learn the
    loop from, so one line names the demos and the exit code is 2, as for other bad input."""
    synth = _human("oval", 8, 3)
    demos = synth.recording.demos
    for name, record in list(demos.items()):
        on = np.flatnonzero(record.attrs["truth_on_loop"])
        cycles = max(float(record.attrs["truth_cycles"]), 1.0)
        end = int(on[0] + 0.4 * (on[-1] - on[0]) / cycles)  # 0.4 of a loop, then stop.
        demos[name] = dataclasses.replace(
            record,
            ee_pos=record.ee_pos[:end],
            timestamps=record.timestamps[:end],
            actions=forward_difference_actions(record.ee_pos[:end], record.timestamps[:end]),
            attrs={},
        )
    path = tmp_path / "parts.hdf5"
    write_recording(path, synth.recording)
    capsys.readouterr()
    assert bt("clean", str(path), "--out", str(tmp_path / "out"), "--no-rrd") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert any("closes a loop of its own" in line for line in err), err
    assert not (tmp_path / "out" / "stirring.cleaned.hdf5").exists()


def test_a_single_demo_of_a_new_task_is_cleaned_against_its_own_loop() -> None:
    synth = _human("d_shape", 9, 1)
    result = clean_demos(demos_from_recording(synth.recording), FAST)
    assert result.loop is not None and result.loop.source == "learned"
    assert any("only demo" in note for note in result.notes)


@pytest.mark.parametrize("seed", [2, 5])
def test_a_majority_sharing_one_bias_does_not_outvote_the_demo_that_traced_the_guide(
    seed: int,
) -> None:
    """Three naive weaving demos go round the same lobe twice (the shared wrong lobe); their
    consensus lies ~70 % off the guide, the expert-like demo within 2 %. It stays the best demo,
    and cleaning leaves it where it was (it was cleaned to 37-44 mm when the consensus won)."""
    crowd = make_crowd_set("weaving", 4, seed)
    demos = demos_from_recording(crowd.recording)
    result = clean_demos(demos, CleanOptions(seed=seed, write_rrd=False, progress=False))
    e = crowd.expert_index
    assert result.stage1.best_index == e
    raw = distance_to_truth(demos[e].positions, crowd.demos[e].truth)
    cleaned = distance_to_truth(result.positions[e], crowd.demos[e].truth)
    assert cleaned <= 1.5 * raw + 2e-4


def test_a_single_loop_expert_keeps_its_whole_loop_against_a_lopsided_consensus() -> None:
    """A varied wiping guide (another aspect) whose consensus comes from lopsided and drifting
    multi-loop demos: the expert-like demo draws one loop after an approach, and against that
    consensus only 0.7 of it was kept, the rest of its loop taken from the consensus (46 x its
    raw error, and every naive demo cleaned towards a lopsided loop). Its span is now sought
    against its own loop too: it keeps its whole loop, and the naive demos come out closer to
    their truth than raw."""
    synth = make_human_set("wiping", 4, 4, shape=draw_set_loop("varied", 4, "wiping"))
    result = clean_demos(demos_from_recording(synth.recording), FAST)
    assert result.best_index == synth.expert_index
    assert result.segments[synth.expert_index].cycles >= 0.95
    naive, expert = _ratios(synth, result)
    assert expert <= 1.1, expert
    assert max(naive) < 1.0, naive


def test_a_thin_stroke_with_hidden_preferences_keeps_its_length() -> None:
    """Back-and-forth strokes drawn by the second generator's wobbly operators, θ/ρ hidden: each
    half of a near-line is fitted closely by a shorter stroke, and the lopsided consensus took
    the smallest of those (ρ 30-50 % small): the wobbly demos came out at 1.25 / 1.60 / 0.42 /
    3.03 of their raw error. A loop that thin keeps its plain fit (0.29 / 1.02 / 0.40 / 0.47)."""
    loop = family_loop("stroke", np.random.default_rng([0, 7]))
    ops = operator_set("wiping", 0, hidden=True, loop=loop)
    result = clean_demos([o.demo for o in ops.demos], CleanOptions(seed=0, progress=False))
    wobbly = [
        ratios_against(o.intended, o.on_loop, o.demo.raw_samples(), result.on_raw_times(i))[0]
        for i, o in enumerate(ops.demos)
        if i != ops.steady_index
    ]
    assert np.mean(wobbly) < 0.8 and max(wobbly) < 1.2, wobbly
