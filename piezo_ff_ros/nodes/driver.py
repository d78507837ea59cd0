"""Driver node: ``voltage`` blocks → (safety) → backend → ``displacement`` blocks, ``joint_states``, ``/diagnostics``.

Whatever it is sent, the voltage applied is within ``±limits.voltage`` and changes by at most ``limits.slew`` V/s
(:class:`piezo_ff_ros.core.safety.VoltageGuard`).  NaN/Inf/wrong-shape/oversized blocks are rejected with an error log
and the last voltage is held for the block's duration; with no block for ``limits.stale_timeout`` s the output ramps
to ``limits.safe_voltage`` at the slew limit.  The displacement block with stamp S answers the voltage block with
stamp S; the stale ramp is published with the stamps that follow the last block.

Parameters: ``config_file`` (''=paper config), ``variant``, ``backend`` ('sim'), ``noise_std`` [m], ``seed``,
``max_block`` (samples), ``joint_states_rate`` [Hz], ``diagnostics_period`` [s], ``limits.voltage|slew|
stale_timeout|safe_voltage`` (default: the config's ``limits``).  Service ``~/reset`` (std_srvs/Trigger): back to
rest (simulator only).
"""
from __future__ import annotations

import sys
import time
from dataclasses import replace

import numpy as np

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from sensor_msgs.msg import JointState, PointCloud2
from std_srvs.srv import Trigger

from ..core.config import LimitsConfig, load_config
from ..core.safety import BlockRejected, VoltageGuard
from .backends import BackendError, make_backend
from .common import BLOCK_QOS, BlockFormatError, diag_values, dt_ns, pack_block, run_node, stamp_to_ns, unpack_block


