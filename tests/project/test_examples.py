"""The bundled examples (recordings/examples) are the happy path: current, and cleaned without a
warning. Also the cause of the warning they gave: a single loop sampled up to the step before
its start was read as "does not cover a whole loop" (bt_pipeline.clean.periodic.phase_loop)."""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path

import numpy as np
import pytest

from bt_pipeline.clean.periodic import PreferenceEstimate, phase_loop, span_demo
from bt_pipeline.clean.segment import segment_demo
from bt_pipeline.data.demo import Demo, demos_from_recording
from bt_pipeline.data.recording import read_recording
from bt_pipeline.data.synth import make_demo_set
from bt_pipeline.data.tasks import TASKS
from tests.conftest import run

EXAMPLES = Path(__file__).resolve().parents[2] / "recordings" / "examples"
PROGRESS = "clean tasks:"


@pytest.mark.parametrize("task", TASKS)
def test_the_examples_are_what_the_generator_writes_now(task: str) -> None:
    """Regenerate them with examples/make_examples.sh when this fails."""
    bundled = read_recording(EXAMPLES / f"{task}_d1.hdf5")
    made = make_demo_set(task, 4, seed=0).recording
    stale = "the generator changed: run examples/make_examples.sh"
    np.testing.assert_allclose(bundled.plane.origin, made.plane.origin, err_msg=stale)
    np.testing.assert_allclose(bundled.plane.axes, made.plane.axes, err_msg=stale)
    assert list(bundled.demos) == list(made.demos)
    for name, record in made.demos.items():
        np.testing.assert_allclose(
            bundled.demos[name].ee_pos, record.ee_pos, atol=1e-12, err_msg=stale
        )
        assert "truth_uv" in bundled.demos[name].attrs  # ground truth travels with them


def test_bt_clean_on_the_examples_warns_of_nothing(
    capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture, tmp_path: Path
) -> None:
    caplog.set_level(logging.INFO)
    code, out, err = run(capsys, "clean", str(EXAMPLES), "--out", str(tmp_path), "--json")
    assert code == 0, err
    document = json.loads(out)
    assert sorted(t["task"] for t in document["tasks"]) == sorted(TASKS)
    assert [note for t in document["tasks"] for note in t["notes"]] == []
    others = [line for line in err.splitlines() if line.strip() and PROGRESS not in line]
    assert others == [], others
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING] == []


def _phase_loop(demo: Demo) -> tuple[Demo, bool]:
    """Stage 1's training loop of `demo` (segmented and spanned as bt clean does)."""
    positions, times = demo.raw_samples()
    segment = segment_demo(positions, times, demo.task, theta_deg=demo.theta_deg, rho=demo.rho)
    assert demo.theta_deg is not None and demo.rho is not None
    preference = PreferenceEstimate(demo.theta_deg, demo.rho, False, 1.0)
    return phase_loop(span_demo(demo, segment, demo.n_samples, preference), segment)


@pytest.mark.parametrize("task", TASKS)
def test_one_whole_loop_needs_no_phase_from_the_guide(task: str) -> None:
    """The expert-like demo of a single-style set draws one loop, sampled at 50 Hz up to the
    step before its start: the step back to its first sample closes it, like any other step.
    Before, the last bin of its phases (0.3 % of the loop) was taken from the guide, with the
    note "does not cover a whole loop" (weaving and pick_and_place of the bundled examples)."""
    synth = make_demo_set(task, 4, seed=0)
    expert = demos_from_recording(synth.recording)[synth.expert_index]
    loop, filled = _phase_loop(expert)
    assert not filled
    # The closing step stays on the demo: the loop's last point lies between the demo's last
    # and first samples, not on the guide.
    x = expert.positions
    gap = float(np.linalg.norm(x[-1] - x[0]))
    assert np.linalg.norm(loop.positions[-2] - x[-1]) <= gap + 1e-9


def test_a_loop_that_stops_short_still_takes_its_missing_part_from_the_guide() -> None:
    synth = make_demo_set("weaving", 4, seed=0)
    name = list(synth.recording.demos)[synth.expert_index]
    record = synth.recording.demos[name]
    keep = int(0.85 * record.num_samples)  # 15 % of the loop missing
    short = dataclasses.replace(
        record,
        ee_pos=record.ee_pos[:keep],
        timestamps=record.timestamps[:keep],
        actions=None,
        attrs={},
    )
    recording = dataclasses.replace(synth.recording, demos={name: short})
    [demo] = demos_from_recording(recording)
    _, filled = _phase_loop(demo)
    assert filled
