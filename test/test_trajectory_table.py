"""A table trajectory sent as a message: a block on the trajectory node's ``~/table`` becomes
``trajectory_file`` (through the same validation as a parameter change) and is played sample-exactly."""
from __future__ import annotations

import json

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from test_nodes_integration import DT_NS, Probe, start_node, stop_node  # noqa: E402

N = 6000   # 0.3 s at 20 kHz


@pytest.fixture()
def probe():
    p = Probe("table_probe")
    yield p
    p.close()


def test_table_message_is_played_sample_exactly_and_the_parameter_says_so(tmp_path, probe):
    from rcl_interfaces.srv import GetParameters
    from sensor_msgs.msg import PointCloud2
    from std_msgs.msg import String
    from std_srvs.srv import Trigger

    from piezo_ff_ros.nodes.common import BLOCK_QOS, LATCHED_QOS, pack_block, stamp_to_ns, unpack_block

    rng = np.random.default_rng(7)
    table = np.cumsum(rng.normal(0.0, 2e-8, (N, 2)), axis=0)          # a random walk: no generator makes it
    got = {}
    probe.node.create_subscription(PointCloud2, "/reference", lambda m: got.__setitem__(
        stamp_to_ns(m.header.stamp), unpack_block(m, ("x", "y"))), BLOCK_QOS)
    states = []
    probe.node.create_subscription(String, "/trajectory/state", lambda m: states.append(json.loads(m.data)),
                                   LATCHED_QOS)
    pub = probe.node.create_publisher(PointCloud2, "/trajectory/table", LATCHED_QOS)
    # fields in the order [y, x]: the node takes the columns by name
    msg = pack_block(table[:, ::-1].copy(), ["y", "x"], 0)
    traj = start_node("trajectory", "-p", "mode:=realtime", "-p", "min_subscribers:=0", "-p", "block_size:=500",
                      "-p", f"table_dir:={tmp_path / 'tables'}", log_dir=tmp_path)
    try:
        pub.publish(msg)
        get = probe.node.create_client(GetParameters, "/trajectory/get_parameters")

        def table_file():
            r = probe.call(get, GetParameters.Request(names=["trajectory_file", "trajectory"]), 30)
            return r.values[0].string_value, r.values[1].string_value

        probe.spin_until(lambda: table_file()[0].endswith(".npy"), 60, "trajectory_file set from the message")
        path, text = table_file()
        assert text == "" and path.startswith(str(tmp_path / "tables"))
        np.testing.assert_array_equal(np.load(path), table)
        assert probe.call(probe.node.create_client(Trigger, "/trajectory/start"), Trigger.Request(), 30).success
        probe.spin_until(lambda: states and states[-1]["state"] == "finished", 60, "the table played")
        probe.spin_for(0.5)
    finally:
        assert stop_node(traj) == 0
    stamps = sorted(got)
    ref = np.vstack([got[s] for s in stamps])
    assert all(b - a == DT_NS * got[a].shape[0] for a, b in zip(stamps, stamps[1:]))     # contiguous
    np.testing.assert_array_equal(ref[:N], table)                                         # bit for bit


def test_a_bad_table_message_is_refused_and_the_old_trajectory_stays(tmp_path, probe):
    from rcl_interfaces.srv import GetParameters
    from sensor_msgs.msg import PointCloud2

    from piezo_ff_ros.nodes.common import LATCHED_QOS, pack_block

    pub = probe.node.create_publisher(PointCloud2, "/trajectory/table", LATCHED_QOS)
    bad = np.full((100, 2), 1.0)           # 1 m: beyond the workspace (1e-4 m)
    traj = start_node("trajectory", "-p", "min_subscribers:=0", "-p", f"table_dir:={tmp_path}", log_dir=tmp_path)
    try:
        pub.publish(pack_block(bad, ["x", "y"], 0))
        get = probe.node.create_client(GetParameters, "/trajectory/get_parameters")
        probe.spin_until(lambda: list(tmp_path.glob("*.npy")), 60, "the table written")
        probe.spin_for(1.0)
        r = probe.call(get, GetParameters.Request(names=["trajectory_file", "trajectory"]), 30)
        assert r.values[0].string_value == "" and "circle" in r.values[1].string_value   # unchanged
    finally:
        assert stop_node(traj) == 0
    log = "\n".join(p.read_text(errors="replace") for p in tmp_path.rglob("*.log"))
    assert "~/table: refused" in log and "workspace" in log, log[-2000:]
