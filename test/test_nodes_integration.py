"""The nodes as separate processes over real DDS (isolated ROS_DOMAIN_ID from conftest, localhost discovery).

- the four nodes end to end in lockstep, the MCAP read back with the ``mcap`` and ``rosbags`` readers: sample-exact
  against the core computed offline, no lost block;
- runtime parameter changes of the compensator from this process through its ``set_parameters`` service;
- driver safety: out-of-range, NaN, wrong-shape, oversized and stale input.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from piezo_ff_ros.core.compensators.cascade import CompensatorCascade  # noqa: E402
from piezo_ff_ros.core.config import load_config  # noqa: E402
from piezo_ff_ros.core.models.plant import Plant  # noqa: E402
from piezo_ff_ros.core.safety import SafeRampConfig, VoltageGuard  # noqa: E402
from piezo_ff_ros.core.trajectories import from_dict  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FS = 20000.0
DT_NS = 50_000
AXES = ["x", "y"]


def child_env() -> dict:
    env = dict(os.environ)  # parent env unchanged (keeps the wheels' bootstrap consistent), plus the repo
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def start_node(name: str, *ros_args: str, log_dir: Path) -> subprocess.Popen:
    log_path = log_dir / f"{name}.log"
    log = open(log_path, "wb")
    p = subprocess.Popen([sys.executable, "-m", f"piezo_ff_ros.nodes.{name}", "--ros-args", *ros_args],
                         env=child_env(), stdout=log, stderr=subprocess.STDOUT)
    p.log_path = log_path  # type: ignore[attr-defined]  # shown by stop_node when the exit is not clean
    return p


#: where stop_node reports a node that ignored SIGINT (test/conftest.py prints them at the end of the run)
UNSTOPPABLE_REPORT = Path(os.environ.get("ROS_LOG_DIR", tempfile.gettempdir())) / "unstoppable_nodes.txt"


def _report_unstoppable(p: subprocess.Popen, timeout: float) -> None:
    log_path = getattr(p, "log_path", None)
    tail = Path(log_path).read_text(errors="replace").splitlines()[-60:] if log_path and Path(log_path).exists() \
        else []
    with open(UNSTOPPABLE_REPORT, "a") as fh:
        fh.write(f"--- {' '.join(map(str, p.args))[:200]}: still running {timeout:g} s after SIGINT, killed; "
                 f"its log ends:\n" + "\n".join(tail) + "\n")


def stop_node(p: subprocess.Popen, timeout: float = 15.0) -> int:
    """SIGINT, wait, exit code (-9 if it had to be killed); a non-zero code prints the node's log tail, which
    pytest shows with the failure."""
    code = p.returncode
    if p.poll() is None:
        p.send_signal(signal.SIGINT)
        try:
            code = p.wait(timeout)
        except subprocess.TimeoutExpired:
            p.send_signal(signal.SIGUSR1)      # the node prints its threads' stacks to its log (run_node)
            try:
                p.wait(1.0)
            except subprocess.TimeoutExpired:
                pass
            p.kill()
            _report_unstoppable(p, timeout)
            p.wait()
            code = -9
    else:
        code = p.returncode
    log_path = getattr(p, "log_path", None)
    if code != 0 and log_path is not None and Path(log_path).exists():
        tail = Path(log_path).read_text(errors="replace").splitlines()[-40:]
        print(f"--- {Path(log_path).name} (exit {code}) ---", *tail, sep="\n")
    return code


class Probe:
    """An in-test rclpy node with its own context."""

    def __init__(self, name="probe"):
        from rclpy.context import Context

        self.ctx = Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node(name, context=self.ctx)
        from rclpy.executors import SingleThreadedExecutor

        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)

    def spin_until(self, cond, timeout: float, what: str = "condition"):
        deadline = time.monotonic() + timeout
        while not cond():
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout} s waiting for {what}")
            self.ex.spin_once(timeout_sec=0.02)

    def spin_for(self, seconds: float):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.ex.spin_once(timeout_sec=0.02)

    def call(self, client, request, timeout=10.0, resend_every=None):
        """The service's reply to ``request`` within ``timeout`` s; a read-only request whose reply is lost is asked
        again (``piezo_ff_ros.ros.service_call``), others too when ``resend_every`` is given."""
        from piezo_ff_ros.ros.service_call import call_service

        assert client.wait_for_service(timeout_sec=timeout), f"service {client.srv_name} not available"
        try:
            return call_service(client, request, lambda t: self.ex.spin_once(timeout_sec=t), timeout, resend_every)
        except TimeoutError:
            raise AssertionError(f"timed out after {timeout} s waiting for reply of {client.srv_name}") from None

    def close(self):
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)


def wait_recorder_connected(probe, topics, timeout=30.0):
    """Until the recorder reports a matched publisher on each topic (its ~/status), so that no block is missed."""
    from std_msgs.msg import String

    from piezo_ff_ros.nodes.common import LATCHED_QOS

    last = {}
    probe.node.create_subscription(String, "/recorder/status", lambda m: last.update(json.loads(m.data)),
                                   LATCHED_QOS)
    probe.spin_until(lambda: all(last.get("publishers", {}).get(t, 0) >= 1 for t in topics), timeout,
                     f"recorder connected to {topics}")


#: the driver runs with a slower slew limit than the config's 1e7 V/s, so that it visibly acts (10 V per sample)
DRIVER_SLEW = 2.0e5


def DRIVER_LIMITS(cfg):  # noqa: N802 - reads like the constant it stands for
    import dataclasses

    return dataclasses.replace(cfg.limits, slew=DRIVER_SLEW)


@pytest.fixture()
def probe():
    p = Probe()
    yield p
    p.close()


@pytest.fixture(scope="module")
def cfg_novib():  # noqa: D103
    cfg = load_config(ROOT / "config" / "pt230_94.yaml")
    return replace(cfg, cascade=replace(cfg.cascade, vibration=False)).validate()


def block_io(probe):
    from sensor_msgs.msg import PointCloud2

    from piezo_ff_ros.nodes.common import BLOCK_QOS, pack_block, stamp_to_ns, unpack_block

    got = {}
    probe.node.create_subscription(PointCloud2, "displacement",
                                   lambda m: got.__setitem__(stamp_to_ns(m.header.stamp), unpack_block(m)), BLOCK_QOS)
    return got, pack_block, BLOCK_QOS


# ----------------------------------------------------------------------------------------------------------------
def test_graph_end_to_end_lockstep_recorded_sample_exact(tmp_path, probe, cfg_novib):
    from std_msgs.msg import String

    from piezo_ff_ros.nodes.common import LATCHED_QOS

    spec = {"type": "sequence", "segments": [
        {"name": "circle_a", "trajectory": {"type": "circle", "radius": 1e-5, "frequency": 20.0, "revolutions": 1},
         "meta": {"stages": ["hysteresis", "creep"]}},
        {"name": "circle_b", "trajectory": {"type": "circle", "radius": 2e-5, "frequency": 40.0, "revolutions": 2},
         "meta": {"stages": ["hysteresis", "creep"]}}]}
    traj = from_dict(spec)
    n_total = traj.n_samples(FS)
    t0 = 1_000_000_000_000
    out = tmp_path / "run.mcap"
    states = []
    probe.node.create_subscription(String, "/trajectory/state", lambda m: states.append(json.loads(m.data)),
                                   LATCHED_QOS)
    from sensor_msgs.msg import JointState

    joints = []
    jsub = probe.node.create_subscription(JointState, "joint_states", joints.append, 100)
    procs = [start_node("recorder", "-p", f"output:={out}", log_dir=tmp_path),
             start_node("driver", "-p", "limits.stale_timeout:=5.0", "-p", f"limits.slew:={DRIVER_SLEW}",
                        log_dir=tmp_path),  # lockstep: no wall clock; a slower amplifier than the compensator assumes
             # resync off: the voltage is compared sample-exactly with the cascade run offline on the reference
             # alone (with it, the slew-limited start would re-synchronise the states on voltage_applied)
             start_node("compensator", "-p", "cascade.vibration:=false", "-p", "resync:=false", log_dir=tmp_path),
             start_node("trajectory", "-p", "mode:=lockstep", "-p", "block_size:=250", "-p", "window:=3",
                        "-p", f"t0_ns:={t0}", "-p", f"trajectory:='{json.dumps(spec)}'",
                        "-p", "min_subscribers:=2", log_dir=tmp_path)]
    try:
        from std_srvs.srv import Trigger

        wait_recorder_connected(probe, ["/reference", "/voltage", "/displacement"], timeout=60)
        probe.spin_until(lambda: jsub.get_publisher_count() > 0, 30, "the driver's joint_states")
        # that is the reader's side of discovery; the driver's writer learns of this reader separately (a volatile
        # writer drops what it publishes before): give it time, the lockstep run itself lasts only ~0.1 s
        probe.spin_for(1.5)
        assert probe.call(probe.node.create_client(Trigger, "/trajectory/start"), Trigger.Request()).success
        probe.spin_until(lambda: states and states[-1]["state"] in ("finished", "failed"), 60, "trajectory end")
        assert states[-1]["state"] == "finished", states[-1]
        probe.spin_for(0.5)
    finally:
        codes = [stop_node(p) for p in reversed(procs)]
    assert codes == [0, 0, 0, 0], [(p.args[2], c) for p, c in zip(reversed(procs), codes)]
    # decimated joint_states for live plots: 100 Hz of sample time = one per 200 samples
    assert len(joints) >= n_total // 200 - 2
    assert list(joints[0].name) == AXES and all(np.all(np.isfinite(j.position)) for j in joints)

    # expected, computed offline by the core: reference → cascade → guard (slew from 0 V) → plant
    ref = traj.block(0, n_total, FS)
    u_cmd = CompensatorCascade(cfg_novib).process(ref)
    u_applied = VoltageGuard(DRIVER_LIMITS(cfg_novib), 2, FS, max_block=20000).apply(u_cmd)
    assert np.any(u_applied != u_cmd)  # the circle starts off-centre: the slew limit acted on the first samples
    y = Plant(cfg_novib).process(u_applied)

    # reader 1: mcap + mcap_ros2 decoder
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    blocks = {"/reference": {}, "/voltage": {}, "/displacement": {}}
    markers = []
    with open(out, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        for schema, channel, _, msg in reader.iter_decoded_messages():
            if channel.topic in blocks:
                assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
                assert "offered_qos_profiles" in channel.metadata and "topic_type_hash" in channel.metadata
                stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                blocks[channel.topic][stamp] = np.frombuffer(bytes(msg.data), "<f8").reshape(msg.width, 2)
            elif channel.topic == "/experiment":
                markers.append(json.loads(msg.data))
    assert [m["name"] for m in markers] == ["circle_a", "circle_b"]
    assert [m["k0"] for m in markers] == [0, traj.segments(FS)[1].start]

    def assemble(d, n):
        ks = sorted((s - t0) // DT_NS for s in d)
        parts = [d[t0 + k * DT_NS] for k in ks]
        ends = np.cumsum([0] + [len(p) for p in parts])
        assert list(ends[:-1]) == ks, "lost or overlapping block"
        return np.vstack(parts)[:n]

    ref_rec = assemble(blocks["/reference"], n_total)
    assert len(blocks["/reference"]) == int(np.ceil(n_total / 250))
    np.testing.assert_array_equal(ref_rec, ref)
    np.testing.assert_array_equal(assemble(blocks["/voltage"], n_total), u_cmd)
    y_rec = assemble(blocks["/displacement"], n_total)
    np.testing.assert_allclose(y_rec, y, rtol=0, atol=1e-15)

    # reader 2: rosbags opens the bare file as a rosbag2 bag
    from rosbags.highlevel import AnyReader

    with AnyReader([out]) as r:
        conns = [c for c in r.connections if c.topic == "/displacement"]
        ys = {}
        for conn, _, raw in r.messages(connections=conns):
            m = r.deserialize(raw, conn.msgtype)
            ys[m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec] = \
                np.frombuffer(bytes(m.data), "<f8").reshape(m.width, 2)
    np.testing.assert_allclose(assemble(ys, n_total), y, rtol=0, atol=1e-15)


# ----------------------------------------------------------------------------------------------------------------
def test_runtime_parameter_change_through_set_parameters_service(tmp_path, probe, cfg_novib):
    from rcl_interfaces.srv import GetParameters, SetParameters
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import PointCloud2

    from piezo_ff_ros.nodes.common import BLOCK_QOS, pack_block, stamp_to_ns, unpack_block

    volts = {}
    vsub = probe.node.create_subscription(PointCloud2, "voltage",
                                          lambda m: volts.__setitem__(stamp_to_ns(m.header.stamp), unpack_block(m)),
                                          BLOCK_QOS)
    pub = probe.node.create_publisher(PointCloud2, "reference", BLOCK_QOS)
    setp = probe.node.create_client(SetParameters, "/compensator/set_parameters")
    getp = probe.node.create_client(GetParameters, "/compensator/get_parameters")
    comp = start_node("compensator", "-p", "cascade.vibration:=false", "-p", "crossfade:=0.02", log_dir=tmp_path)
    try:
        probe.spin_until(lambda: pub.get_subscription_count() > 0 and vsub.get_publisher_count() > 0, 30,
                         "compensator subscription and publisher")
        probe.spin_for(1.0)  # the compensator's writer discovers this reader on its own schedule (volatile QoS)
        assert setp.wait_for_service(timeout_sec=10)
        n_blk, n_blocks = 200, 40
        t = np.arange(n_blk * n_blocks) / FS
        ref = np.column_stack([10e-6 + 8e-6 * np.sin(2 * np.pi * 5 * t), 5e-6 * np.cos(2 * np.pi * 3 * t)])

        def send(i):
            pub.publish(pack_block(ref[i * n_blk:(i + 1) * n_blk], AXES, i * n_blk * DT_NS))
            probe.spin_until(lambda: i * n_blk * DT_NS in volts, 10, f"voltage block {i}")

        for i in range(20):
            send(i)
        # rejected: singular Dp → reason names the field, old value kept
        bad = Parameter("hysteresis.Dp", value=[1e-7, 2e-7, 2e-7, 4e-7]).to_parameter_msg()
        res = probe.call(setp, SetParameters.Request(parameters=[bad])).results[0]
        assert not res.successful and res.reason.startswith("hysteresis.Dp"), res.reason
        got = probe.call(getp, GetParameters.Request(names=["hysteresis.Dp"])).values[0].double_array_value
        np.testing.assert_allclose(list(got), [0.1663e-6, 0.0054e-6, -0.0048e-6, 0.1803e-6], rtol=1e-12)
        # rejected: wrong type
        res = probe.call(setp, SetParameters.Request(
            parameters=[Parameter("cascade.creep", value="no").to_parameter_msg()])).results[0]
        assert not res.successful and res.reason.startswith("cascade.creep")
        # accepted: creep compensation off, applied at a block boundary, bumplessly
        ok = Parameter("cascade.creep", value=False).to_parameter_msg()
        assert probe.call(setp, SetParameters.Request(parameters=[ok])).results[0].successful
        got = probe.call(getp, GetParameters.Request(names=["cascade.creep"])).values[0].bool_value
        assert got is False
        for i in range(20, n_blocks):
            send(i)
    finally:
        assert stop_node(comp) == 0
    u = np.vstack([volts[i * n_blk * DT_NS] for i in range(n_blocks)])
    u_old = CompensatorCascade(cfg_novib).process(ref)
    np.testing.assert_array_equal(u[:20 * n_blk], u_old[:20 * n_blk])     # before the change: old config
    assert np.max(np.abs(u[-n_blk:] - u_old[-n_blk:])) > 0.5              # after: the new one (creep off)
    du = np.abs(np.diff(u, axis=0))
    normal = du[100:20 * n_blk - 1].max()
    assert du[20 * n_blk - 1:].max() < 1.5 * normal, (du[20 * n_blk - 1:].max(), normal)  # no jump


# ----------------------------------------------------------------------------------------------------------------
def test_driver_safety_limits_rejection_and_stale_ramp(tmp_path, probe, cfg_novib):
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import PointCloud2

    from piezo_ff_ros.nodes.common import BLOCK_QOS, pack_block

    got, _, _ = block_io(probe)
    diags = []
    probe.node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: diags.extend(
        {kv.key: kv.value for kv in s.values} for s in m.status if s.name.endswith("driver")), 10)
    pub = probe.node.create_publisher(PointCloud2, "voltage", BLOCK_QOS)
    drv = start_node("driver", "-p", "max_block:=1000", "-p", "limits.stale_timeout:=1.0",
                     "-p", f"limits.slew:={DRIVER_SLEW}",   # the default safe ramp: ≥ 0.05 s, ≤ 1e4 V/s
                     "-p", "diagnostics_period:=0.2", log_dir=tmp_path)
    n = 100
    guard = VoltageGuard(DRIVER_LIMITS(cfg_novib), 2, FS, max_block=1000)
    plant = Plant(cfg_novib)
    plant.process(np.zeros((1, 2)))  # compile before the timed part (blocks must come < stale_timeout apart)
    plant.reset()
    expected = {}
    try:
        probe.spin_until(lambda: pub.get_subscription_count() > 0, 30, "driver subscription")
        probe.spin_for(1.0)  # and the driver's displacement writer discovers this reader (volatile QoS)
        k = 0

        def send(block, expect):
            nonlocal k
            stamp = k * DT_NS
            msg = pack_block(block, AXES[:block.shape[1]] if block.shape[1] <= 2 else ["x", "y", "z"], stamp)
            pub.publish(msg)
            if expect == "hold":
                expected[stamp] = plant.process(guard.hold(block.shape[0]))
            elif expect == "apply":
                expected[stamp] = plant.process(guard.apply(block))
            if expect is not None:
                probe.spin_until(lambda: stamp in got, 10, f"displacement for stamp {stamp}")
            k += block.shape[0]

        send(np.full((n, 2), 50.0), "apply")                        # normal, ramped up at the slew limit
        send(np.full((n, 2), 1000.0) * [1, -1], "apply")            # out of range: clamped to ±200 V, slewed
        nan = np.full((n, 2), 20.0)
        nan[7, 1] = np.nan
        send(nan, "hold")                                           # NaN: rejected, last voltage held
        send(np.full((n, 3), 10.0), "hold")                         # wrong shape (3 fields): rejected, held
        send(np.full((1500, 2), 10.0), None)                        # oversized (> max_block): nothing applied
        probe.spin_for(0.1)
        assert (k - 1500) * DT_NS not in got  # nothing published for the oversized block
        for stamp, y in expected.items():
            np.testing.assert_allclose(got[stamp], y, rtol=0, atol=1e-15)
        # stale input: ramp to 0 V at the slew limit, published after the last applied block
        probe.spin_until(lambda: any(d.get("state") == "safe" for d in diags), 5, "driver safe state")
        last = diags[-1]
        assert json.loads(last["applied_voltage"]) == [0.0, 0.0]
        assert int(last["rejected_blocks"]) == 3 and int(last["saturated_samples"]) == n
        assert int(last["safe_ramps"]) == 1 and int(last["slew_limited_samples"]) > 0
        ramp_stamp = (k - 1500) * DT_NS
        assert ramp_stamp in got  # the ramp continues the sample stream (the oversized block took no indices)
        ramp = guard.ramp_to_safe(SafeRampConfig())
        assert ramp.shape[0] == 1000  # 200 V in 0.05 s (0.2 V/sample, below the 0.5 V/sample of 1e4 V/s)
        np.testing.assert_allclose(got[ramp_stamp], plant.process(ramp), rtol=0, atol=1e-15)
        # a block for sample instants already past (here: the very first) is dropped, never re-applied
        n_diag = len(diags)
        pub.publish(pack_block(np.full((n, 2), 5.0), AXES, 0))
        probe.spin_until(lambda: len(diags) > n_diag + 1, 5, "diagnostics after a late block")
        assert int(diags[-1]["late_blocks"]) == 1
        np.testing.assert_allclose(got[0], expected[0], rtol=0, atol=1e-15)
    finally:
        assert stop_node(drv) == 0


# ----------------------------------------------------------------------------------------------------------------
def test_realtime_pacing_held_point_and_recorder_sigterm(tmp_path, probe):
    """realtime mode is paced by the wall clock; reference_point is played as blocks; SIGTERM finishes the MCAP."""
    from geometry_msgs.msg import PointStamped
    from sensor_msgs.msg import PointCloud2
    from std_msgs.msg import String

    from piezo_ff_ros.nodes.common import BLOCK_QOS, LATCHED_QOS, stamp_to_ns, unpack_block

    states, volts = [], {}
    probe.node.create_subscription(String, "/trajectory/state", lambda m: states.append((time.monotonic(),
                                                                                         json.loads(m.data))),
                                   LATCHED_QOS)
    vsub = probe.node.create_subscription(PointCloud2, "voltage",
                                          lambda m: volts.__setitem__(stamp_to_ns(m.header.stamp), unpack_block(m)),
                                          BLOCK_QOS)
    from std_srvs.srv import Trigger

    start = probe.node.create_client(Trigger, "/trajectory/start")
    out = tmp_path / "rt.mcap"
    preview = 50  # samples: the trajectory plays 2.5 ms ahead (reference preview for an input delay)
    spec = {"type": "circle", "radius": 1e-5, "frequency": 4.0, "revolutions": 4}  # 1 s
    procs = {"recorder": start_node("recorder", "-p", f"output:={out}", log_dir=tmp_path),
             "compensator": start_node("compensator", "-p", "cascade.vibration:=false", "-p", "block_size:=200",
                                       log_dir=tmp_path),
             "trajectory": start_node("trajectory", "-p", "mode:=realtime",
                                      "-p", "min_subscribers:=2", "-p", f"trajectory:='{json.dumps(spec)}'",
                                      "-p", "block_size:=200", "-p", f"preview_s:={preview / FS}",
                                      log_dir=tmp_path)}
    try:
        # no driver: in realtime nothing waits for displacement; start once this probe hears the compensator
        probe.spin_until(lambda: vsub.get_publisher_count() > 0, 30, "compensator's voltage publisher")
        wait_recorder_connected(probe, ["/reference", "/voltage"], timeout=60)
        # that is this reader's side of discovery; the compensator's writer learns of it separately and drops what
        # it publishes before (volatile): give it time before the 1 s run starts
        probe.spin_for(1.5)
        assert probe.call(start, Trigger.Request()).success
        probe.spin_until(lambda: any(s["state"] in ("finished", "failed") for _, s in states), 60, "trajectory end")
        t_play = next(t for t, s in states if s["state"] == "playing")
        t_end, end = next((t, s) for t, s in states if s["state"] in ("finished", "failed"))
        assert end["state"] == "finished" and end["blocks"] == 100
        assert t_end - t_play >= 0.95  # paced: 1 s of signal never plays faster than 1 s
        probe.spin_until(lambda: len(volts) >= 100, 10, "the voltage blocks")
        stamps = sorted(volts)
        assert all(b - a == 200 * DT_NS for a, b in zip(stamps, stamps[1:]))  # contiguous, no gap
        # a held set-point, once the reference stream has stopped for hold_timeout
        n0 = len(volts)
        pub = probe.node.create_publisher(PointStamped, "reference_point", 10)
        probe.spin_until(lambda: pub.get_subscription_count() > 0, 10, "reference_point subscriber")
        msg = PointStamped()
        msg.point.x, msg.point.y = 5e-6, -3e-6
        pub.publish(msg)
        probe.spin_until(lambda: len(volts) >= n0 + 10, 10, "voltage blocks from the held point")
        held = [volts[s] for s in sorted(volts)[n0:]]
        assert all(np.all(np.isfinite(b)) and b.shape == (200, 2) for b in held)
        assert held[-1][-1, 0] > 0 > held[-1][-1, 1]  # voltages of the held point's signs
        assert sorted(volts)[n0] == stamps[-1] + 200 * DT_NS  # the held blocks continue the sample stream
    finally:
        codes = {n: stop_node(p) for n, p in procs.items() if n != "recorder"}
        rec = procs["recorder"]
        rec.send_signal(signal.SIGTERM)
        codes["recorder"] = rec.wait(15)
    assert codes == {"compensator": 0, "trajectory": 0, "recorder": 0}
    from mcap.reader import make_reader

    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics.message_count > 200  # finished file: summary + statistics
    # the trajectory played `preview` samples ahead: the first recorded reference block is the trajectory's
    # samples [preview, preview + 200), exactly (the recorder was connected before the start)
    from piezo_ff_ros.core.recording.blocks import deserialize_block
    from piezo_ff_ros.core.trajectories import from_dict

    with open(out, "rb") as f:
        first = min((deserialize_block(m.data)[:2] for _, c, m in make_reader(f).iter_messages(topics=["/reference"])),
                    key=lambda sb: sb[0])[1]
    np.testing.assert_array_equal(first, from_dict(spec).block(preview, 200, FS))
