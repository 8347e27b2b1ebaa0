#!/usr/bin/env bash
# Check a `bt export --format lerobot` dataset with LeRobot's own LeRobotDataset (lerobot 0.6.1).
#
# LeRobot needs Python >= 3.12 and torch < 2.12, so it gets its own venv (never bt's). The first
# run installs lerobot[dataset]==0.6.1 there (torch comes from PyPI: a few GB with its CUDA
# libraries; set BT_TORCH_INDEX to a CPU wheel index to avoid that). Later runs reuse the venv.
#
#   scripts/verify_lerobot.sh EXPORT_DIR [VENV]      (VENV default: /tmp/bt-lerobot-venv)
set -euo pipefail
export_dir=${1:?usage: scripts/verify_lerobot.sh EXPORT_DIR [VENV]}
venv=${2:-/tmp/bt-lerobot-venv}
here=$(cd "$(dirname "$0")" && pwd)
python=${BT_PYTHON312:-python3.12}
if [ ! -x "$venv/bin/python" ]; then
  "$python" -m venv "$venv"
  extra=()
  if [ -n "${BT_TORCH_INDEX:-}" ]; then extra=(--extra-index-url "$BT_TORCH_INDEX"); fi
  # bt's machine-wide pip constraints cap torch for bt's own venv; LeRobot's venv needs its own.
  PIP_CONSTRAINT= PIP_CONFIG_FILE=/dev/null "$venv/bin/pip" install -q "${extra[@]}" \
    "lerobot[dataset]==0.6.1"
fi
"$venv/bin/python" "$here/check_lerobot_export.py" "$export_dir"
