"""Driver node: ``voltage`` blocks → safety → device → ``voltage_applied`` + ``displacement`` blocks,
``joint_states``, ``/diagnostics``.  Wiring only: the logic is :class:`piezo_ff_ros.core.hardware.DriverCore`.

Whatever it is sent, the voltage applied is within ``±limits.voltage`` and changes by at most ``limits.slew`` V/s.
Malformed blocks (NaN/Inf, other fields such as ``[y, x]``, wrong shape) are rejected with an error log and the
last voltage is held for their samples; oversized blocks (> ``max_block``) are not applied.  Gaps in the stamps are held
and counted, late samples dropped and counted, a block far off the stream is applied only once the next block
confirms the jump; with no block for ``limits.stale_timeout`` s the output ramps to ``limits.safe_voltage`` along the
``safe_ramp`` (its own duration and slew).  ``voltage_applied`` carries every sample the device actually output
(holds and ramps included) on the stamp grid of ``voltage``; ``displacement`` the sensor samples on the same grid.

A managed (lifecycle) node: ``configure`` validates the parameters, opens the backend at the safe voltage and
warms the kernels (a failure: one line, still unconfigured); ``activate`` applies voltage blocks; ``deactivate``
ramps to the safe voltage (played on the device) and holds it, ignoring blocks; ``cleanup`` closes the backend;
``shutdown`` (any state), SIGINT/SIGTERM and an error in a transition ramp to safe, then close.  ``autostart``
(default true) steps it to active at start, so ``ros2 run`` behaves as a plain node.

Parameters (validated at configure; settable only while unconfigured; a bad one is a one-line error naming it):
``autostart``, ``config_file``, ``variant``, ``backend`` (``sim``; plug-ins: ``piezo_ff_ros.backends`` entry points)
and its ``<backend>.*`` parameters, ``noise_std`` [m] and ``seed`` (sim sensor), ``max_block`` [samples],
``max_gap``, ``write_ahead`` (default :data:`DEFAULT_WRITE_AHEAD_S`), ``low_water`` [s], ``joint_states_rate`` [Hz],
``diagnostics_period`` [s], ``limits.voltage|slew|stale_timeout|safe_voltage`` (default the config's; may only
tighten them), ``safe_ramp.duration|slew``.  Service ``~/reset`` (std_srvs/Trigger): back to rest (simulator only).
A late or starved stream and stale input are named once with the setting that fixes them (a ``hint:`` line).
"""
from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import replace
from typing import Any

import numpy as np

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.duration import Duration
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from sensor_msgs.msg import JointState, PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from ..core.config import ConfigError, load_config
from ..core.hardware import DriverCore, DriverSettings
from ..core.hardware.driver_core import ERROR, DriverOutput, lockstep_pacing
from ..core.safety import SafeRampConfig, tightened_limits
from ..backends import get_spec
from .common import (BLOCK_QOS, LATCHED_QOS, BlockFormatError, diag_values, log_lines, pack_block, run_node,
                     stamp_to_ns, unpack_block, writer_matches)
from .params import refuse_unknown_parameters

#: the write-ahead of a clocked device by default [s] (DriverSettings.write_ahead, 0.5 s).  0.05 s underran on the
#: first held point in 2 of 3 runs on a 2-core machine at load ≈ 9 (test/test_live_first_hold.py); 0.2 s underran
#: in rig-check with two CPU-bound loaders, 0.5 s held (docs/hardware.md).  Tracking costs nothing: references are
#: known ahead, only the latency of a newly held point grows by it.
DEFAULT_WRITE_AHEAD_S = DriverSettings.write_ahead

#: the setting that fixes each kind of start-up/stream trouble, said once per run in the driver's log
_HINTS = {
    "late": "blocks arrive later than the write-ahead allows (a loaded host?): raise the driver's write_ahead "
            "(now {write_ahead} s; e.g. --ros-args -p write_ahead:={suggest}, or set it while unconfigured)",
    "underrun": "the device ran dry: blocks arrive later than the write-ahead allows: raise the driver's "
                "write_ahead (now {write_ahead} s; e.g. --ros-args -p write_ahead:={suggest})",
    "stale": "no block for limits.stale_timeout ({stale} s): if the source is only slow (start-up, a loaded host), "
             "raise the driver's limits.stale_timeout or start the source before the driver is activated",
}

