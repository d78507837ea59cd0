"""The trajectory node starts playing only once a recorder on the graph has *matched* every block writer.

CI lost the first blocks of a recorded graph case: the trajectory saw the recorder's readers (discovered), played,
and a writer that had not matched them yet dropped its first blocks for the recorder. A probe stands in for the
recorder here (its ``recorder/status``, readers on the block topics) and for a voltage writer, so that what the
recorder reports is set by the test, not by DDS timing.
"""
from __future__ import annotations

import json

import pytest

rclpy = pytest.importorskip("rclpy")

from test_nodes_integration import Probe, start_node, stop_node  # noqa: E402


def test_playing_waits_until_the_recorder_matched_every_block_writer(tmp_path):
    from sensor_msgs.msg import PointCloud2
    from std_msgs.msg import String
    from std_srvs.srv import Trigger

    from piezo_ff_ros.nodes.common import BLOCK_QOS, LATCHED_QOS

    probe = Probe("fake_recorder")
    node = probe.node
    got, states = [], []
    for topic in ("/reference", "/voltage", "/displacement"):
        node.create_subscription(PointCloud2, topic, lambda m, t=topic: got.append(t), BLOCK_QOS)
    node.create_publisher(PointCloud2, "/voltage", BLOCK_QOS)          # a compensator's writer, never used
    status = node.create_publisher(String, "/recorder/status", LATCHED_QOS)
    node.create_subscription(String, "/trajectory/state", lambda m: states.append(json.loads(m.data)), LATCHED_QOS)

    def report(matched: int) -> None:
        status.publish(String(data=json.dumps({
            "recording": "x.mcap", "subscribed": ["/displacement", "/reference", "/voltage"],
            "publishers": {"/reference": matched, "/voltage": matched, "/displacement": 0}, "error": None})))

    report(0)
    traj = start_node("trajectory", "-p", "mode:=realtime", "-p", "lockstep_timeout:=3.0",
                      "-p", "trajectory:='{\"type\": \"hold\", \"value\": [0.0, 0.0], \"duration\": 0.05}'", log_dir=tmp_path)
    try:
        start = node.create_client(Trigger, "/trajectory/start")
        assert probe.call(start, Trigger.Request(), timeout=30).success
        probe.spin_until(lambda: any(s["state"] == "failed" for s in states), 30, "the unrecorded start to fail")
        error = next(s for s in states if s["state"] == "failed")["error"]
        assert "recorder not yet matched to ['/reference', '/voltage']" in error   # no writer on /displacement
        assert "/reference" not in got                                        # not one block sent

        report(1)
        n = len(states)
        assert probe.call(start, Trigger.Request(), timeout=30).success
        probe.spin_until(lambda: any(s["state"] == "finished" for s in states[n:]), 30, "the recorded run")
        assert got.count("/reference") >= 1
    finally:
        assert stop_node(traj) == 0
        probe.close()
