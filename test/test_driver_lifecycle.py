"""The driver as a managed (lifecycle) node, driven through its lifecycle services while voltage blocks flow.

Each test starts its own driver on the clocked simulator (paced by the wall clock, like a DAQ) and reads what the
device applied on ``voltage_applied``: every sample, holds and ramps included.
"""
from __future__ import annotations

import contextlib
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from test_nodes_integration import AXES, DT_NS, FS, Probe, start_node, stop_node  # noqa: E402

#: the driver's default safe ramp: at most 1e4 V/s, i.e. 0.5 V per 50 µs sample
SAFE_STEP = 1.0e4 / FS
BLOCK = 200


class Rig:
    """A probe that streams real-time voltage blocks to the driver, records voltage_applied, calls its services."""

    def __init__(self, probe: Probe) -> None:
        from lifecycle_msgs.srv import ChangeState, GetState
        from sensor_msgs.msg import PointCloud2

        from piezo_ff_ros.nodes.common import BLOCK_QOS, stamp_to_ns, unpack_block

        self.p = probe
        self.applied: dict[int, np.ndarray] = {}
        self.log_lines: list[str] = []
        probe.node.create_subscription(PointCloud2, "voltage_applied", lambda m: self.applied.__setitem__(
            stamp_to_ns(m.header.stamp), unpack_block(m, AXES)), BLOCK_QOS)
        self.pub = probe.node.create_publisher(PointCloud2, "voltage", BLOCK_QOS)
        self.change = probe.node.create_client(ChangeState, "/driver/change_state")
        self.get = probe.node.create_client(GetState, "/driver/get_state")
        self.k = 0                       # next sample index of the stream sent
        self.t0: float | None = None

    def state(self) -> str:
        from lifecycle_msgs.srv import GetState

        return self.p.call(self.get, GetState.Request(), 30, resend_every=2.0).current_state.label

    def transition(self, label: str, volts: float | None = None) -> bool:
        """Ask for a transition; while waiting for the answer, keep streaming blocks of ``volts`` (None: none)."""
        from lifecycle_msgs.srv import ChangeState

        assert self.change.wait_for_service(timeout_sec=30)
        req = ChangeState.Request()
        req.transition.label = label
        fut = self.change.call_async(req)
        deadline = time.monotonic() + 30
        while not fut.done():
            assert time.monotonic() < deadline, f"no answer to {label}"
            self.stream(volts, 0.02)
        return bool(fut.result().success)

    def stream(self, volts: float | None, seconds: float) -> None:
        """Publish blocks of ``volts`` paced at the sample rate (None: only spin) for ``seconds``."""
        from piezo_ff_ros.nodes.common import pack_block

        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if volts is not None:
                if self.t0 is None:
                    self.t0 = time.monotonic() - self.k / FS
                # keep ~20 ms ahead of real time, as a compensator does
                while self.k / FS < time.monotonic() - self.t0 + 0.02:
                    self.pub.publish(pack_block(np.full((BLOCK, len(AXES)), volts), AXES, self.k * DT_NS))
                    self.k += BLOCK
            else:
                self.t0 = None     # a pause: the stream resumes from real time, not from where it stopped
                self.k += int(FS * 0.02)
            self.p.ex.spin_once(timeout_sec=0.005)

    def series(self) -> np.ndarray:
        stamps = sorted(self.applied)
        ks = np.concatenate([s + DT_NS * np.arange(self.applied[s].shape[0]) for s in stamps])
        assert np.all(np.diff(ks) == DT_NS), "voltage_applied has holes or repeats"
        return np.vstack([self.applied[s] for s in stamps])


@pytest.fixture()
def probe():
    p = Probe("lifecycle_probe")
    yield p
    p.close()


def _start(tmp_path, *args):
    # a 0.1 s write-ahead (the default is 0.5 s): these checks stream blocks for fractions of a second and read
    # what the device played, which a deeper write-ahead only delays
    return start_node("driver", "-p", "autostart:=false", "-p", "sim.mode:=clocked", "-p", "diagnostics_period:=0.2",
                      "-p", "write_ahead:=0.1", *args, log_dir=tmp_path)


