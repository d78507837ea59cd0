"""Test-session defaults: ROS isolation env vars are set before anything can import rclpy.

Every test session gets its own ``ROS_DOMAIN_ID`` — ``PIEZO_FF_TEST_DOMAIN`` if set, else the first domain in
1…100 whose lock file (``$TMPDIR/piezo_ff_test_domain_<id>.lock``, ``flock`` held for the whole session) no other
session holds, so two concurrent runs cannot collide — discovery restricted to this machine, and rcl logs in a
temp dir.  Data tests skip cleanly where ../shared/data is absent.
"""
from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

# Single-threaded BLAS for the session and every process it starts (nodes, CLI commands inherit the environment),
# set before anything imports numpy.  The suite's matrices are small (a 400×400 Hankel SVD, tall-thin least squares)
# and the tests run ROS node processes alongside: OpenBLAS worker threads busy-wait between calls, so on a 2-core
# machine with a second busy process a 400×400 SVD took ~30× the CPU time of the one-thread call (measured).  The
# numbers tested are the same code paths; a value set by hand in the environment wins.
for _blas_threads in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_blas_threads, "1")

import pytest  # noqa: E402  (BLAS threads set first)

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"


from piezo_ff_ros.ros.env import claim_ros_domain as claim_test_domain  # noqa: E402  (ROOT on sys.path first)


if os.environ.get("PIEZO_FF_TEST_DOMAIN"):
    # a domain given by hand is claimed too, so that an automatic claim elsewhere cannot land on it (two sessions
    # on one domain see each other's nodes: "another driver publishes on /displacement")
    # (best effort: already held — by the session that spawned this one, or by hand twice — it is used anyway)
    _DOMAIN = int(os.environ["PIEZO_FF_TEST_DOMAIN"])
    try:
        _DOMAIN, _DOMAIN_LOCK = claim_test_domain(_DOMAIN, _DOMAIN)
    except RuntimeError:
        pass
    os.environ["ROS_DOMAIN_ID"] = str(_DOMAIN)
else:
    _DOMAIN, _DOMAIN_LOCK = claim_test_domain()   # held until this process exits
    os.environ["ROS_DOMAIN_ID"] = str(_DOMAIN)
os.environ["ROS_LOG_DIR"] = tempfile.mkdtemp(prefix="piezo_ff_test_roslog_")
# H∞ designs cached for this run only (every node and command started inherits it): the first compensator on a
# configuration synthesises, the next ones load it; never the user's cache, never one from an earlier run
os.environ["PIEZO_FF_HINF_CACHE"] = tempfile.mkdtemp(prefix="piezo_ff_test_hinf_")

SHARED_DATA = Path(os.environ.get("PIEZO_FF_SHARED_DATA", ROOT.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA} (set PIEZO_FF_SHARED_DATA)")
    return SHARED_DATA


@pytest.fixture(scope="session")
def paper_config():
    from piezo_ff_ros.core.config import load_config

    return load_config(ROOT / "config" / "pt230_94.yaml")


@pytest.fixture(scope="session")
def paper_design(paper_config):
    """The H∞ design on the printed G_L (synthesised once per session)."""
    from piezo_ff_ros.core.synthesis.hinf import synthesize_hinf

    return synthesize_hinf(paper_config.dynamics.G_L, paper_config.vibration)


def _nodes_left_on_our_domain() -> dict[int, str]:
    """Node processes (``piezo_ff_ros.nodes.*`` or a node console script) still running on this session's domain."""
    found: dict[int, str] = {}
    me = os.getpid()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == me:
            continue
        try:
            cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            if "piezo_ff_ros.nodes." not in cmd and not any(f"/bin/{n} " in cmd + " " for n in _NODE_SCRIPTS):
                continue
            env = (entry / "environ").read_bytes().split(b"\0")
        except OSError:
            continue   # gone meanwhile, or not ours to read
        if f"ROS_DOMAIN_ID={_DOMAIN}".encode() in env:
            found[int(entry.name)] = cmd.strip()[:160]
    return found


_NODE_SCRIPTS = ("driver", "compensator", "trajectory", "recorder")


@pytest.fixture(autouse=True)
def _no_node_outlives_its_test():
    """A node a test leaves running keeps publishing on the session's domain and breaks later graph tests (seen:
    an orphaned lockstep trajectory). Each test must stop what it started: one that does not is an error here,
    naming the process, which is then killed so that the next tests run on a clean domain."""
    yield
    if not Path("/proc").is_dir():
        return
    import signal
    import time

    left = _nodes_left_on_our_domain()
    deadline = time.monotonic() + 10.0
    while left and time.monotonic() < deadline:   # a node may still be finishing its SIGINT shutdown
        time.sleep(0.2)
        left = _nodes_left_on_our_domain()
    if left:
        for pid in left:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass
        pytest.fail(f"node processes left running on ROS domain {_DOMAIN} after the test (killed): {left}")


def pytest_terminal_summary(terminalreporter):
    """Every node process a test had to kill because it ignored SIGINT, with the Python stacks it printed
    (test_nodes_integration.stop_node): shown even when the test passed on its rerun."""
    report = Path(os.environ["ROS_LOG_DIR"]) / "unstoppable_nodes.txt"
    if report.exists():
        terminalreporter.write_sep("=", "node processes that ignored SIGINT (killed)")
        terminalreporter.write_line(report.read_text(errors="replace"))
