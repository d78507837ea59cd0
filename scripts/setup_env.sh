#!/usr/bin/env bash
# Create/refresh the project's .venv: pinned requirements (ROS 2 wheels included), then the package itself.
# Idempotent: requirements are reinstalled only when requirements.txt changed.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  echo "[setup] creating .venv with $($PY --version)"
  "$PY" -m venv .venv
fi
stamp=.venv/.requirements.sha
want=$(sha256sum requirements.txt | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "[setup] installing pinned requirements (one-off, ~1-2 min)"
  .venv/bin/python -m pip install -q --upgrade pip >/dev/null 2>&1 || true
  # (this machine's pip.conf lists extra local indexes that may not exist: drop pip's warnings about them)
  .venv/bin/python -m pip install -q -r requirements.txt 2> >(grep -v "^WARNING: Location" >&2)
  echo "$want" > "$stamp"
fi
# the package itself (registers it in the venv's ament index, installs console scripts and ros2-run shims)
.venv/bin/python -m pip install -q --no-deps . >/dev/null 2> >(grep -v "^WARNING: Location" >&2)
echo "[setup] ready: $(.venv/bin/python -c 'import piezo_ff_ros, sys; print("piezo_ff_ros", piezo_ff_ros.__version__, "python", sys.version.split()[0])')"