class DriverNode(Node):
    """See the module docstring."""

    def __init__(self, **kwargs):
        super().__init__("driver", **kwargs)
        p = self._declare_all()
        self.axes = self.cfg.axes
        self.period_ns = dt_ns(self.cfg.sample_rate)
        self.guard = VoltageGuard(self.limits, self.cfg.n_axes, self.cfg.sample_rate, max_block=p["max_block"])
        self.backend = make_backend(p["backend"], self.cfg, p)
        self.backend.open()
        self.backend.start()
        self.state = "idle"            # idle (nothing yet) | active | safe (ramped down after stale input)
        self.next_stamp_ns = None      # stamp the next block should have
        self.last_block_wall = None
        self.last_block_n = 200
        self.gap_samples = 0           # samples skipped between consecutive blocks (k0 jumps)
        self.late_blocks = 0           # blocks overlapping samples already applied (dropped)
        self.malformed_blocks = 0      # messages that are not a block of the contract
        self.last_error = ""
        self._js_every = max(1, int(round(self.cfg.sample_rate / max(p["joint_states_rate"], 1e-3))))
        self._js_next = 0
        self._samples_out = 0

        self.pub_y = self.create_publisher(PointCloud2, "displacement", BLOCK_QOS)
        self.pub_js = self.create_publisher(JointState, "joint_states", 10)
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.sub_u = self.create_subscription(PointCloud2, "voltage", self.on_voltage, BLOCK_QOS)
        self.create_service(Trigger, "~/reset", self.on_reset)
        self.create_timer(min(self.limits.stale_timeout / 4.0, 0.05), self.check_stale)
        self.create_timer(p["diagnostics_period"], self.publish_diagnostics)
        self.get_logger().info(f"driver ready: backend {p['backend']}, ±{self.limits.voltage} V, "
                               f"{self.limits.slew} V/s, stale {self.limits.stale_timeout} s")

    # -- parameters ------------------------------------------------------------------------------------------------
    def _declare_all(self) -> dict:
        cfg_file = self.declare_parameter("config_file", "").value
        variant = self.declare_parameter("variant", "").value
        self.cfg = load_config(cfg_file or None, variant or None)
        lim = self.cfg.limits
        limits = {k: float(self.declare_parameter(f"limits.{k}", float(getattr(lim, k))).value)
                  for k in ("voltage", "slew", "stale_timeout", "safe_voltage")}
        self.limits = LimitsConfig(**limits).validate()
        self.cfg = replace(self.cfg, limits=self.limits)
        return {"backend": self.declare_parameter("backend", "sim").value,
                "noise_std": float(self.declare_parameter("noise_std", 0.0).value),
                "seed": int(self.declare_parameter("seed", 0).value),
                "max_block": int(self.declare_parameter("max_block", 20000).value),
                "joint_states_rate": float(self.declare_parameter("joint_states_rate", 100.0).value),
                "diagnostics_period": float(self.declare_parameter("diagnostics_period", 1.0).value)}

    # -- data path -------------------------------------------------------------------------------------------------
    def on_voltage(self, msg: PointCloud2) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        if self.next_stamp_ns is not None and stamp < self.next_stamp_ns:
            # those sample instants are past (applied by an earlier block or by the stale ramp): never rewrite them
            self.late_blocks += 1
            self._error(f"late block dropped: stamp {stamp} overlaps samples already applied "
                        f"(next expected {self.next_stamp_ns}; ~/reset starts a new stream)")
            return
        if self.next_stamp_ns is not None and stamp > self.next_stamp_ns:
            self.gap_samples += (stamp - self.next_stamp_ns) // self.period_ns
        self.last_block_wall = time.monotonic()
        try:
            block = unpack_block(msg)
            u = self.guard.apply(block)
        except (BlockFormatError, BlockRejected) as exc:
            if isinstance(exc, BlockFormatError):
                self.malformed_blocks += 1
                self.guard.counters.rejected_blocks += 1
            n = int(msg.width) * int(msg.height)
            held = 0 < n <= self.guard.max_block
            self._error(f"voltage block rejected ({exc}); " +
                        (f"holding {self.guard.u_last.tolist()} V for {n} samples" if held else "nothing applied"))
            if not held:
                return
            u = self.guard.hold(n)
        self.state = "active"
        self._apply(u, stamp)

    def _apply(self, u: np.ndarray, stamp: int) -> None:
        try:
            y = self.backend.write(u)
        except BackendError as exc:
            self._error(f"backend: {exc}")
            return
        self.next_stamp_ns = stamp + u.shape[0] * self.period_ns
        self.last_block_n = u.shape[0]
        if y is not None:
            self.pub_y.publish(pack_block(y, self.axes, stamp))
            self._joint_states(y, stamp)
        self._samples_out += u.shape[0]

    def _joint_states(self, y: np.ndarray, stamp: int) -> None:
        if self._samples_out + y.shape[0] <= self._js_next:
            return
        self._js_next = (self._samples_out + y.shape[0]) // self._js_every * self._js_every + self._js_every
        js = JointState()
        last = stamp + (y.shape[0] - 1) * self.period_ns
        js.header.stamp.sec, js.header.stamp.nanosec = last // 1_000_000_000, last % 1_000_000_000
        js.header.frame_id = "piezo"
        js.name = list(self.axes)
        js.position = [float(v) for v in y[-1]]
        self.pub_js.publish(js)

    def check_stale(self) -> None:
        if self.state != "active" or self.last_block_wall is None:
            return
        if time.monotonic() - self.last_block_wall < self.limits.stale_timeout:
            return
        u_from = self.guard.u_last.tolist()
        ramp = self.guard.ramp_to_safe()
        if ramp.shape[0]:
            self.get_logger().warning(f"no voltage block for {self.limits.stale_timeout} s: ramping "
                                   f"from {u_from} V to the safe state "
                                   f"{self.limits.safe_voltage} V in {ramp.shape[0]} samples")
            for i in range(0, ramp.shape[0], self.last_block_n):
                self._apply(ramp[i:i + self.last_block_n], self.next_stamp_ns)
        else:
            self.guard.counters.safe_ramps += 1
        self.backend.safe_state()
        self.state = "safe"

    def on_reset(self, request, response):
        if self.backend.reset():
            self.guard.reset()
            self.state, self.next_stamp_ns, self._samples_out, self._js_next = "idle", None, 0, 0
            self.gap_samples = self.late_blocks = self.malformed_blocks = 0
            response.success, response.message = True, "backend and safety state reset"
        else:
            response.success, response.message = False, f"backend {self.backend.name} cannot be reset"
        return response

    # -- diagnostics -----------------------------------------------------------------------------------------------
    def _error(self, text: str) -> None:
        self.last_error = text
        self.get_logger().error(text)

    def status(self) -> dict:
        d = {"state": self.state, **self.guard.counters.as_dict(), "gap_samples": self.gap_samples,
             "late_blocks": self.late_blocks, "malformed_blocks": self.malformed_blocks,
             "applied_voltage": self.guard.u_last.tolist(), "next_stamp_ns": self.next_stamp_ns,
             "last_error": self.last_error}
        d.update(self.backend.status())
        return d

    def publish_diagnostics(self) -> None:
        st = self.status()
        level = DiagnosticStatus.OK
        if st["rejected_blocks"] or st["late_blocks"] or st["saturated_samples"]:
            level = DiagnosticStatus.WARN
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [DiagnosticStatus(level=level, name=f"{self.get_fully_qualified_name()}", message=self.state,
                                       hardware_id=self.backend.name, values=diag_values(st))]
        self.pub_diag.publish(arr)


def main(argv=None) -> int:
    return run_node("driver", DriverNode, lambda n: n.backend.close(), argv)


if __name__ == "__main__":
    sys.exit(main())
