"""Core chain benchmark (script, not a test): every stage and the full chain vs naive baselines, same run.

    PYTHONPATH=. .venv/bin/python bench/bench_core.py [--json FILE] [--duration 600] [--repeats 3]

Same as ``piezo-ff bench``; what is measured and how, and the naive baselines: :mod:`piezo_ff_ros.bench.throughput`
(the command line and the report: :mod:`piezo_ff_ros.cli.bench`).
"""
from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from piezo_ff_ros.cli.bench import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
