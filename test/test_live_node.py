"""Live reconfiguration of the compensator node through the graph: typed parameters, failed builds reverted,
resynchronisation, workspace, input gaps, bumpless swaps.

The compensator runs as its own process; this test talks to it through its parameter services, topics and
/diagnostics, as ``ros2 param`` / ``ros2 service call`` / ``ros2 topic`` would.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from test_nodes_integration import AXES, DT_NS, Probe, start_node, stop_node  # noqa: E402

N_BLK = 200


@pytest.fixture()
def probe():
    p = Probe("live_probe")
    yield p
    p.close()


class Graph:
    """Probe-side endpoints of a running compensator."""

    def __init__(self, probe):
        from diagnostic_msgs.msg import DiagnosticArray
        from rcl_interfaces.srv import (DescribeParameters, GetParameters, SetParameters,
                                        SetParametersAtomically)
        from sensor_msgs.msg import PointCloud2
        from std_msgs.msg import String

        from piezo_ff_ros.nodes.common import BLOCK_QOS, CONFIG_QOS, stamp_to_ns, unpack_block

        self.probe = probe
        node = probe.node
        self.volts, self.diags, self.configs = {}, [], []
        self.vsub = node.create_subscription(
            PointCloud2, "voltage", lambda m: self.volts.__setitem__(stamp_to_ns(m.header.stamp), unpack_block(m)),
            BLOCK_QOS)
        node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: self.diags.extend(
            {kv.key: kv.value for kv in s.values} | {"_level": _level(s), "_message": s.message}
            for s in m.status if s.name.endswith("compensator")), 10)
        node.create_subscription(String, "/compensator/config", lambda m: self.configs.append(json.loads(m.data)),
                                 CONFIG_QOS)
        self.pub = node.create_publisher(PointCloud2, "reference", BLOCK_QOS)
        self.pub_applied = node.create_publisher(PointCloud2, "voltage_applied", BLOCK_QOS)
        self.setp = node.create_client(SetParameters, "/compensator/set_parameters")
        self.seta = node.create_client(SetParametersAtomically, "/compensator/set_parameters_atomically")
        self.getp = node.create_client(GetParameters, "/compensator/get_parameters")
        self.desc = node.create_client(DescribeParameters, "/compensator/describe_parameters")
        self.k = 0

    def wait_ready(self):
        self.probe.spin_until(lambda: self.pub.get_subscription_count() > 0 and self.vsub.get_publisher_count() > 0,
                              30, "compensator endpoints")
        self.probe.spin_for(1.0)   # the compensator's volatile writer discovers this reader on its own schedule
        assert self.setp.wait_for_service(timeout_sec=10)

    def send(self, block, wait=True):
        from piezo_ff_ros.nodes.common import pack_block

        stamp = self.k * DT_NS
        self.pub.publish(pack_block(block, AXES, stamp))
        self.k += block.shape[0]
        if wait:
            self.probe.spin_until(lambda: stamp in self.volts, 10, f"voltage for stamp {stamp}")
        return stamp

    def set(self, **params):
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        req = SetParameters.Request(parameters=[Parameter(k.replace("__", "."), value=v).to_parameter_msg()
                                                for k, v in params.items()])
        return self.probe.call(self.setp, req).results

    def set_atomically(self, params: dict):
        from rcl_interfaces.srv import SetParametersAtomically
        from rclpy.parameter import Parameter

        req = SetParametersAtomically.Request(parameters=[Parameter(k, value=v).to_parameter_msg()
                                                          for k, v in params.items()])
        return self.probe.call(self.seta, req).result

    def get(self, *names):
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python

        vals = self.probe.call(self.getp, GetParameters.Request(names=list(names))).values
        return [parameter_value_to_python(v) for v in vals]

    def diag_after(self, pred, what, timeout=15.0):
        n0 = len(self.diags)
        self.probe.spin_until(lambda: any(pred(d) for d in self.diags[n0:]), timeout, what)
        return next(d for d in self.diags[n0:] if pred(d))


def _level(status) -> int:
    """DiagnosticStatus.level as an int (a one-byte ``bytes`` in these rclpy messages)."""
    return ord(status.level) if isinstance(status.level, bytes) else int(status.level)


def held(n, x=10e-6, y=0.0):
    return np.tile([x, y], (n, 1))


def test_failed_rebuild_while_blocks_flow_is_logged_reverted_and_later_changes_apply(tmp_path, probe):
    from rcl_interfaces.msg import ParameterEvent

    g = Graph(probe)
    events = []
    probe.node.create_subscription(ParameterEvent, "/parameter_events", lambda m: events.append(m)
                                   if m.node == "/compensator" else None, 1000)
    comp = start_node("compensator", "-p", "cascade.vibration:=false", log_dir=tmp_path)
    try:
        g.wait_ready()
        for _ in range(5):
            g.send(held(N_BLK))
        n_events = len(events)
        # an infeasible H∞ build (γ ≥ 0.948 > 0.5), requested while blocks flow: the data path polls the build
        res = g.set_atomically({"cascade.vibration": True, "vibration.gamma_max": 0.5})
        assert res.successful, res.reason
        for _ in range(10):
            g.send(held(N_BLK))
        d = g.diag_after(lambda d: d.get("failed_builds") == "1", "failed build on /diagnostics")
        assert d["_level"] >= 1 and "not applied" in d["_message"]
        probe.spin_until(lambda: g.get("vibration.gamma_max", "cascade.vibration") == [1.0, False], 10,
                         "parameters reverted")
        assert g.get("vibration.gamma_max", "cascade.vibration") == [1.0, False]   # no lie in `param get`
        probe.spin_for(0.5)
        changed = [sorted(p.name for p in e.changed_parameters) for e in events[n_events:]]
        # the request, then the revert of exactly the two parameters that differ (no array re-set one by one)
        assert changed == [["cascade.vibration", "vibration.gamma_max"]] * 2, changed
        # a later change is applied; the revert created no configuration version (v1 running, v2 failed → v3)
        assert g.set(cascade__creep=False)[0].successful
        for _ in range(3):
            g.send(held(N_BLK))
        g.diag_after(lambda d: d.get("config_version") == "3", "configuration v3 active")
        probe.spin_until(lambda: [c["version"] for c in g.configs] == [1, 3], 10, "~/config versions")
        assert g.configs[1]["stamp_ns"] > g.configs[0]["stamp_ns"] == 0
        assert "creep: false" in g.configs[1]["config_yaml"].replace("creep: False", "creep: false")
    finally:
        assert stop_node(comp) == 0
    log = (tmp_path / "compensator.log").read_text()
    assert "[ERROR]" in log and "configuration v2 not applied" in log and "reverted" in log


def test_parameter_typing_atomic_yaml_and_no_op_load(tmp_path, probe):
    from rcl_interfaces.msg import ParameterType

    g = Graph(probe)
    comp = start_node("compensator", "-p", "cascade.vibration:=false", log_dir=tmp_path)
    try:
        g.wait_ready()
        g.send(held(N_BLK))
        r = g.set(vibration__t_r=1)[0]                        # an integer for a double: taken as 1.0
        assert r.successful, r.reason
        assert g.get("vibration.t_r") == [1.0] and isinstance(g.get("vibration.t_r")[0], float)
        assert g.set(vibration__t_r=0.025)[0].successful
        assert g.set(creep__Cr__yx__num=[])[0].successful     # rclpy types [] as bytes: still a double array
        r = g.set(vibration__t_r="fast")[0]
        assert not r.successful and r.reason.startswith("vibration.t_r: expected a double, got a string"), r.reason
        r = g.set(vibration__t_r=500.0)[0]
        # rclpy's own range check (the descriptor's range, as `ros2 param describe` and rqt show it), naming the field
        assert not r.successful and "vibration.t_r out of range" in r.reason and "\n" not in r.reason, r.reason
        from rcl_interfaces.srv import DescribeParameters

        desc = probe.call(g.desc, DescribeParameters.Request(names=["vibration.t_r", "creep.Cr.xx.den_deg"]))
        # typed by the node (TypedParameters: rclpy's dynamic typing, the declared type checked in a callback)
        assert desc.descriptors[0].type == ParameterType.PARAMETER_DOUBLE
        assert desc.descriptors[0].floating_point_range and desc.descriptors[0].description
        assert desc.descriptors[1].type == ParameterType.PARAMETER_INTEGER_ARRAY
        assert g.get("vibration.t_r") == [0.025]
        from rcl_interfaces.srv import GetParameters

        v = probe.call(g.getp, GetParameters.Request(names=["creep.Cr.yx.num", "vibration.t_r"])).values
        assert v[0].type == ParameterType.PARAMETER_DOUBLE_ARRAY and v[1].type == ParameterType.PARAMETER_DOUBLE
        r = g.set(hysteresis__Dp=[1e-7, 2e-7])[0]
        assert not r.successful and r.reason.startswith("hysteresis.Dp"), r.reason
        # a coupled change, refused one by one, accepted atomically through config_yaml
        den = np.polymul([1.0, 0.1156], [1.0, 0.01249]).tolist()
        assert not g.set(creep__Cr__xx__den=den)[0].successful
        r = g.set(config_yaml=f"creep.Cr.xx.den: {den}\ncreep.Cr.xx.den_deg: [2]\n")[0]
        assert r.successful, r.reason
        assert g.get("creep.Cr.xx.den_deg", "config_yaml") == [[2], ""]
        g.send(held(N_BLK))
        # versions: v2 t_r = 1.0, v3 t_r back, ([] for yx.num is the value it has: none), v4 the YAML
        g.diag_after(lambda d: d.get("config_version") == "4", "configuration v4 active")
        # `ros2 param load` of a dump: every parameter set one by one to the value it has → no new version
        from rcl_interfaces.srv import ListParameters

        names = probe.call(probe.node.create_client(ListParameters, "/compensator/list_parameters"),
                           ListParameters.Request()).result.names
        names = [n for n in names if n.startswith(("hysteresis.", "creep.", "vibration.", "cascade.", "dynamics."))]
        from rcl_interfaces.msg import Parameter as ParameterMsg
        from rcl_interfaces.srv import GetParameters, SetParameters

        values = probe.call(g.getp, GetParameters.Request(names=names)).values   # typed, as a dump keeps them
        for n, v in zip(names, values):
            res = probe.call(g.setp, SetParameters.Request(parameters=[ParameterMsg(name=n, value=v)])).results[0]
            assert res.successful, (n, res.reason)
        g.send(held(N_BLK))
        d = g.diag_after(lambda d: True, "diagnostics")
        assert d["config_version"] == "4" and d["pending_version"] == "None"
    finally:
        assert stop_node(comp) == 0


def test_applied_voltage_resync_workspace_and_input_gaps(tmp_path, probe):
    from piezo_ff_ros.nodes.common import pack_block

    g = Graph(probe)
    comp = start_node("compensator", "-p", "cascade.vibration:=false", "-p", "workspace:=[-5.0e-5, 5.0e-5, "
                      "-5.0e-5, 5.0e-5]", "-p", "driver:=live_probe", log_dir=tmp_path)
    try:
        g.wait_ready()
        # the compensator tracks blocks in flight only once its paired driver (this probe) publishes voltage_applied
        probe.spin_until(lambda: g.pub_applied.get_subscription_count() > 0, 30, "voltage_applied subscriber")
        probe.spin_for(0.5)
        stamps = [g.send(held(N_BLK)) for _ in range(3)]
        # the driver reports what it applied: the first block as sent, then a stall (safe ramp to 0 V)
        g.pub_applied.publish(pack_block(g.volts[stamps[0]], AXES, stamps[0]))
        g.pub_applied.publish(pack_block(np.zeros((N_BLK, 2)), AXES, stamps[1]))
        g.diag_after(lambda d: d.get("resyncs") == "1" and d.get("applied_blocks") == "1", "a re-synchronisation")
        g.send(held(N_BLK, x=6e-5))                    # 60 µm: outside the workspace, clamped and counted
        g.k += 5 * N_BLK                               # 5 blocks lost
        g.send(held(N_BLK))
        d = g.diag_after(lambda d: d.get("input_gaps") == "1", "a counted input gap")
        assert d["input_gap_samples"] == str(5 * N_BLK) and d["input_workspace_clamped_samples"] == str(N_BLK)
        assert d["resync_active"] == "True"
        assert d["_level"] == 1
    finally:
        assert stop_node(comp) == 0
    assert "outside the workspace" in (tmp_path / "compensator.log").read_text()
    # the node did exactly what the core does with the same sequence (re-synchronised states included)
    from dataclasses import replace

    from piezo_ff_ros.core.config import load_config
    from piezo_ff_ros.core.hot_swap import HotSwapCascade
    from test_nodes_integration import ROOT

    cfg = load_config(ROOT / "config" / "pt230_94.yaml")
    hs = HotSwapCascade(replace(cfg, cascade=replace(cfg.cascade, vibration=False)).validate())
    expected = {k * DT_NS: hs.process(held(N_BLK), k0=k) for k in (0, N_BLK, 2 * N_BLK)}
    assert hs.applied(0, expected[0]) == "match" and hs.applied(N_BLK, np.zeros((N_BLK, 2))) == "resync"
    expected[3 * N_BLK * DT_NS] = hs.process(held(N_BLK, x=5e-5), k0=3 * N_BLK)
    expected[9 * N_BLK * DT_NS] = hs.process(held(N_BLK), k0=9 * N_BLK)
    assert sorted(g.volts) == sorted(expected)
    for stamp, u in expected.items():
        np.testing.assert_array_equal(g.volts[stamp], u)


def test_creep_gain_change_through_the_graph_is_the_cores_bumpless_swap(tmp_path, probe):
    """`ros2 param set /compensator creep.Cr.xx.k` while holding: the node's voltages are, sample for sample, the
    core's HotSwapCascade with the same request at the same block (whose jump test_live_bumpless bounds)."""
    from dataclasses import replace

    from piezo_ff_ros.core.config import load_config
    from piezo_ff_ros.core.hot_swap import HotSwapCascade
    from piezo_ff_ros.core.param_map import params_to_config
    from test_nodes_integration import ROOT

    cfg = load_config(ROOT / "config" / "pt230_94.yaml")
    cfg = replace(cfg, cascade=replace(cfg.cascade, vibration=False)).validate()
    new = params_to_config({"creep.Cr.xx.k": 0.003299 * 1.0003}, cfg)
    g = Graph(probe)
    comp = start_node("compensator", "-p", "cascade.vibration:=false", log_dir=tmp_path)
    stamps = []
    try:
        g.wait_ready()
        stamps += [g.send(held(N_BLK)) for _ in range(20)]
        assert g.set(creep__Cr__xx__k=0.003299 * 1.0003)[0].successful
        stamps += [g.send(held(N_BLK)) for _ in range(20)]
    finally:
        assert stop_node(comp) == 0
    hs = HotSwapCascade(cfg, crossfade_samples=200)
    expected = []
    for i in range(40):
        if i == 20:
            hs.request(new)
        expected.append(hs.process(held(N_BLK)))
    got = np.vstack([g.volts[s] for s in stamps])
    np.testing.assert_array_equal(got, np.vstack(expected))
    assert hs.version == 2


