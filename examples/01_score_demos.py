"""Score a synthetic mixed-skill demo set and check that selection finds the expert-like demo.

python examples/01_score_demos.py --task weaving --seed 3
"""

from __future__ import annotations

from dataclasses import dataclass

import tyro

from bt_pipeline import score_demos
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.synth import make_d2
from bt_pipeline.data.tasks import GuidedTask
from bt_pipeline.viz.tables import print_score_tables


@dataclass
class Args:
    task: GuidedTask = "wiping"
    """Task of the synthetic D2 set (20 demos, 4 demonstrators)."""
    seed: int = 0
    """Seed of the set."""


def main(args: Args) -> None:
    synth = make_d2(args.task, args.seed)
    scores = score_demos(demos_from_recording(synth.recording))
    print_score_tables([scores])
    found = scores.best_index == synth.expert_index
    print(f"expert-like demo: {synth.expert_name}; selected: {scores.best.demo.name} ({found=})")


if __name__ == "__main__":
    main(tyro.cli(Args))
