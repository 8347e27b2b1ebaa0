#!/usr/bin/env bash
# Check a `bt export --format robomimic` file with robomimic 0.3.0 in its own venv.
#
# robomimic needs torch: the venv gets bt's pinned CPU build first (a local wheel in
# /opt/wheels on the project machine; set BT_TORCH_WHEEL elsewhere), then robomimic==0.3.0.
#
#   scripts/verify_robomimic.sh FILE [VENV]          (VENV default: /tmp/bt-robomimic-venv)
set -euo pipefail
file=${1:?usage: scripts/verify_robomimic.sh FILE [VENV]}
venv=${2:-/tmp/bt-robomimic-venv}
here=$(cd "$(dirname "$0")" && pwd)
wheel=${BT_TORCH_WHEEL:-/opt/wheels/torch-2.13.0+cpu-cp311-cp311-manylinux_2_28_x86_64.whl}
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c "import robomimic" 2>/dev/null; then
  "${BT_PYTHON311:-$(command -v python3.11 || ls "$HOME"/.pyenv/versions/3.11*/bin/python3.11 | head -1)}" -m venv "$venv"
  if [ -f "$wheel" ]; then "$venv/bin/pip" install -q "$wheel"; else "$venv/bin/pip" install -q torch; fi
  # robomimic 0.3.0 imports six without declaring it.
  "$venv/bin/pip" install -q robomimic==0.3.0 six
fi
"$venv/bin/python" "$here/check_robomimic_export.py" "$file"
