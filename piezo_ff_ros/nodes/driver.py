"""Driver node: ``voltage`` blocks → safety → device → ``voltage_applied`` + ``displacement`` blocks,
``joint_states``, ``/diagnostics``.  Wiring only: the logic is :class:`piezo_ff_ros.core.hardware.DriverCore`.

Whatever it is sent, the voltage applied is within ``±limits.voltage`` and changes by at most ``limits.slew`` V/s.
Malformed blocks (NaN/Inf, other fields such as ``[y, x]``, wrong shape) are rejected with an error log and the
last voltage is held for their samples; oversized blocks (> ``max_block``) are not applied.  Gaps in the stamps are held
and counted, late samples dropped and counted, a block far off the stream is applied only once the next block
confirms the jump; with no block for ``limits.stale_timeout`` s the output ramps to ``limits.safe_voltage`` along the
``safe_ramp`` (its own duration and slew).  ``voltage_applied`` carries every sample the device actually output
(holds and ramps included) on the stamp grid of ``voltage``; ``displacement`` the sensor samples on the same grid.

Parameters (read-only, validated at start-up; a bad one is a one-line error naming it): ``config_file``,
``variant``, ``backend`` (``sim``; plug-ins: ``piezo_ff_ros.backends`` entry points) and its ``<backend>.*``
parameters, ``noise_std`` [m] and ``seed`` (sim sensor), ``max_block`` [samples], ``max_gap``, ``write_ahead``,
``low_water`` [s], ``joint_states_rate`` [Hz], ``diagnostics_period`` [s], ``limits.voltage|slew|stale_timeout|
safe_voltage`` (default the config's; may only tighten them), ``safe_ramp.duration|slew``.  Service ``~/reset``
(std_srvs/Trigger): back to rest (simulator only).
"""
from __future__ import annotations

import math
import os
import sys
from dataclasses import replace
from typing import Any

import numpy as np

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from sensor_msgs.msg import JointState, PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from ..core.config import ConfigError, load_config
from ..core.hardware import DriverCore, DriverSettings
from ..core.hardware.driver_core import ERROR, Emit, lockstep_pacing
from ..core.safety import SafeRampConfig
from ..backends import get_spec
from .common import (BLOCK_QOS, LATCHED_QOS, BlockFormatError, diag_values, log_lines, pack_block, run_node,
                     stamp_to_ns, unpack_block, writer_matches)

_LEVEL = {0: DiagnosticStatus.OK, 1: DiagnosticStatus.WARN, 2: DiagnosticStatus.ERROR}


def _check(name: str, value: Any, lo: float, hi: float, unit: str = "") -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and lo <= value <= hi):
        raise ConfigError(name, f"must be in [{lo:g}, {hi:g}]{unit}, got {value!r}")


