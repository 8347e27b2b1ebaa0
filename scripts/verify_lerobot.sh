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
# A Python 3.12: $BT_PYTHON312, else python3.12 on PATH, else a pyenv- or uv-managed one.
python=${BT_PYTHON312:-}
if [ -z "$python" ]; then
  for candidate in python3.12 "$HOME"/.pyenv/versions/3.12*/bin/python3.12 \
      "$(uv python find 3.12 2>/dev/null || true)"; do
    if [ -n "$candidate" ] && "$candidate" -c "" 2>/dev/null; then python=$candidate; break; fi
  done
fi
if [ -z "$python" ]; then
  echo "verify_lerobot.sh: no Python 3.12 found; set BT_PYTHON312 (LeRobot 0.6.1 needs >= 3.12)" >&2
  exit 2
fi
if [ ! -x "$venv/bin/python" ]; then
  "$python" -m venv "$venv"
  extra=()
  if [ -n "${BT_TORCH_INDEX:-}" ]; then extra=(--extra-index-url "$BT_TORCH_INDEX"); fi
  # bt's machine-wide pip constraints cap torch for bt's own venv; LeRobot's venv needs its own.
  PIP_CONSTRAINT= PIP_CONFIG_FILE=/dev/null "$venv/bin/pip" install -q "${extra[@]}" \
    "lerobot[dataset]==0.6.1"
fi
"$venv/bin/python" "$here/check_lerobot_export.py" "$export_dir"
