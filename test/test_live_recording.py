"""The recording tells which configuration produced every sample, through the graph.

The recorder stores the compensator's ``~/config`` versions in the MCAP ``piezo_ff_ros`` metadata with the sample
index where each took effect, plus ``t0_ns``, ``block_size`` and the node parameters.
"""
from __future__ import annotations

import json
import signal

import pytest

rclpy = pytest.importorskip("rclpy")

from test_live_node import Graph, held  # noqa: E402
from test_nodes_integration import DT_NS, Probe, start_node, stop_node, wait_recorder_connected  # noqa: E402

T0 = 1_000_000_000_000


@pytest.fixture()
def probe():
    p = Probe("rec_probe")
    yield p
    p.close()


def test_metadata_has_t0_block_size_parameters_and_every_configuration_version(tmp_path, probe):
    from mcap.reader import make_reader

    out = tmp_path / "run.mcap"
    from sensor_msgs.msg import PointCloud2

    from piezo_ff_ros.nodes.common import BLOCK_QOS, pack_block

    g = Graph(probe)
    g.k = T0 // DT_NS
    stray = probe.node.create_publisher(PointCloud2, "displacement", BLOCK_QOS)
    rec = start_node("recorder", "-p", f"output:={out}", "-p", f"t0_ns:={T0}", "-p", "block_size:=200",
                     log_dir=tmp_path)
    comp = start_node("compensator", "-p", "cascade.vibration:=false", "-p", "crossfade:=0.005", log_dir=tmp_path)
    try:
        g.wait_ready()
        wait_recorder_connected(probe, ["/reference", "/voltage", "/compensator/config"], timeout=60)
        probe.spin_for(1.0)
        # a stray 7-sample block stamped 0 before the run: recorded, but it sets neither t0_ns nor block_size
        probe.spin_until(lambda: stray.get_subscription_count() > 0, 30, "recorder on /displacement")
        stray.publish(pack_block(held(7), ["x", "y"], 0))
        # and one larger than any block of the contract: not recorded at all
        stray.publish(pack_block(held(100_000), ["x", "y"], 7 * DT_NS))
        probe.spin_for(0.5)
        for _ in range(10):
            g.send(held(200))
        assert g.set(cascade__creep=False)[0].successful
        for _ in range(5):
            g.send(held(200))
        for _ in range(4):   # 20 000-sample blocks (320 kB each): chunks must still stay ≤ 512 KiB
            g.send(held(20000))
        assert g.set(crossfade=0.02)[0].successful       # a node parameter: no new configuration version
        probe.spin_until(lambda: [c["version"] for c in g.configs] == [1, 2], 10, "two versions announced")
        probe.spin_for(1.0)
    finally:
        assert stop_node(comp) == 0
        rec.send_signal(signal.SIGINT)
        assert rec.wait(15) == 0
    with open(out, "rb") as f:
        reader = make_reader(f)
        meta = {}
        for m in reader.iter_metadata():
            if m.name == "piezo_ff_ros":
                meta.update(m.metadata)
        chunks = reader.get_summary().chunk_indexes
        displacement = [m.log_time for _, _, m in reader.iter_messages(topics=["/displacement"])]
    assert len(displacement) == 1   # the stray block, not the oversized one
    assert int(meta["t0_ns"]) == T0 and int(meta["block_size"]) == 200
    versions = json.loads(meta["config_versions"])
    assert [(v["version"], v["k0"]) for v in versions] == [(1, 0), (2, 10 * 200)]
    assert "creep: false" in versions[1]["config_yaml"] and "creep: true" in versions[0]["config_yaml"]
    assert versions[0]["parameters"]["crossfade"] == 0.005
    params = json.loads(meta["parameters"])
    assert params["compensator"]["crossfade"] == 0.005 and params["recorder"]["output"] == str(out)
    assert meta["config_yaml"] == versions[0]["config_yaml"]      # the live configuration, not the base file's
    assert max(c.uncompressed_size for c in chunks) <= 512 * 1024, [c.uncompressed_size for c in chunks]