class DriverNode(Node):
    """See the module docstring."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("driver", **kwargs)
        settings, backend_name, bparams, p = self._declare_all()
        self.axes = self.cfg.axes
        self.backend_name = backend_name
        backend = get_spec(backend_name).create(self.cfg, bparams)
        self.core = DriverCore(settings, backend)
        self.malformed_blocks = 0
        self.conflict = ""
        self._js_every = max(1, int(round(self.cfg.sample_rate / p["joint_states_rate"])))
        self._js_count = 0

        # no sensor, no displacement topic: a publisher that never publishes would pass for a sensor (commissioning
        # and lockstep trajectories look for one)
        self.has_sensor = bool(backend.info.has_sensor)
        self.pub_y = self.create_publisher(PointCloud2, "displacement", BLOCK_QOS) if self.has_sensor else None
        self.pub_u = self.create_publisher(PointCloud2, "voltage_applied", BLOCK_QOS)
        self.pub_js = self.create_publisher(JointState, "joint_states", 10)
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.sub_u = self.create_subscription(PointCloud2, "voltage", self.on_voltage, BLOCK_QOS)
        self.create_service(Trigger, "~/reset", self.on_reset)
        # a lockstep trajectory paces a lockstep simulator: its time stands still between blocks (no stale ramp)
        self.sub_traj = None
        if p["trajectory_state"] and backend.info.time_follows_samples:
            try:
                self.sub_traj = self.create_subscription(String, p["trajectory_state"], self.on_trajectory_state,
                                                         LATCHED_QOS)
            except Exception as exc:  # noqa: BLE001 - rclpy raises several types for an invalid topic name
                raise ConfigError("trajectory_state", f"not a valid topic name: {p['trajectory_state']!r} "
                                                      f"({str(exc).splitlines()[0][:100]})") from None
        lim = settings.limits
        tick = min(settings.low_water / 2, 0.005) if backend.info.clocked else min(lim.stale_timeout / 4, 0.05)
        # the device's clock starts with the first tick (not here: spinning may begin much later)
        self.create_timer(tick, self.on_tick)
        self.create_timer(p["diagnostics_period"], self.publish_diagnostics)
        self._conflict_timer = self.create_timer(2.0, self.check_conflict)
        mode = "clocked" if backend.info.clocked else "lockstep"
        if not self.has_sensor:
            self.get_logger().info("the device has no displacement sensor: no displacement topic")
        self.get_logger().info(f"driver ready: backend {backend_name} ({mode}), ±{lim.voltage} V, {lim.slew} V/s, stale {lim.stale_timeout} s, safe ramp ≥ "
                               f"{settings.ramp.duration} s at ≤ {settings.ramp.slew} V/s")

    # -- parameters ------------------------------------------------------------------------------------------------
    def _param(self, name: str, default: Any, description: str = "") -> Any:
        return self.declare_parameter(name, default, ParameterDescriptor(
            description=description or name, read_only=True)).value

    def _declare_all(self) -> tuple[DriverSettings, str, dict[str, Any], dict[str, Any]]:
        cfg_file = self._param("config_file", "", "configuration YAML ('' = the paper's)")
        variant = self._param("variant", "", "config variant")
        self.cfg = load_config(cfg_file or None, variant or None)
        lim = self.cfg.limits
        given = {k: float(self._param(f"limits.{k}", float(getattr(lim, k)))) for k in
                 ("voltage", "slew", "stale_timeout", "safe_voltage")}
        limits = replace(lim, voltage=given["voltage"], slew=given["slew"], stale_timeout=given["stale_timeout"],
                         safe_voltage=given["safe_voltage"]).validate()   # the config's workspace kept
        # the config describes the amplifier: a parameter may tighten its limits, never widen them
        for k in ("voltage", "slew"):
            if getattr(limits, k) > getattr(lim, k):
                raise ConfigError(f"limits.{k}", f"{getattr(limits, k)!r} exceeds the config's {getattr(lim, k)!r} "
                                                 "(the amplifier's range: change the config file to raise it)")
        _check("limits.stale_timeout", limits.stale_timeout, 1e-3, 3600.0, " s")
        self.cfg = replace(self.cfg, limits=limits)
        ramp = SafeRampConfig(duration=float(self._param("safe_ramp.duration", 0.05, "minimum safe-ramp duration [s]")),
                              slew=float(self._param("safe_ramp.slew", 1.0e4, "maximum safe-ramp slew [V/s]")))
        p = {"max_block": self._param("max_block", 20000, "largest accepted block [samples]"),
             "max_gap": float(self._param("max_gap", 1.0, "largest gap held [s]; larger jumps need confirmation")),
             "write_ahead": float(self._param("write_ahead", 0.05, "clocked devices: FIFO margin [s]")),
             "low_water": float(self._param("low_water", 0.01, "clocked devices: hold below this margin [s]")),
             "joint_states_rate": float(self._param("joint_states_rate", 100.0, "joint_states rate [Hz]")),
             "diagnostics_period": float(self._param("diagnostics_period", 1.0, "/diagnostics period [s]")),
             "trajectory_state": str(self._param("trajectory_state", "trajectory/state",
                                                 "the trajectory's ~/state topic: a lockstep run playing there "
                                                 "suspends the stale watchdog of a lockstep simulator ('' = never)"))}
        _check("diagnostics_period", p["diagnostics_period"], 0.05, 3600.0, " s")
        _check("joint_states_rate", p["joint_states_rate"], 0.01, 1000.0, " Hz")
        settings = DriverSettings(sample_rate=self.cfg.sample_rate, n_axes=self.cfg.n_axes, limits=limits, ramp=ramp,
                                  max_block=p["max_block"], max_gap=p["max_gap"], write_ahead=p["write_ahead"],
                                  low_water=p["low_water"]).validate()
        name = self._param("backend", "sim", "backend plug-in name")
        spec = get_spec(name)
        given = {}
        if name == "sim":  # the historical top-level names of the simulator's sensor noise
            given = {"noise_std": float(self._param("noise_std", 0.0, "sim sensor noise [m]")),
                     "seed": int(self._param("seed", 0, "sim noise seed"))}
        for pname, prm in spec.parameters.items():
            if pname in given:
                continue
            given[pname] = self._param(f"{name}.{pname}", prm.default, prm.description)
        return settings, name, spec.validate(given), p

    # -- data path -------------------------------------------------------------------------------------------------
    def on_voltage(self, msg: PointCloud2) -> None:
        if not self.core.started:
            self.on_tick()
        stamp = stamp_to_ns(msg.header.stamp)
        try:
            u = unpack_block(msg, self.axes)
        except BlockFormatError as exc:
            self.malformed_blocks += 1
            self._emit(self.core.on_block(stamp, n=int(msg.width) * int(msg.height), reject=str(exc)))
            return
        self._emit(self.core.on_block(stamp, u))

    def on_trajectory_state(self, msg: String) -> None:
        on, why = lockstep_pacing(msg.data)
        self._emit(self.core.set_stream_paced(on, why))

    def on_tick(self) -> None:
        self._emit(self.core.tick() if self.core.started else self.core.start())

    def _emit(self, em: Emit) -> None:
        for stamp, u in em.applied:
            self.pub_u.publish(pack_block(u, self.axes, stamp))
        for stamp, y in em.displacement:
            if self.pub_y is not None:
                self.pub_y.publish(pack_block(y, self.axes, stamp))
                self._joint_states(y, stamp)
        log_lines(self.get_logger(), em.log)

    def _joint_states(self, y: np.ndarray, stamp: int) -> None:
        n = y.shape[0]
        before = self._js_count
        self._js_count += n
        if self._js_count // self._js_every == before // self._js_every:
            return
        js = JointState()
        last = stamp + (n - 1) * self.core.period_ns
        js.header.stamp.sec, js.header.stamp.nanosec = last // 1_000_000_000, last % 1_000_000_000
        js.header.frame_id = "piezo"
        js.name = list(self.axes)
        js.position = [float(v) for v in y[-1]]
        self.pub_js.publish(js)

    def on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        if self.core.reset():
            self.malformed_blocks, self._js_count = 0, 0
            self._emit(self.core.tick())
            response.success, response.message = True, "backend and safety state reset"
        else:
            response.success, response.message = False, f"backend {self.backend_name} cannot be reset"
        return response

    # -- diagnostics -----------------------------------------------------------------------------------------------
    def check_conflict(self) -> None:
        """Two graphs on one ROS domain (or two drivers in one namespace) mix their blocks: say so plainly.  Also:
        a lockstep source that vanished (killed trajectory node) no longer paces the stream."""
        if self.sub_traj is not None and self.core.stream_paced and self.sub_traj.get_publisher_count() == 0:
            self._emit(self.core.set_stream_paced(False, "the trajectory node is gone"))
        others = {t: self.count_publishers(t) - (1 if t == "voltage_applied" or self.has_sensor else 0)
                  for t in ("displacement", "voltage_applied")}
        if any(v > 0 for v in others.values()):
            topics = ", ".join(self.resolve_topic_name(t) for t, v in others.items() if v > 0)  # the ones it is on
            text = (f"another driver publishes on {topics} (publishers besides this "
                    f"one: {others}): two graphs on ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID', '0')}? Give each "
                    "graph its own ROS_DOMAIN_ID or namespace (--ros-args -r __ns:=/tube2)")
            if text != self.conflict:
                self.get_logger().error(text)
            self.conflict = text
        else:
            self.conflict = ""

    def publish_diagnostics(self) -> None:
        self.check_conflict()
        st = {**self.core.status(), "malformed_blocks": self.malformed_blocks, "backend": self.backend_name,
              "has_sensor": self.has_sensor,
              **writer_matches({"voltage_applied": self.pub_u, "displacement": self.pub_y})}
        level, message = self.core.health()
        if self.conflict:
            level, message = ERROR, self.conflict
        st["conflict"] = self.conflict
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [DiagnosticStatus(level=_LEVEL[level], name=f"{self.get_fully_qualified_name()}",
                                       message=message, hardware_id=self.backend_name, values=diag_values(st))]
        self.pub_diag.publish(arr)


def main(argv: list[str] | None = None) -> int:
    return run_node("driver", DriverNode, lambda n: n.core.close(), argv)


if __name__ == "__main__":
    sys.exit(main())
