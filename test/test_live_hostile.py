"""A hostile peer on the same ROS domain (own publishers, own packing, the parameter services) against a running
driver + compensator, through real DDS: every bad message or parameter is refused with one line and counted, the
nodes stay up, nothing pins the voltage at the limit or poisons the compensator, and the driver is never locked out.
"""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from test_live_node import Graph, held  # noqa: E402
from test_nodes_integration import AXES, DT_NS, Probe, child_env, start_node, stop_node  # noqa: E402

N = 200


@pytest.fixture()
def probe():
    p = Probe("hostile_probe")
    yield p
    p.close()


def _level(status) -> int:
    return ord(status.level) if isinstance(status.level, bytes) else int(status.level)


def _driver_diags(probe):
    from diagnostic_msgs.msg import DiagnosticArray

    out = []
    probe.node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: out.extend(
        {kv.key: kv.value for kv in s.values} | {"_level": _level(s), "_message": s.message}
        for s in m.status if s.name.endswith("/driver")), 10)
    return out


def test_compensator_with_its_driver_refuses_what_would_pin_or_poison_it(tmp_path, probe):
    from geometry_msgs.msg import PointStamped
    from sensor_msgs.msg import PointCloud2

    from piezo_ff_ros.nodes.common import BLOCK_QOS, pack_block

    g = Graph(probe)
    ddiags = _driver_diags(probe)
    applied_sub = probe.node.create_subscription(PointCloud2, "voltage_applied", lambda m: None, BLOCK_QOS)
    point = probe.node.create_publisher(PointStamped, "reference_point", 10)
    drv = start_node("driver", "-p", "limits.stale_timeout:=5.0", log_dir=tmp_path)
    comp = start_node("compensator", "-p", "cascade.vibration:=false", log_dir=tmp_path)
    try:
        g.wait_ready()
        probe.spin_until(lambda: applied_sub.get_publisher_count() > 0 and g.pub_applied.get_subscription_count()
                         > 0, 30, "the driver's voltage_applied")
        probe.spin_for(1.0)
        base_k = 10**6 * N
        g.k = base_k
        for _ in range(5):
            g.send(held(N))
        # one sample of 1e308 m, a 1e10 m block: refused, nothing published for them
        bad = held(N)
        bad[7, 0] = 1e308
        s_bad = g.send(bad, wait=False)
        s_big = g.send(held(N, 1e10, 1e10), wait=False)
        d = g.diag_after(lambda d: int(d.get("rejected_blocks", 0)) >= 2, "refused reference blocks")
        assert d["_level"] == 2 and "reference_limit" in d["_message"], d["_message"]
        # a 1 m held point: refused, the previous (none) stays
        msg = PointStamped()
        msg.point.x = 1.0
        point.publish(msg)
        g.diag_after(lambda d: int(d.get("rejected_blocks", 0)) >= 3, "refused reference_point")
        # a hostile voltage_applied (not from the paired driver): NaN, then 1e10 V
        stamp = g.send(held(N))
        g.pub_applied.publish(pack_block(np.full((N, 2), np.nan), AXES, stamp))
        g.pub_applied.publish(pack_block(np.full((N, 2), 1e10), AXES, stamp))
        d = g.diag_after(lambda d: int(d.get("applied_rejected", 0)) >= 2, "refused voltage_applied")
        assert d["_level"] >= 1
        # exactly those two: the paired driver's own blocks are used (tracked and confirmed), never refused
        assert d["applied_rejected"] == "2" and int(d["applied_blocks"]) > 0, d
        # the reference is back at 10 µm (≈ 64 V): the voltages are finite and off the limit, no reset needed
        for _ in range(20):
            g.send(held(N))
        assert s_bad not in g.volts and s_big not in g.volts
        tail = np.vstack([g.volts[s] for s in sorted(g.volts)[-20:]])
        assert np.all(np.isfinite(tail)) and np.max(np.abs(tail)) < 100.0, np.max(np.abs(tail))
        dd = [x for x in ddiags if "saturated_samples" in x]
        probe.spin_until(lambda: len(ddiags) > len(dd) + 1, 10, "driver diagnostics")
        assert ddiags[-1]["saturated_samples"] == "0" and "nan" not in ddiags[-1]["applied_voltage"].lower()
        # malformed blocks: width 0, an oversized one (refused before its data is read), off the grid
        empty = pack_block(held(1), AXES, g.k * DT_NS)
        empty.width, empty.row_step, empty.data = 0, 0, b""
        g.pub.publish(empty)
        huge = pack_block(np.zeros((100_000, 2)), AXES, g.k * DT_NS)
        g.pub.publish(huge)
        g.pub.publish(pack_block(held(N), AXES, g.k * DT_NS + 1))
        n0 = int(d["rejected_blocks"])
        d = g.diag_after(lambda d: int(d.get("rejected_blocks", 0)) >= n0 + 3, "three malformed blocks refused")
        # a stray stamp far in the future: a jump, not 1e14 lost samples
        g.pub.publish(pack_block(held(N), AXES, (g.k + 10**12) * DT_NS))
        g.send(held(N))
        d = g.diag_after(lambda d: int(d.get("input_jumps", 0)) >= 1, "a counted jump")
        assert int(d["input_gap_samples"]) < 10 * N, d["input_gap_samples"]
        # YAML bombs in config_yaml: refused with one line, the service answers, the node keeps working
        deep = "{a: " * 1000 + "1" + "}" * 1000     # 5 kB, 1000 levels
        bomb = 'a0: &a0 ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]\n' + "".join(
            f"a{i}: &a{i} [" + ",".join([f"*a{i - 1}"] * 9) + "]\n" for i in range(1, 10))
        for text in (deep, bomb, "x: '" + "a" * (8 << 20) + "'"):
            r = g.set(config_yaml=text)[0]
            assert not r.successful and r.reason.startswith("config_yaml:") and "\n" not in r.reason, r.reason
        g.send(held(N))
        assert comp.poll() is None and drv.poll() is None
    finally:
        assert stop_node(comp) == 0
        assert stop_node(drv) == 0
    log = (tmp_path / "compensator.log").read_text()
    assert "reference_limit" in log and "is not the paired driver" in log


