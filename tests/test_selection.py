"""Selection (paper Sec. III-B step 1) finds the expert-like demo of synthetic D1 and D2 sets."""

from __future__ import annotations

import pytest

from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.synth import make_d1, make_d2
from bt_pipeline.data.tasks import TASKS
from bt_pipeline.score.utility import select_best

SEEDS = range(20)


@pytest.mark.parametrize("task", TASKS)
@pytest.mark.parametrize("make", [make_d1, make_d2], ids=["D1", "D2"])
def test_selection_picks_the_expert_in_at_least_95_percent_of_sets(task, make) -> None:
    hits = 0
    for seed in SEEDS:
        synth_set = make(task, seed)
        demos = demos_from_recording(synth_set.recording)
        hits += select_best(demos) == synth_set.expert_index
    assert hits / len(SEEDS) >= 0.95, f"{task}: expert chosen in {hits}/{len(SEEDS)} sets"