_LEVEL = {0: DiagnosticStatus.OK, 1: DiagnosticStatus.WARN, 2: DiagnosticStatus.ERROR}


def _check(name: str, value: Any, lo: float, hi: float, unit: str = "") -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and lo <= value <= hi):
        raise ConfigError(name, f"must be in [{lo:g}, {hi:g}]{unit}, got {value!r}")


class DriverNode(LifecycleNode):
    """See the module docstring."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("driver", **kwargs)
        self.core: DriverCore | None = None
        self.configure_error = ""
        self.ignored_blocks = 0
        self._configured_entities: list[tuple[str, Any]] = []
        self.pub_y = self.pub_u = self.pub_js = self.pub_diag = self.sub_traj = None
        # registered before any declare_parameter so that it sees the command line's overrides too
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.autostart = bool(self.declare_parameter("autostart", True, ParameterDescriptor(
            description="configure and activate at start (false: wait for `ros2 lifecycle set /driver configure`, "
                        "then `activate`)", read_only=True)).value)
        self.create_service(Trigger, "~/reset", self.on_reset)
        try:
            self._declare_all()   # every parameter visible (`ros2 param list`) before configure
        except Exception:  # noqa: BLE001 - a bad value: configure says so (and fails)
            pass
        if self.autostart:
            # `ros2 run` as before the driver was managed: a bad parameter is one line and exit code 2
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                raise RuntimeError(self.configure_error or "configure failed")
            if self.trigger_activate() != TransitionCallbackReturn.SUCCESS:
                raise RuntimeError("activate failed")
            self.get_logger().info("driver ready: active (autostart)")
        else:
            self.get_logger().info("driver ready: unconfigured (`ros2 lifecycle set /driver configure`, then "
                                   "`activate`)")

    @property
    def lifecycle_state(self) -> str:
        """The managed node's state label (``unconfigured``, ``inactive``, ``active``, ``finalized`` or a
        transition state)."""
        return str(self._state_machine.current_state[1])

    # -- lifecycle transitions ----------------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Validate the parameters, open the backend (its output at the safe voltage), warm the kernels."""
        try:
            self._configure()
        except Exception as exc:  # noqa: BLE001 - any bad parameter or backend error: one line, stay unconfigured
            self._teardown()
            self.configure_error = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            if not self.autostart:   # with autostart, main() prints it (one line, exit code 2)
                self.get_logger().error(f"configure failed: {self.configure_error} (still unconfigured: fix the "
                                        "parameter and configure again)")
            return TransitionCallbackReturn.FAILURE
        self.configure_error = ""
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Accept voltage blocks (the first one restarts from the safe voltage the output holds)."""
        self.get_logger().info("active: voltage blocks are applied")
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Safe ramp now, then hold the safe voltage; blocks are ignored until activated again."""
        self._logged("deactivate", self._to_safe, "deactivated")
        self.get_logger().info("inactive: output held at the safe voltage, blocks ignored "
                               "(`ros2 lifecycle set /driver activate` resumes)")
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Close the backend (the output is at the safe voltage since deactivate)."""
        self._logged("cleanup", self._close)
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """From any state: the safe voltage by a ramp, then the backend closed."""
        self._logged("shutdown", self._close)
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """A transition raised: ramp to safe, close, back to unconfigured (a new configure may retry)."""
        self.get_logger().error(f"error while leaving {state.label}: output ramped to the safe voltage, backend closed")
        try:
            self._close()
        except Exception as exc:  # noqa: BLE001 - the error state must end somewhere
            self.get_logger().error(f"closing after the error failed: {exc}")
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def _logged(self, transition: str, fn: Any, *args: Any) -> None:
        """Run a transition's work; an exception is logged in one line (rclpy would swallow it), then raised so
        that the node goes through ErrorProcessing (:meth:`on_error`)."""
        try:
            fn(*args)
        except Exception as exc:
            self.get_logger().error(f"{transition} failed: {exc}")
            raise

    def finish(self) -> None:
        """The process ends (SIGINT/SIGTERM or an error): from whatever state, ramp to safe and close."""
        self._close()

    def _to_safe(self, why: str) -> None:
        """Ramp to the safe voltage and wait (ticking a clocked device) until the device has played the ramp."""
        if self.core is None:
            return
        self._emit(self.core.ramp_to_safe(why))
        if not self.core.started:
            return
        lim = self.core.s
        budget = 2.0 + 2 * lim.write_ahead + lim.ramp.duration + lim.limits.voltage / lim.ramp.slew
        deadline = time.monotonic() + budget
        while not self.core.played_out():
            if time.monotonic() > deadline:
                self.get_logger().error(f"the safe ramp was not played out within {budget:.2f} s")
                break
            self._emit(self.core.tick())
            time.sleep(min(lim.low_water / 2, 0.002))
        self._emit(self.core.tick())   # what the device applied up to the end of the ramp
        if self.context.ok():           # the ramp reaches voltage_applied's readers before anything is torn down
            try:
                for pub in (self.pub_u, self.pub_y):
                    if pub is not None:
                        pub.wait_for_all_acked(Duration(seconds=1.0))
            except Exception:
                if self.context.ok():   # not the shutdown racing this wait (see _emit): a real error
                    raise

    def _close(self) -> None:
        """Safe ramp (if anything is applied), then close the backend and drop the configured entities."""
        if self.core is not None:
            try:
                self._to_safe("shutting down")
            finally:
                core, self.core = self.core, None
                core.close()
        self._teardown()

    def _teardown(self) -> None:
        for kind, entity in reversed(self._configured_entities):
            getattr(self, f"destroy_{kind}")(entity)
        self._configured_entities = []
        self.pub_y = self.pub_u = self.pub_js = self.pub_diag = self.sub_traj = None

    def _configured(self, kind: str, entity: Any) -> Any:
        self._configured_entities.append((kind, entity))
        return entity

    def _on_set_parameters(self, params: list[Any]) -> SetParametersResult:
        """The driver's parameters describe its device: they change only while it is unconfigured."""
        state = self.lifecycle_state if hasattr(self, "_state_machine") else "unconfigured"
        if state not in ("unconfigured", "configuring"):
            names = ", ".join(p.name for p in params)
            return SetParametersResult(successful=False, reason=(
                f"{names}: the driver's parameters change only while unconfigured (it is {state}): deactivate, "
                "cleanup, set, configure"))
        return SetParametersResult(successful=True)

    def _configure(self) -> None:
        settings, backend_name, bparams, p = self._declare_all()
        refuse_unknown_parameters(self)   # before the device is opened
        self.axes = self.cfg.axes
        self.backend_name = backend_name
        backend = get_spec(backend_name).create(self.cfg, bparams)
        try:
            self.core = DriverCore(settings, backend)
            # compile before the first block: on a clocked device it must be written within the write-ahead
            self.core.warm()
        except Exception:
            backend.close()
            self.core = None
            raise
        self.malformed_blocks = 0
        self.ignored_blocks = 0
        self._hinted: set[str] = set()
        self.conflict = ""
        self._js_every = max(1, int(round(self.cfg.sample_rate / p["joint_states_rate"])))
        self._js_count = 0

        # no sensor, no displacement topic: a publisher that never publishes would pass for a sensor (commissioning
        # and lockstep trajectories look for one)
        self.has_sensor = bool(backend.info.has_sensor)
        pub = lambda t, name, q: self._configured("publisher", self.create_publisher(t, name, q))  # noqa: E731
        self.pub_y = pub(PointCloud2, "displacement", BLOCK_QOS) if self.has_sensor else None
        self.pub_u = pub(PointCloud2, "voltage_applied", BLOCK_QOS)
        self.pub_js = pub(JointState, "joint_states", 10)
        self.pub_diag = pub(DiagnosticArray, "/diagnostics", 10)
        self._configured("subscription", self.create_subscription(PointCloud2, "voltage", self.on_voltage,
                                                                   BLOCK_QOS))
        # a lockstep trajectory paces a lockstep simulator: its time stands still between blocks (no stale ramp)
        self.sub_traj = None
        if p["trajectory_state"] and backend.info.time_follows_samples:
            try:
                self.sub_traj = self._configured("subscription", self.create_subscription(
                    String, p["trajectory_state"], self.on_trajectory_state, LATCHED_QOS))
            except Exception as exc:  # noqa: BLE001 - rclpy raises several types for an invalid topic name
                raise ConfigError("trajectory_state", f"not a valid topic name: {p['trajectory_state']!r} "
                                                      f"({str(exc).splitlines()[0][:100]})") from None
        lim = settings.limits
        tick = min(settings.low_water / 2, 0.005) if backend.info.clocked else min(lim.stale_timeout / 4, 0.05)
        self._last_tick: float | None = None
        # the device's clock starts with the first tick (not here: spinning may begin much later)
        self._configured("timer", self.create_timer(tick, self.on_tick))
        self._configured("timer", self.create_timer(p["diagnostics_period"], self.publish_diagnostics))
        self._configured("timer", self.create_timer(2.0, self.check_conflict))
        mode = "clocked" if backend.info.clocked else "lockstep"
        if not self.has_sensor:
            self.get_logger().info("the device has no displacement sensor: no displacement topic")
        self.get_logger().info(f"driver configured: backend {backend_name} ({mode}), ±{lim.voltage} V, {lim.slew} V/s, "
                               f"stale {lim.stale_timeout} s, safe ramp ≥ {settings.ramp.duration} s at ≤ "
                               f"{settings.ramp.slew} V/s")

    # -- parameters ------------------------------------------------------------------------------------------------
    def _param(self, name: str, default: Any, description: str = "") -> Any:
        """A parameter's value, declared on first use (a backend chosen later declares its own at configure)."""
        if not self.has_parameter(name):
            self.declare_parameter(name, default, ParameterDescriptor(
                description=(description or name) + " (changes only while unconfigured)"))
        return self.get_parameter(name).value

    def _declare_all(self) -> tuple[DriverSettings, str, dict[str, Any], dict[str, Any]]:
        cfg_file = self._param("config_file", "", "configuration YAML ('' = the paper's)")
        variant = self._param("variant", "", "config variant")
        self.cfg = load_config(cfg_file or None, variant or None)
        lim = self.cfg.limits
        given = {k: float(self._param(f"limits.{k}", float(getattr(lim, k)))) for k in
                 ("voltage", "slew", "stale_timeout", "safe_voltage")}
        limits = tightened_limits(lim, **given)   # tighten the amplifier's limits, never widen them
        self.cfg = replace(self.cfg, limits=limits)
        ramp = SafeRampConfig(duration=float(self._param("safe_ramp.duration", 0.05, "minimum safe-ramp duration [s]")),
                              slew=float(self._param("safe_ramp.slew", 1.0e4, "maximum safe-ramp slew [V/s]")))
        p = {"max_block": self._param("max_block", 20000, "largest accepted block [samples]"),
             "max_gap": float(self._param("max_gap", 1.0, "largest gap held [s]; larger jumps need confirmation")),
             "write_ahead": float(self._param("write_ahead", DriverSettings.write_ahead,
                                              "clocked devices: how far ahead of the device's clock the stream is "
                                              "placed [s]; raise it when blocks arrive late or the device runs dry")),
             "low_water": float(self._param("low_water", DriverSettings.low_water,
                                            "clocked devices: hold below this margin [s]")),
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
        if self.core is None:
            return
        if self.lifecycle_state != "active":
            # inactive: the output holds the safe voltage whatever is sent (the compensator may keep streaming)
            self.ignored_blocks += 1
            if self.ignored_blocks == 1:
                self.get_logger().warning("voltage blocks ignored: the driver is inactive (`ros2 lifecycle set "
                                          "/driver activate` applies them)")
            return
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
        if self.core is None:
            return
        on, why = lockstep_pacing(msg.data)
        self._emit(self.core.set_stream_paced(on, why))

    def on_tick(self) -> None:
        if self.core is None:
            return
        # a tick more than half the stale timeout after the previous one means this process stood still (a
        # collection, a host that did not schedule it): the blocks sent meanwhile wait in the reader, read right
        # after this tick — not stale input.  Shorter gaps (a loaded host's timer jitter) all count as silence.
        now = time.monotonic()
        half = self.core.s.limits.stale_timeout / 2
        stalled = 0.0 if self._last_tick is None else max(0.0, now - self._last_tick - half)
        self._last_tick = now
        self._emit(self.core.tick(stalled) if self.core.started else self.core.start())

    def _emit(self, em: DriverOutput) -> None:
        if not self.context.ok():   # stopping after SIGINT: the device still ramps, nothing can be published
            self._log_to_stderr(em)
            return
        try:
            for stamp, u in em.applied:
                if self.pub_u is not None:
                    self.pub_u.publish(pack_block(u, self.axes, stamp))
            for stamp, y in em.displacement:
                if self.pub_y is not None:
                    self.pub_y.publish(pack_block(y, self.axes, stamp))
                    self._joint_states(y, stamp)
        except Exception:
            # SIGINT/SIGTERM may shut the context down between the check above and a publish (the signal handler
            # runs on another thread): the device has already been given the samples, only the report is lost
            if self.context.ok():
                raise
            self._log_to_stderr(em)
            return
        log_lines(self.get_logger(), em.log)
        self._hint(em)

    @staticmethod
    def _log_to_stderr(em: DriverOutput) -> None:
        for _, text in em.log:
            print(f"driver: {text}", file=sys.stderr)

    def _hint(self, em: DriverOutput) -> None:
        """Name the setting that fixes a late/underrun/stale stream, once per kind."""
        if self.core is None or not em.log:
            return
        c = self.core
        seen = {"late": c.book.counters.late_blocks > 0, "underrun": c.faults.get("underrun", 0) > 0,
                "stale": any("no voltage block for" in text for _, text in em.log)}
        for kind, now in seen.items():
            if now and kind not in self._hinted:
                self._hinted.add(kind)
                wa = c.s.write_ahead
                self.get_logger().warning("hint: " + _HINTS[kind].format(
                    write_ahead=wa, suggest=max(2 * wa, DEFAULT_WRITE_AHEAD_S), stale=c.s.limits.stale_timeout))

    def _joint_states(self, y: np.ndarray, stamp: int) -> None:
        if self.core is None or self.pub_js is None:   # not configured (any more): nothing to publish
            return
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
        if self.core is None:
            response.success, response.message = False, f"the driver is {self.lifecycle_state}: configure it first"
        elif self.core.reset():
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
        if self.core is None:
            return
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
        if self.core is None or self.pub_diag is None:
            return
        self.check_conflict()
        st = {**self.core.status(), "lifecycle": self.lifecycle_state, "ignored_blocks": self.ignored_blocks,
              "malformed_blocks": self.malformed_blocks, "backend": self.backend_name,
              "has_sensor": self.has_sensor,
              **writer_matches({"voltage_applied": self.pub_u, "displacement": self.pub_y})}
        level, message = self.core.health()
        if self.lifecycle_state != "active":
            message = f"{self.lifecycle_state} (output held at the safe voltage); {message}"
        if self.conflict:
            level, message = ERROR, self.conflict
        st["conflict"] = self.conflict
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [DiagnosticStatus(level=_LEVEL[level], name=f"{self.get_fully_qualified_name()}",
                                       message=message, hardware_id=self.backend_name, values=diag_values(st))]
        self.pub_diag.publish(arr)


def main(argv: list[str] | None = None) -> int:
    # SIGINT/SIGTERM, from any state: the output ramps to the safe voltage before the backend closes
    return run_node("driver", DriverNode, lambda n: n.finish(), argv)


if __name__ == "__main__":
    sys.exit(main())