def test_driver_is_not_locked_out_by_an_off_grid_first_block(tmp_path, probe):
    from sensor_msgs.msg import PointCloud2

    from piezo_ff_ros.nodes.common import BLOCK_QOS, pack_block, stamp_to_ns

    got = {}
    sub = probe.node.create_subscription(PointCloud2, "voltage_applied", lambda m: got.__setitem__(
        stamp_to_ns(m.header.stamp), m.width), BLOCK_QOS)
    diags = _driver_diags(probe)
    pub = probe.node.create_publisher(PointCloud2, "voltage", BLOCK_QOS)
    drv = start_node("driver", "-p", "diagnostics_period:=0.2", "-p", "limits.stale_timeout:=5.0",
                     log_dir=tmp_path)
    try:
        probe.spin_until(lambda: pub.get_subscription_count() > 0 and sub.get_publisher_count() > 0, 30,
                         "driver endpoints")
        probe.spin_for(1.0)
        k0 = 10**6 * N
        pub.publish(pack_block(np.full((N, 2), 1.0), AXES, k0 * DT_NS + 1))   # 1 ns off the grid, first
        stamps = [(k0 + i * N) * DT_NS for i in range(20)]
        for s in stamps:
            pub.publish(pack_block(np.full((N, 2), 1.0), AXES, s))
        probe.spin_until(lambda: all(s in got for s in stamps), 20, "every valid block applied")
        probe.spin_until(lambda: diags and diags[-1].get("blocks_applied") == "20", 10, "driver diagnostics")
        assert diags[-1]["rejected_blocks"] == "1" and diags[-1]["_level"] >= 1
    finally:
        assert stop_node(drv) == 0
    log = (tmp_path / "driver.log").read_text()
    assert log.count("off the 50000 ns sample grid") == 1


def test_driver_refuses_a_safe_ramp_that_is_a_step():
    r = subprocess.run([sys.executable, "-m", "piezo_ff_ros.nodes.driver", "--ros-args", "-p",
                        "safe_ramp.duration:=0.0", "-p", "safe_ramp.slew:=1.0e12"],
                       env=child_env(), capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "safe_ramp." in lines[0], lines


def test_compensator_recovers_without_reset_after_the_reference_returns(tmp_path, probe):
    """A reference at the edge of the limit saturates; back at 1 µm the voltage leaves the limit at once."""
    from piezo_ff_ros.core.config import load_config
    from piezo_ff_ros.core.trajectories.workspace import reachable_range
    from test_nodes_integration import ROOT

    lim = reachable_range(load_config(ROOT / "config" / "pt230_94.yaml"))
    g = Graph(probe)
    comp = start_node("compensator", "-p", "cascade.vibration:=false", log_dir=tmp_path)
    try:
        g.wait_ready()
        g.k = 10**6 * N
        edge = [g.send(held(N, 0.99 * lim[1], 0.99 * lim[3])) for _ in range(10)]
        back = [g.send(held(N)) for _ in range(3)]
    finally:
        assert stop_node(comp) == 0
    assert np.max(np.abs(g.volts[edge[-1]])) >= 199.999
    assert np.max(np.abs(g.volts[back[0]])) < 199.0
