"""Start-up on this 2-core machine: the first point held with ``reference_point`` right after the graph is up, and
its first blocks, never trip the driver's stale-input ramp (kernels are warm before the driver expects blocks, the
nodes' start-up heaps are frozen before they spin, the driver's own stalls are not stale input, and the held point's
blocks are large enough for a loaded host to keep up).

compensator → driver on the clocked simulator (wall-clock paced, with its default write-ahead and stale timeout),
as separate processes; this probe holds a point the moment both nodes say they are ready.
"""
from __future__ import annotations

import os
import signal

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from test_driver_node import _io  # noqa: E402
from test_nodes_integration import Probe, start_node, stop_node  # noqa: E402


@pytest.fixture()
def probe():
    p = Probe("first_hold_probe")
    yield p
    p.close()


def _ready(proc, marker: str) -> bool:
    return marker in proc.log_path.read_text(errors="replace")


def test_first_held_point_after_start_does_not_trip_the_stale_ramp(tmp_path, probe):
    """With the driver's defaults (write-ahead, stale timeout) and warm kernels: no ramp, no late block, no WARN."""
    log, diags = _hold_right_after_start(tmp_path, probe, [])
    assert "no voltage block for" not in log, log[-2000:]
    assert "late block dropped" not in log and "underrun" not in log, log[-2000:]
    assert not any(d[2].get("state") == "safe" for d in diags), [d[1] for d in diags][-5:]
    assert diags and diags[-1][0] == 0, diags[-1][:2]    # /diagnostics OK, not WARN from then on


def test_a_write_ahead_too_short_for_the_host_is_named_in_the_log(tmp_path, probe):
    """A driver starved by a 2 ms write-ahead: its log names the setting that fixes it."""
    log, _ = _hold_right_after_start(tmp_path, probe, ["-p", "write_ahead:=0.002", "-p", "low_water:=0.001"])
    assert "underrun" in log or "late block dropped" in log
    hint = next(ln for ln in log.splitlines() if "hint:" in ln)
    assert "write_ahead" in hint and "now 0.002 s" in hint, hint


def test_a_driver_that_stood_still_longer_than_the_stale_timeout_does_not_ramp(tmp_path, probe):
    """The driver process stopped (SIGSTOP) for 0.35 s mid-hold — longer than its stale timeout (0.2 s), shorter than
    its write-ahead (0.5 s): the blocks sent meanwhile wait in its reader, so no stale ramp and no late block."""
    def stall(procs):
        os.kill(procs[0].pid, signal.SIGSTOP)
        try:
            probe.spin_for(0.35)
        finally:
            os.kill(procs[0].pid, signal.SIGCONT)

    log, diags = _hold_right_after_start(tmp_path, probe, [], during=stall)
    assert "no voltage block for" not in log, log[-2000:]
    assert "late block dropped" not in log and "underrun" not in log, log[-2000:]
    assert not any(d[2].get("state") == "safe" for d in diags), [d[1] for d in diags][-5:]


def test_a_source_that_really_stops_still_ramps_and_the_log_names_the_setting(tmp_path, probe):
    """The compensator stopped (SIGSTOP) mid-hold until the driver does ramp to safe, and both its ramp line and
    its hint name ``limits.stale_timeout``."""
    def stall(procs):
        os.kill(procs[1].pid, signal.SIGSTOP)
        try:
            probe.spin_until(lambda: "no voltage block for" in procs[0].log_path.read_text(errors="replace"), 10,
                             "the driver's stale ramp")
        finally:
            os.kill(procs[1].pid, signal.SIGCONT)

    log, _ = _hold_right_after_start(tmp_path, probe, [], during=stall)
    ramp = next(ln for ln in log.splitlines() if "no voltage block for" in ln)
    assert "no voltage block for 0.2 s (limits.stale_timeout)" in ramp, ramp
    hint = next(ln for ln in log.splitlines() if "hint:" in ln and "stale" in ln)
    assert "limits.stale_timeout" in hint, hint


def _hold_right_after_start(tmp_path, probe, driver_args, during=None):
    from geometry_msgs.msg import PointStamped

    got, diags, _ = _io(probe, publisher=False)
    pub = probe.node.create_publisher(PointStamped, "reference_point", 10)
    procs = [start_node("driver", "-p", "sim.mode:=clocked", "-p", "diagnostics_period:=0.2", *driver_args,
                        log_dir=tmp_path),
             start_node("compensator", "-p", "cascade.vibration:=false", log_dir=tmp_path)]
    try:
        probe.spin_until(lambda: _ready(procs[0], "driver ready") and _ready(procs[1], "compensator ready"), 90,
                         "both nodes ready")
        probe.spin_until(lambda: pub.get_subscription_count() > 0, 30, "the compensator's reference_point reader")
        msg = PointStamped()
        msg.point.x = 5e-6
        pub.publish(msg)
        probe.spin_until(lambda: got["voltage_applied"] and max(np.max(np.abs(b)) for b in
                                                                  got["voltage_applied"].values()) > 1.0,
                         30, "the held point's voltage applied")
        if during is not None:
            during(procs)
        probe.spin_for(2.0)
        log = procs[0].log_path.read_text(errors="replace")    # before anything stops (then the input stops)
        n_diags = len(diags)
    finally:
        codes = [stop_node(p) for p in procs]                   # the driver first: it must not starve
    assert codes == [0, 0]
    return log, diags[:n_diags]


def test_a_spinning_node_leaves_its_start_up_heap_out_of_garbage_collection(tmp_path):
    """A node spun by ``spin_node`` has its start-up heap frozen: a full collection then walks only what the stream
    allocated (the start-up heap's collection stalled a node for 0.3–0.8 s a few seconds into the first stream)."""
    import subprocess
    import sys

    from test_nodes_integration import child_env

    code = ("import gc, rclpy\n"
            "from piezo_ff_ros.nodes import common\n"
            "from piezo_ff_ros.nodes.driver import DriverNode\n"
            "rclpy.init()\n"
            "node = DriverNode()\n"
            "before = len(gc.get_objects())\n"
            "node.create_timer(0.05, lambda: (print('tracked', before, len(gc.get_objects()), gc.get_freeze_count(),"
            " flush=True), rclpy.shutdown()))\n"
            "raise SystemExit(common.spin_node(node, on_exit=node.finish))\n")
    out = subprocess.run([sys.executable, "-c", code], env=child_env(), capture_output=True, text=True, timeout=120)
    line = next((ln for ln in out.stdout.splitlines() if ln.startswith("tracked")), None)
    assert line is not None and out.returncode == 0, out.stdout[-1000:] + out.stderr[-2000:]
    before, tracked, frozen = (int(v) for v in line.split()[1:])
    assert frozen >= before // 2 and tracked < before // 10, line
