"""Pieces shared by the node-graph benchmarks (bench_graph.py, soak.py): process figures from /proc, a ROS domain
held for the whole run, percentiles.  No ROS import here (the ROS environment must be set before rclpy loads)."""
from __future__ import annotations

import os

import numpy as np

from piezo_ff_ros.ros.env import claim_ros_domain  # noqa: F401  (one lock-file scheme: tests, benchmarks, demo)

CLK = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    """User + system CPU time [s] of process ``pid`` so far (``/proc/<pid>/stat``)."""
    with open(f"/proc/{pid}/stat") as f:
        parts = f.read().rsplit(")", 1)[1].split()
    return (int(parts[11]) + int(parts[12])) / CLK


def rss_bytes(pid: int) -> int:
    """Resident set size [bytes] of process ``pid`` (``VmRSS`` of ``/proc/<pid>/status``)."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise ValueError(f"/proc/{pid}/status: no VmRSS line")


def have_hinf() -> bool:
    """True when the H∞ synthesis module can be imported (vibration compensation can be built)."""
    try:
        import piezo_ff_ros.core.synthesis.hinf  # noqa: F401
        return True
    except ImportError:
        return False




def percentiles_ms(seconds, digits: int = 3) -> dict:
    """``{"p50", "p99", "max", "n"}`` of a list of durations [s], in ms (``None`` values when it is empty)."""
    a = np.asarray(list(seconds), float) * 1e3
    if a.size == 0:
        return {"p50": None, "p99": None, "max": None, "n": 0}
    return {"p50": round(float(np.percentile(a, 50)), digits), "p99": round(float(np.percentile(a, 99)), digits),
            "max": round(float(a.max()), digits), "n": int(a.size)}