def test_deactivate_at_100_volts_ramps_activate_resumes_shutdown_ends_safe(tmp_path, probe):
    """configure → inactive (blocks ignored, output at the safe 0 V); activate → 100 V blocks applied; deactivate
    while 100 V blocks keep coming → a ramp no steeper than the safe step, then 0 V held; activate → 100 V again;
    shutdown from active → a ramp to 0 V."""
    rig = Rig(probe)
    drv = _start(tmp_path)
    try:
        assert rig.state() == "unconfigured"
        assert rig.transition("configure")
        assert rig.state() == "inactive"
        probe.spin_until(lambda: rig.pub.get_subscription_count() > 0, 30, "the driver's voltage subscription")
        probe.spin_for(1.0)   # the driver's writer discovers this reader (volatile QoS)
        rig.stream(100.0, 0.3)                        # inactive: ignored
        k_ignored = rig.k
        assert rig.transition("activate", 100.0)
        rig.stream(100.0, 0.5)
        n_active = rig.series().shape[0]
        assert rig.transition("deactivate", 100.0)    # blocks keep flowing while it ramps
        assert rig.state() == "inactive"
        rig.stream(100.0, 0.5)                        # ignored: the output holds 0 V
        n_inactive = rig.series().shape[0]
        assert rig.transition("activate", 100.0)
        rig.stream(100.0, 0.5)
        n_resumed = rig.series().shape[0]
        assert rig.transition("shutdown", 100.0)
        assert rig.state() == "finalized"
        probe.spin_for(0.5)
    finally:
        assert stop_node(drv) == 0
    u = rig.series()
    assert min(rig.applied) >= k_ignored * DT_NS       # nothing sent while inactive was applied
    first_100 = int(np.argmax(u[:, 0] == 100.0))
    assert first_100 < n_active
    # the deactivate ramp: from the last 100 V sample down to 0 V, no step larger than the safe step
    last_100 = first_100 + int(np.argmin(u[first_100:, 0] == 100.0)) - 1
    down = int(np.argmax(u[last_100:, 0] == 0.0)) + last_100
    assert last_100 < n_inactive and down > last_100 + 100
    assert np.abs(np.diff(u[last_100:down + 1], axis=0)).max() <= SAFE_STEP + 1e-9
    assert np.all(u[down:n_inactive - 1] == 0.0)      # held at 0 V while inactive, 100 V blocks notwithstanding
    # activate: applied again
    resumed = u[n_inactive:n_resumed]
    assert np.any(resumed == 100.0)
    # shutdown from active: ends at 0 V by a safe ramp
    tail = u[int(np.flatnonzero(u[:, 0] == 100.0)[-1]):]
    np.testing.assert_array_equal(tail[-1], [0.0, 0.0])
    assert np.abs(np.diff(tail, axis=0)).max() <= SAFE_STEP + 1e-9


def test_failing_configure_stays_unconfigured_with_one_line_and_can_be_fixed(tmp_path, probe):
    """A bad backend parameter: configure fails, the driver stays unconfigured, its log says so in one line naming
    the parameter; set while unconfigured, the next configure succeeds."""
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    rig = Rig(probe)
    drv = _start(tmp_path, "-p", "sim.fifo_depth:=3")
    try:
        assert rig.state() == "unconfigured"
        assert not rig.transition("configure")
        assert rig.state() == "unconfigured"
        setp = probe.node.create_client(SetParameters, "/driver/set_parameters")
        req = SetParameters.Request(parameters=[Parameter(name="sim.fifo_depth", value=ParameterValue(
            type=ParameterType.PARAMETER_INTEGER, integer_value=8000))])
        assert probe.call(setp, req, 30).results[0].successful
        assert rig.transition("configure")
        assert rig.state() == "inactive"
        # configured: the device's parameters are frozen until cleanup
        res = probe.call(setp, req, 30).results[0]
        assert not res.successful and "unconfigured" in res.reason
    finally:
        assert stop_node(drv) == 0
    lines = [ln for ln in drv.log_path.read_text().splitlines() if "configure failed" in ln]
    assert len(lines) == 1 and "sim.fifo_depth" in lines[0], lines
    assert "Traceback" not in drv.log_path.read_text()


