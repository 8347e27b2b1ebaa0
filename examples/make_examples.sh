#!/usr/bin/env bash
# Regenerate the bundled example recordings, recordings/examples/<task>_d1.hdf5: the paper's D1
# (4 demos, one expert-like, demonstrators θ = 5, -5, 10, -10°, ρ = 1-1.3) of each task, seed 0,
# written by the current `bt synth` (format v1 with ground truth in the truth_* attrs, each task
# on its current plane). tests/project/test_examples.py fails when they drift from the generator, and
# checks that `bt clean recordings/examples` runs without a warning.
set -euo pipefail
cd "$(dirname "$0")/.."
BT="${BT:-.venv/bin/bt}"
for task in wiping weaving pick_and_place; do
  "$BT" synth --task "$task" --demos 4 --seed 0 --overwrite --out "recordings/examples/${task}_d1.hdf5"
done
