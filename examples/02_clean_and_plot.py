"""Clean a synthetic D1 set of every task and plot raw vs cleaned demos (the paper's Fig. 7).

Writes one PNG with a column per task: raw demos on top, cleaned demos below, each demo's
ground-truth shape dotted, the best (expert-like) demo drawn thicker.

    python examples/02_clean_and_plot.py --out docs/images/fig7_clean.png
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # Files only; no display needed.
import matplotlib.pyplot as plt
import tyro

from bt_pipeline.clean.pipeline import CleanOptions, clean_demos
from bt_pipeline.data.demo import demos_from_recording
from bt_pipeline.data.synth import make_d1
from bt_pipeline.data.tasks import TASKS
from bt_pipeline.evaluate.distance import distance_to_truth


@dataclass
class Args:
    out: Path = Path("docs/images/fig7_clean.png")
    """The PNG to write."""
    seed: int = 0
    """Seed of the synthetic sets and of the cleaner."""


def main(args: Args) -> None:
    fig, axes = plt.subplots(2, len(TASKS), figsize=(4.4 * len(TASKS), 9.5), squeeze=False)
    for column, task in enumerate(TASKS):
        synth = make_d1(task, args.seed)
        demos = demos_from_recording(synth.recording)
        result = clean_demos(demos, CleanOptions(seed=args.seed, progress=False))
        for row, (title, curves) in enumerate(
            (("raw", [d.positions for d in demos]), ("cleaned", list(result.positions)))
        ):
            ax = axes[row][column]
            for i, curve in enumerate(curves):
                truth = synth.demos[i].truth
                colour = f"C{i}"
                ax.plot(1e3 * truth[:, 0], 1e3 * truth[:, 1], ":", color=colour, lw=0.8)
                error = 1e3 * distance_to_truth(curve, truth)
                ax.plot(
                    1e3 * curve[:, 0],
                    1e3 * curve[:, 1],
                    color=colour,
                    lw=2.2 if i == result.best_index else 1.0,
                    label=f"{demos[i].name} ({demos[i].demonstrator}): {error:.1f} mm",
                )
            ax.set_title(f"{task}: {title}")
            ax.set_aspect("equal")
            ax.set_xlabel("u [mm]")
            ax.set_ylabel("v [mm]")
            ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=1)
    fig.suptitle(
        "Synthetic D1 sets: raw vs cleaned (thick = best demo; dotted = ground truth; "
        "legend = distance to truth)",
        fontsize=10,
    )
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(args.out)


if __name__ == "__main__":
    main(tyro.cli(Args))
