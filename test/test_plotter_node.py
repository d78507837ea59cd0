"""The plotter node over DDS: reference, applied voltage, displacement and tracking error as PointStamped at the
plot rate, on one grid of instants stamped with the samples' own times; the Foxglove layout shows exactly them."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from test_nodes_integration import AXES, DT_NS, FS, ROOT, Probe, child_env, start_node, stop_node  # noqa: E402

from piezo_ff_ros.nodes.plotter import OUTPUTS  # noqa: E402


@pytest.fixture()
def probe():
    p = Probe("plot_probe")
    yield p
    p.close()


def test_plot_topics_from_a_driven_stage(tmp_path, probe):
    from geometry_msgs.msg import PointStamped
    from sensor_msgs.msg import PointCloud2

    from piezo_ff_ros.nodes.common import BLOCK_QOS, pack_block, stamp_to_ns, unpack_block

    got: dict[str, dict[int, list[float]]] = {t: {} for t in OUTPUTS.values()}
    for t in got:
        probe.node.create_subscription(PointStamped, t, lambda m, t=t: got[t].__setitem__(
            stamp_to_ns(m.header.stamp), [m.point.x, m.point.y, m.point.z]), 1000)
    disp: dict[int, np.ndarray] = {}
    probe.node.create_subscription(PointCloud2, "displacement", lambda m: disp.__setitem__(
        stamp_to_ns(m.header.stamp), unpack_block(m, AXES)), BLOCK_QOS)
    pub_ref = probe.node.create_publisher(PointCloud2, "reference", BLOCK_QOS)
    pub_u = probe.node.create_publisher(PointCloud2, "voltage", BLOCK_QOS)
    procs = [start_node("driver", log_dir=tmp_path), start_node("plotter", "-p", "rate:=200.0", log_dir=tmp_path)]
    try:
        probe.spin_until(lambda: pub_u.get_subscription_count() > 0 and pub_ref.get_subscription_count() > 0, 60,
                         "driver and plotter subscriptions")
        probe.spin_until(lambda: all(probe.node.count_publishers(t) > 0 for t in got), 30, "plot publishers")
        probe.spin_for(1.0)   # the writers discover this reader (volatile QoS)
        n, blocks = 300, 20   # 300-sample blocks: not a multiple of the 100-sample plot step
        k = np.arange(n * blocks)
        ref = np.column_stack([1e-6 * np.sin(2 * np.pi * k / 4000), 0.5e-6 * np.ones(k.size)])
        u = np.column_stack([40.0 * np.sin(2 * np.pi * k / 4000), 10.0 * np.ones(k.size)])
        for b in range(blocks):
            sl = slice(b * n, (b + 1) * n)
            pub_ref.publish(pack_block(ref[sl], AXES, b * n * DT_NS))
            pub_u.publish(pack_block(u[sl], AXES, b * n * DT_NS))
        # every topic has its own writer: each is waited for (the last displacement may come after the last error)
        probe.spin_until(lambda: all(len(v) >= k.size // 100 for v in got.values()), 30, "every plotted sample")
    finally:
        assert [stop_node(p) for p in procs] == [0, 0]
    stamps = sorted(got["plot_reference"])
    assert stamps == [i * 100 * DT_NS for i in range(k.size // 100)]       # 200 Hz of 20 kHz, on the sample grid
    for t in got:
        assert sorted(got[t]) == stamps, t
    d = np.vstack([disp[s] for s in sorted(disp)])
    for s in stamps:
        i = s // DT_NS
        np.testing.assert_array_equal(got["plot_reference"][s], [*ref[i], 0.0])
        np.testing.assert_array_equal(got["plot_voltage"][s], [*u[i], 0.0])
        np.testing.assert_array_equal(got["plot_displacement"][s], [*d[i], 0.0])
        np.testing.assert_array_equal(got["plot_error"][s], [*(ref[i] - d[i]), 0.0])


@pytest.mark.parametrize("arg", ["rate:=0.0", "rate:=1.0e6"])
def test_bad_rate_refused_with_one_line(arg):
    r = subprocess.run([sys.executable, "-m", "piezo_ff_ros.nodes.plotter", "--ros-args", "-p", arg],
                       env=child_env(), capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "rate" in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_foxglove_layout_plots_the_plotter_topics_with_legends_off_the_data():
    layout = json.loads((ROOT / "share" / "foxglove" / "piezo_ff.layout.json").read_text())
    topics = {f"/{t}" for t in OUTPUTS.values()}
    shown = set()
    for panel_id, cfg in layout["configById"].items():
        assert panel_id.startswith("Plot!")
        assert cfg["legendDisplay"] != "floating"            # a floating legend covers the curves
        for p in cfg["paths"]:
            topic, field = p["value"].split(".", 1)
            assert topic in topics and field in ("point.x", "point.y"), p
            shown.add(topic)
    assert shown == topics

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])
    assert sorted(leaves(layout["layout"])) == sorted(layout["configById"])
    setup = (ROOT / "setup.py").read_text()
    assert '"/foxglove", glob("share/foxglove/*.json")' in setup
