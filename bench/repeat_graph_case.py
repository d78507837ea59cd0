"""Play the `track --graph` cascade case (asymmetric truth) through the node graph N times, optionally beside K busy
loops, and count the runs whose recording did not hold the whole segment (the CI failure of stop 16).

    PYTHONPATH=. .venv/bin/python bench/repeat_graph_case.py --runs 8 --busy 3 [--domain 88]

Run it from a checkout of the code to judge (a ``git worktree`` of an older commit, with ``PYTHONPATH`` on it, judges
that commit: the nodes are started from the package that is imported).
"""
from __future__ import annotations

import argparse
import multiprocessing
import os
import tempfile
import time
from pathlib import Path


def _busy(seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pass


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=4)
    ap.add_argument("--busy", type=int, default=0, help="busy loops beside the graph (load)")
    ap.add_argument("--domain", type=int, default=88)
    ap.add_argument("--timeout", type=float, default=120.0)
    args = ap.parse_args()
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="piezo_ff_roslog_"))
    from piezo_ff_ros.cli.track_graph import run_graph_case

    loads = [multiprocessing.Process(target=_busy, args=(args.runs * 60.0,), daemon=True) for _ in range(args.busy)]
    for p in loads:
        p.start()
    fails = 0
    try:
        for i in range(args.runs):
            t = time.monotonic()
            try:
                row = run_graph_case(Path(tempfile.mkdtemp()), preview=False, truth="asymmetric",
                                     domain_id=args.domain, timeout=args.timeout)
                print(f"{i} ok {time.monotonic() - t:.1f} s, rms {row['rms_error_um']:.3f} um", flush=True)
            except Exception as exc:  # noqa: BLE001 - counted and shown
                fails += 1
                print(f"{i} FAIL {time.monotonic() - t:.1f} s: {str(exc)[:300]}", flush=True)
    finally:
        for p in loads:
            p.terminate()
    print(f"failed {fails} of {args.runs}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
