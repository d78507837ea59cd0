"""Compensator node: ``reference`` blocks [m] → the cascade (H∞ C(s) → creep⁻¹ → hysteresis⁻¹) → ``voltage`` [V].

Every stage parameter is a ROS parameter (names and encoding: :mod:`piezo_ff_ros.core.param_map`, e.g.
``hysteresis.Dp`` flat row-major [m/V], ``creep.Cr.xx.k``, ``vibration.t_r``, ``cascade.creep``), loadable with
``--ros-args --params-file config/compensator.params.yaml`` and changeable at runtime (``ros2 param set``).  A change
is validated in the on-set callback by building the whole new configuration (rejected with the
:class:`~piezo_ff_ros.core.config.ConfigError` text, which starts with the field's name; the old value stays) and
applied after, at a block boundary, bumplessly (:class:`~piezo_ff_ros.core.hot_swap.HotSwapCascade`).  A change that
needs an H∞ synthesis is built in a worker thread while the old cascade keeps running; if that build fails (e.g.
γ > gamma_max) the error is logged and published on ``/diagnostics`` and the parameters are reverted to the running
configuration.  Several parameters that are only valid together (e.g. ``….den`` and ``….den_deg``) are set with
``set_parameters_atomically``.

Other parameters: ``config_file`` and ``variant`` (read-only: the base configuration), ``crossfade`` [s] (output
crossfade at a swap), ``block_size`` (samples per block generated from a held ``reference_point``),
``hold_timeout`` [s] (the held point is played only while no ``reference`` block arrived for this long),
``bypass`` (bool: the reference blocks are voltages [V] forwarded unchanged, for open-loop characterisation such as
the paper's S0 experiments; the cascade is not run).
Service ``~/reset`` (std_srvs/Trigger): all compensator states back to rest.
"""
from __future__ import annotations

import json
import sys
import threading
import time

import numpy as np

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PointStamped
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import Trigger

from ..core.config import ConfigError, load_config
from ..core.hot_swap import HotSwapCascade
from ..core.param_map import config_to_params, is_config_param, needs_synthesis, params_to_config
from .common import BLOCK_QOS, BlockFormatError, diag_values, dt_ns, pack_block, run_node, stamp_to_ns, unpack_block

_DESCRIPTIONS = {
    "hysteresis.": "Bouc-Wen matrix, flat row-major, one row per axis (Dp, A in m/V; B, Gamma, Delta1/2 in 1/V)",
    "creep.K": "creep static matrix K, flat row-major",
    "creep.Cr.": "creep transfer function entry <out><in>: k gain, num/den concatenated factor coefficients, "
                 "num_deg/den_deg degree of each factor",
    "dynamics.G_L.": "dynamics G_L(s) entry <out><in> (used by the H∞ synthesis), same encoding as creep.Cr",
    "vibration.controller.": "ready continuous controller C(s) (flat A, B, C, D); empty = synthesise H∞",
    "vibration.": "H∞ weights (t_r [s], eps_s, k_o, W2 per axis), reduced order, gamma_max",
    "cascade.": "which stages run (bool), order paper|commuted, hysteresis_loop exact|delayed",
}


def _describe(name: str) -> str:
    for prefix, text in _DESCRIPTIONS.items():
        if name.startswith(prefix):
            return text
    return ""


