#!/usr/bin/env bash
# The test command (README, CI): set up the environment if needed, then run the whole suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup_env.sh
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST   # conftest sets it too; never leave DDS discovery on the LAN
# A test whose node process stopped answering DDS (no service reply; SIGINT ignored until killed) runs once more:
# seen in about one full run in two, in a different graph test each time, never reproduced alone (a Fast DDS
# deadlock is suspected).  Every such node's Python stacks are printed at the end of the run (test/conftest.py), and
# only these two symptoms are rerun (a node's exit code -9 is stop_node's kill): any other failure fails at once.
exec .venv/bin/python -m pytest -q -p no:cacheprovider --durations=25 \
    --reruns 1 --only-rerun "waiting for reply of" --only-rerun "= stop_node\(" \
    --only-rerun "(?s)AssertionError: assert .*(?<![\w.])-9\b" "$@"
