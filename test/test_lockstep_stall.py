"""A lockstep run must be lossless whatever the host's scheduling does (found by bench/soak.py).

Lockstep (trajectory ``mode:=lockstep``) is documented as "deterministic and lossless": the next block is sent when
the displacement of an earlier one came back.  But the driver's stale-input watchdog runs on the wall clock even
with the lockstep simulator: a stall of any node longer than ``limits.stale_timeout`` (0.2 s by default; the soak
measured 0.29 s round trips on the loaded 2-core machine) makes the driver ramp to the safe state over the stream's
next samples.  The blocks in flight then arrive "late" and are dropped, their displacement never comes back, and
the trajectory stops with ``failed`` after ``lockstep_timeout``.  Here the stall is made deterministic: the
compensator process is stopped (SIGSTOP) for 0.6 s in the middle of a lockstep run.  (Failed before the fix, as a
strict xfail; fixed by the driver suspending the watchdog of the lockstep simulator while a lockstep run plays.)
"""
from __future__ import annotations

import json
import os
import signal

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from test_driver_node import _io, _stream  # noqa: E402
from test_nodes_integration import DT_NS, FS, Probe, start_node, stop_node  # noqa: E402

SIGNAL_S = 10.0


@pytest.fixture()
def probe():
    p = Probe("lockstep_stall_probe")
    yield p
    p.close()


def test_lockstep_run_survives_a_stall_longer_than_the_stale_timeout(tmp_path, probe):
    from std_msgs.msg import String
    from std_srvs.srv import Trigger

    from piezo_ff_ros.nodes.common import LATCHED_QOS

    got, diags, _ = _io(probe, publisher=False)
    states = []
    probe.node.create_subscription(String, "/trajectory/state", lambda m: states.append(json.loads(m.data)),
                                   LATCHED_QOS)
    spec = {"type": "circle", "radius": 1e-5, "frequency": 5.0, "revolutions": SIGNAL_S * 5.0}
    procs = [start_node("driver", "-p", "diagnostics_period:=0.2", log_dir=tmp_path),   # default stale_timeout
             start_node("compensator", "-p", "cascade.vibration:=false", log_dir=tmp_path),
             start_node("trajectory", "-p", "mode:=lockstep", "-p", "block_size:=200", "-p", "window:=4",
                        "-p", f"trajectory:='{json.dumps(spec)}'", "-p", "min_subscribers:=1",
                        "-p", "lockstep_timeout:=5.0", log_dir=tmp_path)]
    comp = procs[1]
    try:
        probe.spin_until(lambda: all(sub.get_publisher_count() > 0 for sub in probe.block_subs), 90,
                         "the driver's voltage_applied and displacement publishers")
        probe.spin_for(1.5)    # the driver's writers discover the probe's readers too
        assert probe.call(probe.node.create_client(Trigger, "/trajectory/start"), Trigger.Request(), 60).success
        probe.spin_until(lambda: len(got["displacement"]) >= 20, 90, "20 displacement blocks")
        os.kill(comp.pid, signal.SIGSTOP)           # the compensator stalls (a loaded host) for 0.6 s
        try:
            probe.spin_for(0.6)
        finally:
            os.kill(comp.pid, signal.SIGCONT)
        probe.spin_until(lambda: states and states[-1]["state"] in ("finished", "failed"), 120, "trajectory end")
        probe.spin_for(1.0)
    finally:
        codes = [stop_node(p) for p in reversed(procs)]
    assert codes == [0, 0, 0]
    assert states[-1]["state"] == "finished", states[-1]
    ys, _ = _stream(got["displacement"])
    n = int(SIGNAL_S * FS)
    assert np.all(np.diff(ys[:n]) == DT_NS) and ys.size >= n      # every sample of the run answered once
    last = diags[-1][2]
    assert int(last["late_samples"]) == 0 and int(last["gap_samples"]) == 0, last


#: Fast DDS participant profile of the node that is killed: it announces a 4 s lease (default 20 s), so that the
#: others see its process gone after ≤ 4 s instead of 20 s.  Only the killed process's own announced lease matters.
_SHORT_LEASE_XML = """<?xml version="1.0" encoding="UTF-8"?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <participant profile_name="short_lease" is_default_profile="true">
    <rtps><builtin><discovery_config>
      <leaseDuration><sec>4</sec></leaseDuration>
      <leaseAnnouncement><sec>1</sec></leaseAnnouncement>
    </discovery_config></builtin></rtps>
  </participant>
</profiles>
"""


def test_a_vanished_lockstep_source_gives_the_watchdog_back(tmp_path, probe, monkeypatch):
    """The suspension lasts only while a lockstep run plays: when the trajectory node is killed (-9, no final
    state message) the driver sees its state publisher gone, and the stale watchdog ramps to safe."""
    got, diags, _ = _io(probe, publisher=False)
    spec = {"type": "circle", "radius": 1e-5, "frequency": 5.0, "revolutions": 1000.0}
    procs = [start_node("driver", "-p", "diagnostics_period:=0.2", log_dir=tmp_path),
             start_node("compensator", "-p", "cascade.vibration:=false", log_dir=tmp_path)]
    profile = tmp_path / "short_lease.xml"
    profile.write_text(_SHORT_LEASE_XML)
    with monkeypatch.context() as env:      # the trajectory node's process only
        env.setenv("FASTDDS_DEFAULT_PROFILES_FILE", str(profile))
        procs.append(start_node("trajectory", "-p", "mode:=lockstep", "-p", "block_size:=200", "-p", "window:=4",
                                "-p", f"trajectory:='{json.dumps(spec)}'", "-p", "min_subscribers:=1",
                                "-p", "autostart:=true", log_dir=tmp_path))
    try:
        probe.spin_until(lambda: diags and diags[-1][2].get("stream_paced") == "True"
                         and diags[-1][2].get("state") == "active", 90,
                         "the driver active with its watchdog suspended for the lockstep run")
        procs[2].kill()
        procs[2].wait(10)
        probe.spin_until(lambda: diags[-1][2].get("state") == "safe", 30, "the stale ramp once the source is gone")
        assert diags[-1][2]["stream_paced"] == "False"
    finally:
        if procs[2].poll() is None:     # never leave a playing trajectory behind on the test domain
            procs[2].kill()
            procs[2].wait(10)
        codes = [stop_node(p) for p in reversed(procs[:2])]
    assert codes == [0, 0]
