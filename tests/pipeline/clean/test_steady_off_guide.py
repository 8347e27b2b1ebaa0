"""A steady best demo that draws another loop than the guide replaces it (best_loop.py).

The sets come from the second, independent generator (``testing/operator_sets.py``: wobbly
operators and one steady one) drawing a pick-and-place arch varied as a lab would draw it
(``random_loops.draw_set_loop("varied", …)``), θ/ρ hidden. The steady operator's own loop lies
2.5-3.5 % of its size off the guide, inside the 4 % that kept the guide, but many times its own
scatter about that loop. Truth is the generator's intended path, never the cleaner's loop.
"""

from __future__ import annotations

import numpy as np
import pytest

import bt_pipeline.clean.best_loop as best_loop
from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.data.random_loops import draw_set_loop
from bt_pipeline.data.synth_truth import ratios_against
from bt_pipeline.testing.operator_sets import OperatorSet, operator_set

FAST = CleanOptions(epochs=30, progress=False, write_rrd=False)


def _wobbly_shape(synth: OperatorSet) -> tuple[str, float]:
    """The loop's source and the wobbly demos' mean shape ratio after cleaning."""
    result = clean_demos([o.demo for o in synth.demos], FAST)
    ratios = [
        ratios_against(o.intended, o.on_loop, o.demo.raw_samples(), result.on_raw_times(i))[0]
        for i, o in enumerate(synth.demos)
        if i != synth.steady_index
    ]
    assert result.loop is not None
    return result.loop.source, float(np.mean(ratios))


@pytest.mark.parametrize("seed", [0, 6])
def test_a_steady_loop_off_the_guide_replaces_it(monkeypatch, seed: int) -> None:
    synth = operator_set(
        "pick_and_place", seed, hidden=True, loop=draw_set_loop("varied", seed, "pick_and_place")
    )
    source, own = _wobbly_shape(synth)
    assert source == "learned"
    # The same set with the rule switched off keeps the guide and cleans worse (0.79 and 1.69
    # against 0.51 and 0.55 when written).
    monkeypatch.setattr(best_loop, "_STEADY_OFF", np.inf)
    kept, guided = _wobbly_shape(synth)
    assert kept == "guide"
    assert own < 0.8 * guided
