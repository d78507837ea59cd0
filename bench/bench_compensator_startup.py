"""CPU cost of constructing the compensator node (every graph start-up pays it), with and without the H∞ cache.

Each figure is one child process (fresh Python, rclpy initialised, single-threaded BLAS as in the tests) that
constructs ``CompensatorNode`` once on the packaged configuration (the paper's tube, C(s) on) and prints the CPU
seconds of that construction — what every node process of a graph pays at start-up: ``--processes`` of them with
the H∞ design cache off (``PIEZO_FF_HINF_CACHE=off``: each synthesises), then as many sharing one fresh cache
directory (the first synthesises and stores, the next ones load).

    PYTHONPATH=. .venv/bin/python bench/bench_compensator_startup.py [--processes 3]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

_CHILD = """
import json, sys, time
import rclpy
from piezo_ff_ros.nodes.compensator import CompensatorNode
rclpy.init()
t = time.process_time()
node = CompensatorNode()
cpu = time.process_time() - t
node.destroy_node()
rclpy.shutdown()
print(json.dumps(cpu))
"""


def _construction(cache: str) -> float:
    from piezo_ff_ros.ros.env import apply_ros_env_defaults

    env = apply_ros_env_defaults(env=dict(os.environ), force_domain=True)
    env["PIEZO_FF_HINF_CACHE"] = cache
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")
    out = subprocess.run([sys.executable, "-c", _CHILD], env=env, capture_output=True, text=True, check=True,
                         timeout=600)
    return float(json.loads(out.stdout.strip().splitlines()[-1]))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--processes", type=int, default=3, help="node processes per setting (default 3)")
    args = ap.parse_args(argv)
    off = [_construction("off") for _ in range(args.processes)]
    with tempfile.TemporaryDirectory(prefix="piezo_ff_bench_hinf_") as d:
        on = [_construction(d) for _ in range(args.processes)]
    print(f"load average {os.getloadavg()[0]:.1f}; CPU seconds of one CompensatorNode construction per process "
          "(paper's tube, C(s) on)")
    print("  H∞ cache off:             " + "  ".join(f"{v:.3f}" for v in off))
    print("  H∞ cache, empty at start: " + "  ".join(f"{v:.3f}" for v in on))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
