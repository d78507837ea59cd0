"""The driver node over real DDS: bad parameters, future-stamped blocks, lost-block counts, two drivers on one
domain, voltage_applied, and the graph on the clocked simulator.  Each test starts its own nodes (isolated ROS_DOMAIN_ID from conftest)."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from test_nodes_integration import (AXES, DT_NS, FS, ROOT, Probe, child_env, start_node,  # noqa: E402
                                    stop_node)

from piezo_ff_ros.core.config import load_config  # noqa: E402
from piezo_ff_ros.core.models.plant import Plant  # noqa: E402


@pytest.fixture()
def probe():
    p = Probe("driver_probe")
    yield p
    p.close()


@pytest.mark.parametrize("arg, field", [
    ("diagnostics_period:=0.0", "diagnostics_period"),
    ("limits.voltage:=1.0e9", "limits.voltage"),
    ("limits.slew:=-5.0", "limits.slew"),
    ("max_block:=0", "max_block"),
    ("max_gap:=-1.0", "max_gap"),
    ("safe_ramp.slew:=0.0", "safe_ramp.slew"),
    ("joint_states_rate:=0.0", "joint_states_rate"),
    ("sim.mode:=realtimeish", "sim.mode"),
    ("sim.fifo_depth:=3", "sim.fifo_depth"),
    ("backend:=nope", "backend"),
    ("trajectory_state:=a b", "trajectory_state"),
])
def test_bad_driver_parameters_refused_with_one_line_naming_the_field(arg, field):
    """Each bad driver parameter stops the node with exit 2 and one line naming the field (these were accepted;
    diagnostics_period 0 spun a core)."""
    r = subprocess.run([sys.executable, "-m", "piezo_ff_ros.nodes.driver", "--ros-args", "-p", arg],
                       env=child_env(), capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and field in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


def _io(probe, publisher=True):
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import PointCloud2

    from piezo_ff_ros.nodes.common import BLOCK_QOS, stamp_to_ns, unpack_block

    got = {"displacement": {}, "voltage_applied": {}}
    probe.block_subs = [probe.node.create_subscription(PointCloud2, topic, lambda m, t=topic: got[t].__setitem__(
        stamp_to_ns(m.header.stamp), unpack_block(m, AXES)), BLOCK_QOS) for topic in got]
    diags = []
    probe.node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: diags.extend(
        (ord(s.level) if isinstance(s.level, bytes) else int(s.level), s.message,
         {kv.key: kv.value for kv in s.values}) for s in m.status
        if s.name.endswith("driver")), 50)
    pub = probe.node.create_publisher(PointCloud2, "voltage", BLOCK_QOS) if publisher else None
    return got, diags, pub


def _stream(d):
    stamps = sorted(d)
    ks = np.concatenate([s + DT_NS * np.arange(d[s].shape[0]) for s in stamps])
    return ks, np.vstack([d[s] for s in stamps])


def test_future_block_gaps_and_applied_voltage_through_the_node(tmp_path, probe):
    """One future-stamped block no longer stalls the graph (every later block was dropped as late); lost blocks
    show on /diagnostics with counts; voltage_applied carries every applied
    sample exactly once (clamped, held and ramped ones included), and the displacement answers it."""
    from piezo_ff_ros.nodes.common import pack_block

    got, diags, pub = _io(probe)
    drv = start_node("driver", "-p", "limits.stale_timeout:=1.0", "-p", "diagnostics_period:=0.2",
                     log_dir=tmp_path)
    try:
        probe.spin_until(lambda: pub.get_subscription_count() > 0, 30, "driver subscription")
        probe.spin_for(1.0)  # the driver's writers discover this reader (volatile QoS)
        n, k, sent = 200, 0, []

        def send(value, k0):
            stamp = k0 * DT_NS
            pub.publish(pack_block(np.full((n, 2), value), AXES, stamp))
            sent.append(stamp)

        for i in range(5):
            send(10.0 * i, k)
            k += n
        send(50.0, k + 10 ** 9)             # one block ~14 h in the future
        for i in range(5):
            send(60.0, k)
            k += n
        k += 3 * n                          # three blocks lost
        send(300.0, k)                      # out of range: clamped to 200 V
        k += n
        probe.spin_until(lambda: k * DT_NS - n * DT_NS in got["displacement"], 20, "the last displacement")
        # stale → safe ramp, published on voltage_applied too
        probe.spin_until(lambda: any(d[2].get("state") == "safe" for d in diags), 10, "safe state")
        probe.spin_for(0.5)
        ks, u = _stream(got["voltage_applied"])
        assert np.all(np.diff(ks) == DT_NS) and ks[0] == 0      # every sample once, in order, no hole
        assert u.shape[0] >= k + 1000                            # the blocks, the held gap and the ramp
        np.testing.assert_array_equal(u[1000:2000], 60.0)        # the blocks after the stray one were applied
        np.testing.assert_array_equal(u[2000:2600], 60.0)        # the gap held at the last voltage
        np.testing.assert_array_equal(u[2600:2800], 200.0)       # clamped
        np.testing.assert_array_equal(u[-1], [0.0, 0.0])         # ramped to safe
        assert np.abs(np.diff(u[2800:], axis=0)).max() <= 1.0e4 / FS + 1e-12   # the ramp's own slew
        ys, y = _stream(got["displacement"])
        np.testing.assert_array_equal(ys, ks)
        np.testing.assert_allclose(y, Plant(load_config()).process(u), rtol=0, atol=1e-15)
        st = [d for d in diags if d[2].get("state") == "safe"][-1]
        assert int(st[2]["out_of_sequence_blocks"]) == 1 and int(st[2]["late_blocks"]) == 0
        assert int(st[2]["gap_samples"]) == 600 and int(st[2]["lost_blocks"]) == 3
        assert any(d[0] >= 1 and "lost" in d[1] for d in diags)  # WARN/ERROR with counts
    finally:
        assert stop_node(drv) == 0


def test_two_drivers_on_one_domain_named_as_the_cause(tmp_path, probe):
    """A second driver on the same domain is refused with a message naming the first as the cause (two graphs on
    one domain used to fail with messages that did not name it)."""
    d1 = start_node("driver", "-p", "diagnostics_period:=0.2", log_dir=tmp_path)
    (tmp_path / "second").mkdir()
    d2 = start_node("driver", "-p", "diagnostics_period:=0.2", log_dir=tmp_path / "second")
    _, diags, _ = _io(probe, publisher=False)
    try:
        probe.spin_until(lambda: any(d[0] == 2 and "another driver" in d[1] for d in diags), 30,
                         "an ERROR naming the other driver")
        msg = next(d[1] for d in diags if "another driver" in d[1])
        assert "ROS_DOMAIN_ID" in msg and "namespace" in msg
    finally:
        assert stop_node(d1) == 0 and stop_node(d2) == 0


@pytest.mark.parametrize("window,write_ahead", [(8, 0.1), (1, 0.002)], ids=["ample", "starved"])
def test_graph_on_the_clocked_simulator(tmp_path, probe, window, write_ahead):
    """trajectory (lockstep window) → compensator → driver on the clocked simulator (paced by the wall clock, FIFO,
    latency): the run finishes, voltage_applied has every sample once, and the displacement is exactly the plant's
    answer to it — whatever the timing did (starved/late samples are counted, not hidden).  ``starved``: one block
    in flight, answered only once played, so the FIFO runs dry before every next block (underrun → safe ramp →
    resume, late samples dropped), as on a host too slow for its DAQ."""
    from std_msgs.msg import String

    from piezo_ff_ros.nodes.common import LATCHED_QOS

    got, diags, _ = _io(probe, publisher=False)
    states = []
    probe.node.create_subscription(String, "/trajectory/state", lambda m: states.append(json.loads(m.data)),
                                   LATCHED_QOS)
    spec = {"type": "circle", "radius": 1e-5, "frequency": 10.0, "revolutions": 2}
    procs = [start_node("driver", "-p", "sim.mode:=clocked", "-p", "sim.latency_samples:=40",
                        "-p", f"write_ahead:={write_ahead}", "-p", "low_water:=0.001", "-p", "diagnostics_period:=0.2",
                        log_dir=tmp_path),
             start_node("compensator", "-p", "cascade.vibration:=false", log_dir=tmp_path),
             start_node("trajectory", "-p", "mode:=lockstep", "-p", "block_size:=400", "-p", f"window:={window}",
                        "-p", f"trajectory:='{json.dumps(spec)}'", "-p", "min_subscribers:=1",
                        "-p", "lockstep_timeout:=20.0", log_dir=tmp_path)]
    try:
        from std_srvs.srv import Trigger

        probe.spin_until(lambda: all(sub.get_publisher_count() > 0 for sub in probe.block_subs), 60,
                         "the driver's voltage_applied and displacement publishers")
        # that is the reader's side of discovery; the driver's writers learn of these readers separately (a
        # volatile writer drops what it publishes before): the whole stream must reach the probe from sample 0
        probe.spin_for(1.5)
        assert probe.call(probe.node.create_client(Trigger, "/trajectory/start"), Trigger.Request(), 30).success
        probe.spin_until(lambda: states and states[-1]["state"] in ("finished", "failed"), 90, "trajectory end")
        assert states[-1]["state"] == "finished", states[-1]

        def tails_arrived():   # every displacement sample answers an applied sample the probe has received
            return (got["voltage_applied"] and got["displacement"]
                    and _stream(got["voltage_applied"])[0][-1] >= _stream(got["displacement"])[0][-1])

        probe.spin_for(0.5)
        probe.spin_until(tails_arrived, 30, "the last voltage_applied blocks")
    finally:
        codes = [stop_node(p) for p in reversed(procs)]
    assert codes == [0, 0, 0]
    ks, u = _stream(got["voltage_applied"])
    assert np.all(np.diff(ks) == DT_NS)
    assert u.shape[0] >= 2 * int(FS / 10)
    ys, y = _stream(got["displacement"])
    i0 = np.searchsorted(ks, ys[0])
    np.testing.assert_array_equal(ys, ks[i0:i0 + ys.size])
    assert i0 == 0
    cfg = load_config()
    # the device output the safe 0 V (prefill, idle) before the first stamped sample: the plant saw it
    y_ref = Plant(cfg).process(np.vstack([np.zeros((1, 2)), u]))[1:]
    np.testing.assert_allclose(y, y_ref[:y.shape[0]], rtol=0, atol=1e-15)
    last = diags[-1][2]
    assert int(last["latency_samples"]) == 40
    # on a loaded host the FIFO may run dry (the device holds, as a DAC does): never hidden — every underrun the
    # device had is a fault on /diagnostics, and the held samples are in voltage_applied (checked above)
    assert int(last["underrun_faults"]) == int(last["device.underruns"])
    if window == 1:
        assert int(last["underrun_faults"]) > 0
    if int(last["underrun_faults"]):
        assert any(level >= 1 and "fault" in msg for level, msg, _ in diags), diags[-3:]   # WARN/ERROR, not OK
