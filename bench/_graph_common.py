"""Pieces shared by the node-graph benchmarks (bench_graph.py, soak.py): process figures from /proc, a ROS domain
held for the whole run, percentiles.  No ROS import here (the ROS environment must be set before rclpy loads)."""
from __future__ import annotations

import fcntl
import os
import tempfile
from pathlib import Path

import numpy as np

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


def claim_ros_domain(first: int = 1, last: int = 100) -> tuple[int, object]:
    """A ROS domain that no test session or other benchmark holds, held while the returned file stays open.

    Same lock files as test/conftest.py (``$TMPDIR/piezo_ff_test_domain_<id>.lock``, ``flock``), so that a test
    run started during a long benchmark picks another domain.

    Returns
    -------
    domain : int
        The domain id.
    lock : file
        Keep it open for as long as the domain is used.
    """
    start = os.getpid() % (last - first + 1)
    for i in range(last - first + 1):
        domain = first + (start + i) % (last - first + 1)
        f = open(Path(tempfile.gettempdir()) / f"piezo_ff_test_domain_{domain}.lock", "a")
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            f.close()
            continue
        return domain, f
    raise RuntimeError(f"no free ROS domain in {first}…{last} (all locked by test sessions or benchmarks)")


def percentiles_ms(seconds, digits: int = 3) -> dict:
    """``{"p50", "p99", "max", "n"}`` of a list of durations [s], in ms (``None`` values when it is empty)."""
    a = np.asarray(list(seconds), float) * 1e3
    if a.size == 0:
        return {"p50": None, "p99": None, "max": None, "n": 0}
    return {"p50": round(float(np.percentile(a, 50)), digits), "p99": round(float(np.percentile(a, 99)), digits),
            "max": round(float(a.max()), digits), "n": int(a.size)}