@pytest.mark.parametrize("signame", ["SIGINT", "SIGTERM"])
def test_sigint_while_active_at_100_volts_ramps_before_closing(tmp_path, probe, signame):
    """SIGINT (Ctrl-C) or SIGTERM (a supervisor's stop) of an active driver holding 100 V: the output ramps to the
    safe voltage before the backend closes (the ramp is played on the device; the log says from where and in how
    many samples)."""
    import signal
    import subprocess

    rig = Rig(probe)
    drv = _start(tmp_path)
    try:
        assert rig.transition("configure") and rig.transition("activate")
        probe.spin_until(lambda: rig.pub.get_subscription_count() > 0, 30, "the driver's voltage subscription")
        probe.spin_for(1.0)
        rig.stream(100.0, 0.5)
        assert np.any(rig.series() == 100.0)
        drv.send_signal(getattr(signal, signame))
        with contextlib.suppress(subprocess.TimeoutExpired):
            drv.wait(15)
    finally:
        assert stop_node(drv) == 0
    log = drv.log_path.read_text()
    line = next(ln for ln in log.splitlines() if "shutting down: ramping from" in ln)
    n = int(line.split(" in ")[-1].split()[0])
    assert "[100.0, 100.0]" in line and n >= 100 / SAFE_STEP, line
    # the ramp is published too (the node stops with its context up): voltage_applied's readers see it end safe
    probe.spin_until(lambda: rig.applied and rig.series()[-1].tolist() == [0.0, 0.0], 10,
                     "the SIGINT ramp's last sample on voltage_applied")
    u = rig.series()
    assert np.abs(np.diff(u, axis=0)).max() <= SAFE_STEP + 1e-9


def test_an_error_in_a_transition_goes_through_error_processing_to_safe():
    """A transition that raises (here: deactivate, once) → ErrorProcessing → the output ramps to the safe voltage,
    the backend is closed, the driver is back unconfigured (and can be configured again)."""
    from rclpy.lifecycle import TransitionCallbackReturn

    with _in_process_driver_at_100_volts("error") as (_, node):
        assert node.core.guard.u_last.tolist() == [100.0, 100.0]
        core, real = node.core, node._to_safe
        calls = []

        def failing_once(why):
            calls.append(why)
            if len(calls) == 1:
                raise RuntimeError("the device did not answer")
            real(why)

        node._to_safe = failing_once
        assert node.trigger_deactivate() == TransitionCallbackReturn.ERROR
        assert node.lifecycle_state == "unconfigured" and node.core is None
        assert core.guard.u_last.tolist() == [0.0, 0.0] and core.guard.counters.safe_ramps >= 1
        node._to_safe = real
        assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS


def test_a_shutdown_racing_the_final_ramp_is_a_clean_exit():
    """SIGINT's handler shuts the context down on another thread; if that lands between the driver's "context ok?"
    check and a publish of the final ramp's ``voltage_applied``, rclpy raises "publisher's context is invalid".  The
    ramp has been handed to the device already: finishing must not fail (the node exited with code 1 before)."""
    with _in_process_driver_at_100_volts("race") as (ctx, node):
        core, real_publish = node.core, node.pub_u.publish

        def publish_as_the_signal_lands(msg):
            if ctx.ok():
                rclpy.try_shutdown(context=ctx)   # what the SIGINT handler does, between the check and the publish
            real_publish(msg)                     # raises: the publisher's context is invalid

        node.pub_u.publish = publish_as_the_signal_lands
        node.finish()                             # must not raise
        assert core.guard.u_last.tolist() == [0.0, 0.0] and core.guard.counters.safe_ramps >= 1


@contextlib.contextmanager
def _in_process_driver_at_100_volts(tag: str):
    """A driver node in this process (own context), configured, active, with a 100 V block applied; ``(ctx, node)``.
    Renamed and namespaced: no later test of this session may take it for a running driver (`/driver`,
    `/voltage`)."""
    from rclpy.context import Context
    from rclpy.lifecycle import TransitionCallbackReturn

    from piezo_ff_ros.nodes.driver import DriverNode

    ctx = Context()
    rclpy.init(context=ctx)
    node = DriverNode(context=ctx, namespace=f"/lifecycle_{tag}_test",
                      cli_args=["--ros-args", "-r", f"__node:=driver_{tag}_test"],
                      parameter_overrides=[rclpy.parameter.Parameter("autostart", value=False)])
    try:
        assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
        assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
        node.on_tick()
        node.core.on_block(0, np.full((400, 2), 100.0))
        yield ctx, node
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
