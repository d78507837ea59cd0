#!/usr/bin/env bash
# The test command (README, CI): set up the environment if needed, then run the whole suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup_env.sh
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST   # conftest sets it too; never leave DDS discovery on the LAN
exec .venv/bin/python -m pytest -q -p no:cacheprovider --durations=25 "$@"