def test_config_yaml_forms_and_one_line_errors():
    from piezo_ff_ros.core.config import ConfigError
    from piezo_ff_ros.nodes.compensator import parse_config_yaml

    flat = {"creep.Cr.xx.den": [1.0, 0.1], "creep.Cr.xx.den_deg": [1]}
    assert parse_config_yaml("creep.Cr.xx.den: [1.0, 0.1]\ncreep.Cr.xx.den_deg: [1]\n") == flat
    assert parse_config_yaml("creep: {Cr: {xx: {den: [1.0, 0.1], den_deg: [1]}}}") == flat
    assert parse_config_yaml("/**:\n  ros__parameters:\n    creep.Cr.xx.den: [1.0, 0.1]\n"
                             "    creep.Cr.xx.den_deg: [1]\n") == flat
    assert parse_config_yaml("") == {}
    for bad, text in [("crossfade: 0.1", "not a stage parameter: crossfade"), ("[1, 2]", "expected a mapping"),
                      ("a: [", "not valid YAML")]:
        with pytest.raises(ConfigError) as e:
            parse_config_yaml(bad)
        assert str(e.value).startswith("config_yaml") and text in str(e.value) and "\n" not in str(e.value)


def test_process_and_publish_from_two_threads_keeps_one_contiguous_stream():
    """The held-point thread and the executor both publish: counters, stamps and publish are under one lock."""
    import threading

    from rclpy.context import Context

    from piezo_ff_ros.nodes.common import stamp_to_ns
    from piezo_ff_ros.nodes.compensator import CompensatorNode

    ctx = Context()
    rclpy.init(context=ctx, args=["--ros-args", "-p", "cascade.vibration:=false"])
    node = CompensatorNode(context=ctx)
    node.stop()                                  # its own held-point thread out of the way
    stamps = []
    node.pub_u.publish = lambda msg: stamps.append((stamp_to_ns(msg.header.stamp), msg.width))
    try:
        def worker():
            for _ in range(100):
                node._process_and_publish(held(50), None)   # None: continue the stream (as the held point does)

        threads = [threading.Thread(target=worker) for _ in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    assert node.blocks == 200 and len(stamps) == 200
    ks = [s for s, _ in stamps]
    assert all(b - a == 50 * DT_NS for a, b in zip(ks, ks[1:])), "stamps out of order or duplicated"
