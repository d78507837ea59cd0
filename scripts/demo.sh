#!/usr/bin/env bash
# The main job (README): set up the environment, then run the full node graph on the simulated piezotube,
# record an MCAP and print the paper's metrics (Tables I/II) from its replay analysis.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup_env.sh
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
out=${1:-out/demo}
if .venv/bin/piezo-ff demo --help >/dev/null 2>&1; then
  exec .venv/bin/piezo-ff demo --out "$out"
else
  exec .venv/bin/piezo-ff reproduce --json "$out/reproduce.json" --plots "$out/plots"
fi
