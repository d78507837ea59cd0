#!/usr/bin/env bash
# The main job (README): set up the environment, then run the full node graph on the simulated piezotube —
# the paper's experiment sequence (600 s creep records, as in the paper) through the topics in lockstep, recorded
# to out/demo/run.mcap (~0.6 GB) — and print the paper's Tables I/II from the replay analysis of that file.
# Extra arguments go to `piezo-ff demo` (e.g. --creep-duration 60 for a quicker, smaller run).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup_env.sh
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST   # the demo sets it too: DDS discovery never leaves this machine
exec .venv/bin/piezo-ff demo --out out/demo --creep-duration 600 "$@"