class CompensatorNode(Node):
    """See the module docstring."""

    def __init__(self, **kwargs):
        super().__init__("compensator", **kwargs)
        self._values: dict = {}
        self._candidate = None
        self._declaring = True
        self.base = None
        # on-set BEFORE the declarations, so that params-file and -p overrides are validated too
        self.add_on_set_parameters_callback(self._on_set)
        self.add_post_set_parameters_callback(self._post_set)
        ro = ParameterDescriptor(read_only=True)
        cfg_file = self.declare_parameter("config_file", "", ro).value
        variant = self.declare_parameter("variant", "", ro).value
        self.base = load_config(cfg_file or None, variant or None)
        self.crossfade = float(self.declare_parameter("crossfade", 0.01).value)
        self.block_size = int(self.declare_parameter("block_size", 200).value)
        self.hold_timeout = float(self.declare_parameter("hold_timeout", 0.2).value)
        self.bypass = bool(self.declare_parameter("bypass", False).value)
        for name, value in config_to_params(self.base).items():
            desc = ParameterDescriptor(dynamic_typing=True, description=_describe(name))
            self._values[name] = self.declare_parameter(name, value, desc).value
        self._declaring = False
        cfg = params_to_config(self._values, self.base)  # cross-field check of everything that was loaded
        self.cfg = cfg
        self.axes = cfg.axes
        self.period_ns = dt_ns(cfg.sample_rate)
        self.get_logger().info("building the compensator cascade" +
                               (" (H∞ synthesis)" if cfg.cascade.vibration and cfg.vibration.controller is None
                                else ""))
        self.hs = HotSwapCascade(cfg, crossfade_samples=int(round(self.crossfade * cfg.sample_rate)))
        self._lock = threading.Lock()
        self.blocks = 0
        self.rejected_blocks = 0
        self.last_error = ""
        self._reported_version = self.hs.version
        self._next_stamp = None
        self._last_block_wall = 0.0
        self._hold_point = None

        self.pub_u = self.create_publisher(PointCloud2, "voltage", BLOCK_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(PointCloud2, "reference", self.on_reference, BLOCK_QOS)
        self.create_subscription(PointStamped, "reference_point", self.on_point, 10)
        self.create_service(Trigger, "~/reset", self.on_reset)
        self.create_timer(0.05, self.poll)
        self.create_timer(1.0, self.publish_diagnostics)
        self._stop = threading.Event()
        self._hold_thread = threading.Thread(target=self._hold_loop, daemon=True)
        self._hold_thread.start()
        self.get_logger().info(f"compensator ready: config v{self.hs.version}, stages "
                               f"{ {k: getattr(cfg.cascade, k) for k in ('vibration', 'creep', 'hysteresis')} }")

    # -- parameters ------------------------------------------------------------------------------------------------
    def _on_set(self, params: list[Parameter]) -> SetParametersResult:
        if self.base is None:   # config_file / variant themselves
            return SetParametersResult(successful=True)
        updates = {}
        for p in params:
            if p.name in ("crossfade", "hold_timeout"):
                if not isinstance(p.value, (int, float)) or isinstance(p.value, bool) or not p.value >= 0:
                    return SetParametersResult(successful=False, reason=f"{p.name}: must be a number ≥ 0")
            elif p.name == "bypass":
                if not isinstance(p.value, bool):
                    return SetParametersResult(successful=False, reason="bypass: must be true or false")
            elif p.name == "block_size":
                if not isinstance(p.value, int) or p.value < 1:
                    return SetParametersResult(successful=False, reason="block_size: must be an integer ≥ 1")
            elif is_config_param(p.name):
                updates[p.name] = p.value
        if not updates:
            return SetParametersResult(successful=True)
        merged = {**self._values, **updates}
        try:
            if self._declaring:
                # partial set while declaring: check against the base for the names declared so far
                params_to_config(merged, self.base)
                return SetParametersResult(successful=True)
            cand = params_to_config(merged, self.base)
        except ConfigError as exc:
            old = {k: self._values.get(k) for k in updates}
            self.get_logger().error(f"parameter change rejected: {exc}")
            return SetParametersResult(successful=False, reason=f"{exc} (kept: {_short(old)})")
        self._candidate = (updates, cand)
        return SetParametersResult(successful=True)

    def _post_set(self, params: list[Parameter]) -> None:
        if self._declaring:
            return
        for p in params:
            if p.name == "crossfade":
                self.crossfade = float(p.value)
                self.hs.crossfade_samples = int(round(self.crossfade * self.cfg.sample_rate))
            elif p.name == "block_size":
                self.block_size = int(p.value)
            elif p.name == "hold_timeout":
                self.hold_timeout = float(p.value)
            elif p.name == "bypass":
                self.bypass = bool(p.value)
        if self._candidate is None:
            return
        updates, cand = self._candidate
        self._candidate = None
        self._values.update(updates)
        bg = any(needs_synthesis(n) for n in updates) or self.hs.needs_background(cand)
        with self._lock:
            v = self.hs.request(cand, background=bg)
        self.get_logger().info(f"configuration v{v} requested ({', '.join(sorted(updates))})" +
                               ("; building in the background" if bg else ""))
        self.publish_diagnostics()

    def poll(self) -> None:
        """Timer: swap in a finished build even when no block flows; report swaps and failed builds."""
        with self._lock:
            failed = self.hs.failed_builds
            self.hs.poll()
            failed_now = self.hs.failed_builds != failed
        if failed_now:
            self.last_error = self.hs.last_error
            self.get_logger().error(self.last_error + "; parameters reverted to the running configuration")
            self._revert_to(self.hs.cfg)
            self.publish_diagnostics()
        if self.hs.version != self._reported_version:
            self._reported_version = self.hs.version
            self.cfg = self.hs.cfg
            self.get_logger().info(f"configuration v{self.hs.version} active")
            self.publish_diagnostics()

    def _revert_to(self, cfg) -> None:
        running = config_to_params(cfg)
        changed = [Parameter(k, value=v) for k, v in running.items() if self._values.get(k) != v]
        if changed:
            self.set_parameters(changed)
            self._values.update({p.name: p.value for p in changed})
            self._candidate = None

    # -- data path -------------------------------------------------------------------------------------------------
    def on_reference(self, msg: PointCloud2) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        try:
            block = unpack_block(msg, self.axes)
            if not np.all(np.isfinite(block)):
                raise BlockFormatError("NaN/Inf in the reference")
        except BlockFormatError as exc:
            self.rejected_blocks += 1
            self.last_error = f"reference block rejected: {exc}"
            self.get_logger().error(self.last_error)
            return
        self._last_block_wall = time.monotonic()
        self._process_and_publish(block, stamp)

    def _process_and_publish(self, block, stamp) -> None:
        with self._lock:
            u = block if self.bypass else self.hs.process(block)
        self.blocks += 1
        self._next_stamp = stamp + block.shape[0] * self.period_ns
        self.pub_u.publish(pack_block(u, self.axes, stamp))

    def on_point(self, msg: PointStamped) -> None:
        p = [msg.point.x, msg.point.y, msg.point.z][:len(self.axes)]
        if not np.all(np.isfinite(p)):
            self.get_logger().error("reference_point rejected: NaN/Inf")
            return
        self._hold_point = np.array(p, float)

    def _hold_loop(self) -> None:
        """Play a held ``reference_point`` as blocks, paced by the wall clock (sleep-until)."""
        period = None
        nxt = time.monotonic()
        while not self._stop.is_set():
            n = self.block_size
            period = n / self.cfg.sample_rate
            nxt += period
            delay = nxt - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                nxt = time.monotonic()
            point = self._hold_point
            if point is None or time.monotonic() - self._last_block_wall < max(self.hold_timeout, 2 * period):
                continue
            stamp = self._next_stamp if self._next_stamp is not None else time.time_ns() // self.period_ns * \
                self.period_ns
            try:
                self._process_and_publish(np.tile(point, (n, 1)), stamp)
            except Exception as exc:  # noqa: BLE001 - context shut down while stopping
                if not self._stop.is_set():
                    self.get_logger().error(f"held point: {exc}")

    def on_reset(self, request, response):
        with self._lock:
            self.hs.reset()
        self._hold_point = None
        self._next_stamp = None
        response.success, response.message = True, f"compensator states reset (config v{self.hs.version})"
        return response

    # -- diagnostics -----------------------------------------------------------------------------------------------
    def status(self) -> dict:
        st = {**self.hs.status(), "bypass": self.bypass, "blocks": self.blocks, "rejected_blocks": self.rejected_blocks,
              "stages": ",".join(k for k in ("vibration", "creep", "hysteresis") if getattr(self.hs.cfg.cascade, k)),
              "order": self.hs.cfg.cascade.order}
        if self.last_error:
            st["last_error"] = self.last_error
        h = self.hs.active.hysteresis
        if h is not None:
            st["hysteresis_fallbacks"] = h.fallbacks
        design = getattr(self.hs.active, "design", None)
        if design is not None and hasattr(design, "as_dict"):
            d = design.as_dict()  # γ and orders of the H∞ design in use (recorded with /diagnostics)
            st["hinf"] = json.dumps({k: d.get(k) for k in ("gamma", "order_full", "order_reduced",
                                                             "gamma_reduced_achieved", "synthesis_s")})
        return st

    def publish_diagnostics(self) -> None:
        st = self.status()
        level = DiagnosticStatus.WARN if (st["failed_builds"] or st["rejected_blocks"]) else DiagnosticStatus.OK
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [DiagnosticStatus(level=level, name=self.get_fully_qualified_name(),
                                       message=f"config v{st['config_version']}", hardware_id="compensator",
                                       values=diag_values(st))]
        self.pub_diag.publish(arr)

    def stop(self) -> None:
        self._stop.set()
        self._hold_thread.join(timeout=1.0)


def _short(d: dict) -> str:
    parts = []
    for k, v in d.items():
        s = repr(v)
        parts.append(f"{k}={s if len(s) < 80 else s[:77] + '...'}")
    return ", ".join(parts)


def main(argv=None) -> int:
    return run_node("compensator", CompensatorNode, lambda n: n.stop(), argv)


if __name__ == "__main__":
    sys.exit(main())
