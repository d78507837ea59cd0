"""A point held with ``reference_point`` is recorded as what the stage was asked to do: ``/reference`` holds its
blocks (stamped like the voltage blocks that track it), and ``analyze`` reports the tracking error of the hold."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from test_nodes_integration import Probe, child_env, start_node, stop_node, wait_recorder_connected  # noqa: E402


@pytest.fixture()
def probe():
    p = Probe("held_probe")
    yield p
    p.close()


def test_held_point_is_in_the_recording_and_analyze_reports_its_tracking_error(tmp_path, probe):
    from geometry_msgs.msg import PointStamped
    from sensor_msgs.msg import PointCloud2

    from piezo_ff_ros.core.recording.mcap_io import read_run
    from piezo_ff_ros.nodes.common import BLOCK_QOS

    refs = []
    probe.node.create_subscription(PointCloud2, "reference", refs.append, BLOCK_QOS)
    mcap = tmp_path / "run.mcap"
    procs = [start_node("recorder", "-p", f"output:={mcap}", log_dir=tmp_path),
             start_node("driver", log_dir=tmp_path),
             start_node("compensator", "-p", "cascade.vibration:=false", log_dir=tmp_path)]
    try:
        wait_recorder_connected(probe, ["/voltage", "/displacement"], timeout=90)
        pub = probe.node.create_publisher(PointStamped, "reference_point", 10)
        probe.spin_until(lambda: pub.get_subscription_count() > 0, 30, "the compensator's reference_point reader")
        probe.spin_for(1.0)
        msg = PointStamped()
        msg.point.x, msg.point.y = 5e-6, -2e-6
        pub.publish(msg)
        probe.spin_until(lambda: sum(m.width for m in refs) >= 100 * 200, 60, "20000 held reference samples")
    finally:
        codes = [stop_node(p) for p in (procs[2], procs[1], procs[0])]
    assert codes == [0, 0, 0]
    run = read_run(mcap)
    assert run.reference is not None
    held = ~np.isnan(run.reference[:, 0])
    assert held.sum() >= 90 * 200   # the run spans where every topic has samples: the last blocks may fall outside
    np.testing.assert_array_equal(np.unique(run.reference[held], axis=0), [[5e-6, -2e-6]])
    r = subprocess.run([sys.executable, "-m", "piezo_ff_ros", "analyze", str(mcap)], env=child_env(),
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    line = next(ln for ln in r.stdout.splitlines() if "tracking error (whole run" in ln)
    assert "n/a" not in line, r.stdout
