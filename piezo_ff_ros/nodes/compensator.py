"""Compensator node: ``reference`` blocks [m] → the cascade (H∞ C(s) → creep⁻¹ → hysteresis⁻¹) → ``voltage`` [V].
Wiring only: the logic (stream bookkeeping, workspace clamp, parameter transactions, status) is
:class:`piezo_ff_ros.core.compensator_core.CompensatorCore`.

Every stage parameter is a ROS parameter (names and encoding: :mod:`piezo_ff_ros.core.param_map`, e.g.
``hysteresis.Dp`` flat row-major [m/V], ``creep.Cr.xx.k``, ``vibration.t_r``, ``cascade.creep``), loadable with
``--ros-args --params-file config/compensator.params.yaml`` and changeable at runtime (``ros2 param set``).  A change
is validated in the on-set callback by building the whole new configuration (rejected with the
:class:`~piezo_ff_ros.core.config.ConfigError` text, which starts with the field's name; the old value stays) and
applied after, at a block boundary, bumplessly (:class:`~piezo_ff_ros.core.hot_swap.HotSwapCascade`).  A change that
needs an H∞ synthesis is built in a worker thread while the old cascade keeps running; if that build fails (e.g.
γ > gamma_max) the error is logged and published on ``/diagnostics`` and the parameters are reverted to the running
configuration (logged at ERROR, on ``/diagnostics``; the revert itself creates no configuration version).  Setting
parameters to the values that run (e.g. ``ros2 param load`` of a dump) creates no new version.  Parameters only
valid together (``….den`` with ``….den_deg``) are set atomically: ``config_yaml`` (string: a YAML mapping of stage
parameters, applied as one change; the stage parameters then read back the new values) or the node's standard
``set_parameters_atomically`` service.  Every parameter keeps the type it is declared with
(:class:`~piezo_ff_ros.nodes.params.TypedParameters`: a value of another type is refused in one line naming the
parameter, the old value kept; an integer for a double is taken), with a description and, for numbers, a range.

Other parameters: ``config_file`` and ``variant`` (read-only: the base configuration), ``crossfade`` [s] (output
crossfade at a swap), ``block_size`` (samples per block generated from a held ``reference_point``; default
:data:`~piezo_ff_ros.core.hold_pacer.HOLD_BLOCK_SIZE`, 1000: fewer, larger blocks keep a loaded host up with the stream),
``hold_timeout`` [s] (the held point is played only while no ``reference`` block arrived for this long; played
from one executor timer, paced by :class:`~piezo_ff_ros.core.hold_pacer.HoldPacer`; its blocks also go out on
``reference``, stamped like their voltage blocks, so that a recording and the plots hold what the stage was asked to
do whatever its source),
``bypass`` (bool: the reference blocks are voltages [V] forwarded unchanged, for open-loop characterisation such as
the paper's S0 experiments; the cascade is not run).
``resync`` (bool, default true): follow ``voltage_applied`` (the driver's applied voltage, same block layout
and stamps as ``voltage``) and rebuild the hysteresis and creep states when what was applied differs from what
was sent (clamps, safe ramps, stalls).  ``workspace`` (double[], ``[min_x, max_x, min_y, max_y]`` [m]; default
the config's ``limits.workspace``, empty = none): references outside are clamped, with a WARN and a count.
``reference_limit`` (double[], same layout [m]; default the stage's reachable range at ``±limits.voltage`` with a
margin of 2, :func:`~piezo_ff_ros.core.trajectories.workspace.reachable_range`; empty = only the hard bound of
1e12 × the static reach, :data:`~piezo_ff_ros.core.compensator_core.HARD_REFERENCE_FACTOR`): a reference block or
``reference_point`` with a sample outside is refused whole (one ERROR line a second at most, counted in
``rejected_blocks``, ``/diagnostics`` at ERROR while it lasts) — a unit mistake or a corrupt sample never reaches
the cascade.  ``driver`` (read-only, default ``driver``): the node name of the paired driver, resolved in this
node's namespace; ``voltage_applied`` is used only from that node's publisher (by publisher GID), finite, on the
sample grid and within ``±limits.voltage``; anything else is refused and counted (``applied_rejected``).
Tracking stages in front of the cascade (:mod:`piezo_ff_ros.core.tracking.front`, docs/tracking.md), after the
workspace clamp: ``preview.enabled`` (bool), ``preview.horizon_s``, ``preview.tail_s``, ``preview.bandwidth_hz``,
``preview.constrained``, ``learning.file`` (a stored learned correction); with the preview on, the reference must
arrive ``preview_s`` ahead (trajectory node ``preview_s``; the value needed is in /diagnostics).
Service ``~/reset`` (std_srvs/Trigger): all compensator states back to rest.
Topic ``~/config`` (std_msgs/String JSON, transient-local, every version kept): each configuration when it takes
effect, ``{"version", "stamp_ns" (first sample it produced), "config_yaml", "parameters"}`` — the recorder
stores them in the MCAP metadata.  ``/diagnostics`` also counts lost (gap), late and rejected input blocks.
"""
from __future__ import annotations

import json
import sys
import threading
import time
from collections import deque
from typing import Any, Sequence

import numpy as np

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PointStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from ..core.compensator_core import (SETTING_NAMES, CompensatorCore, CompensatorOutput, CompensatorSettings,
                                     ParameterBook, build_notice, parse_config_yaml, same_value)
from ..core.config import load_config
from ..core.param_map import config_to_params
from ..core.tracking.front import FRONT_DEFAULTS
from ..core.trajectories.workspace import reachable_range
from .common import (BLOCK_QOS, CONFIG_QOS, BlockFormatError, diag_values, log_lines, pack_block, run_node,
                     stamp_to_ns, unpack_block, writer_matches)
from .params import TypedParameters, refuse_unknown_parameters

#: parse_config_yaml lives in the core now; importable from here as before
__all__ = ["CompensatorNode", "main", "parse_config_yaml"]

_LEVEL = {0: DiagnosticStatus.OK, 1: DiagnosticStatus.WARN, 2: DiagnosticStatus.ERROR}

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


#: numeric ranges of scalar parameters (min, max); rclpy refuses values outside with the parameter's name
_RANGES = {"vibration.t_r": (1e-6, 100.0), "vibration.eps_s": (0.0, 1.0), "vibration.k_o": (0.0, 1e6),
           "vibration.gamma_max": (0.0, 1e3), "vibration.order": (1, 500), "crossfade": (0.0, 10.0),
           "hold_timeout": (0.0, 3600.0), "block_size": (1, 20000)}


def _declared_type(name: str, value: Any) -> Parameter.Type:
    """The fixed type of a parameter from its default value (arrays: ``…_deg`` and lists of integers are integer
    arrays, other arrays, empty ones included, double arrays)."""
    if not isinstance(value, list):
        return Parameter.Type.from_parameter_value(value)
    if name.endswith("_deg") or (value and all(isinstance(v, int) and not isinstance(v, bool) for v in value)):
        return Parameter.Type.INTEGER_ARRAY
    return Parameter.Type.DOUBLE_ARRAY


class CompensatorNode(Node):
    """See the module docstring."""

    #: the logic (built once every parameter is declared)
    core: CompensatorCore

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("compensator", **kwargs)
        self._internal = False        # the node sets its own parameters (revert, config_yaml read-back)
        self.book: ParameterBook | None = None   # None until the base configuration is loaded
        self._lock = threading.RLock()
        # on-set BEFORE the declarations, so that params-file and -p overrides are validated too
        self.add_on_set_parameters_callback(self._on_set)
        self.add_post_set_parameters_callback(self._post_set)
        self.params = TypedParameters(self)   # after _on_set: the type check runs first
        cfg_file = self._declare("config_file", "", "base configuration file (YAML); empty = the packaged "
                                 "pt230_94.yaml", read_only=True)
        variant = self._declare("variant", "", "named variant of the base configuration", read_only=True)
        base = load_config(cfg_file or None, variant or None)
        self.book = book = ParameterBook(base)
        ws = base.limits.workspace
        settings = CompensatorSettings(
            crossfade=float(self._declare("crossfade", 0.01, "output crossfade at a configuration swap [s]")),
            block_size=int(self._declare("block_size", CompensatorSettings.block_size,
                                         "samples per block played from a held reference_point")),
            hold_timeout=float(self._declare("hold_timeout", 0.2, "the held point plays once no reference block "
                                             "came for this long [s]")),
            bypass=bool(self._declare("bypass", False, "forward reference blocks as voltages [V] (open loop)")),
            resync=bool(self._declare("resync", True, "rebuild the hysteresis/creep states from voltage_applied "
                                      "when it differs from what was sent")),
            workspace=tuple(float(v) for v in self._declare(
                "workspace", [float(v) for pair in (ws or ()) for v in pair],
                "reference limits [m], [min, max] per axis, flat; empty = none")),
            reference_limit=tuple(float(v) for v in self._declare(
                "reference_limit", list(reachable_range(base)),
                "a reference outside [m] ([min, max] per axis, flat) is refused; default: the stage's reachable "
                "range at the voltage limit with a margin of 2; empty = none but a hard bound of 1e12 x the reach")))
        self.driver_name = str(self._declare("driver", "driver", "node name of the paired driver: voltage_applied "
                                             "is used only from it", read_only=True))
        self._declare("config_yaml", "", "a YAML mapping of stage parameters applied as one atomic change "
                      "(then cleared)")
        book.front_values = {n: self._declare(n, v, "tracking front (docs/tracking.md)")
                             for n, v in FRONT_DEFAULTS.items()}
        for name, value in config_to_params(base).items():
            book.values[name] = self._declare(name, value)
        cfg = book.end_declarations()  # cross-field check of everything that was loaded
        refuse_unknown_parameters(self)
        settings.validate(len(base.axes))
        self.get_logger().info(build_notice(cfg))
        self._driver_gids: set[bytes] = set()
        self._gids_checked = -1.0
        self.core = CompensatorCore(book, cfg, settings, applied_feedback=self._driver_publishes)

        self.pub_u = self.create_publisher(PointCloud2, "voltage", BLOCK_QOS)
        self.pub_ref = self.create_publisher(PointCloud2, "reference", BLOCK_QOS)   # a held point's blocks
        self._own_reference: deque[int] = deque(maxlen=1000)
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.pub_config = self.create_publisher(String, "~/config", CONFIG_QOS)
        self.create_subscription(PointCloud2, "reference", self.on_reference, BLOCK_QOS)
        self._applied_sub = self.create_subscription(PointCloud2, "voltage_applied", self.on_applied, BLOCK_QOS)
        self.create_subscription(PointStamped, "reference_point", self.on_point, 10)
        self.create_service(Trigger, "~/reset", self.on_reset)
        self.create_timer(0.05, self.poll)
        self.create_timer(1.0, self.publish_diagnostics)
        # the held reference_point: one executor timer, paced by the core HoldPacer (no thread of its own); it runs
        # only while a point is held, so a streaming or idle compensator has no extra wake-ups
        self._hold_timer = self.create_timer(self._hold_tick_period(), self._on_hold_tick)
        self._hold_timer.cancel()
        self.get_logger().info(f"compensator ready: config v{self.core.hs.version}, stages "
                               f"{ {k: getattr(cfg.cascade, k) for k in ('vibration', 'creep', 'hysteresis')} }")

    @property
    def blocks(self) -> int:
        """Blocks processed (the core's count)."""
        return self.core.blocks

    # -- parameters ------------------------------------------------------------------------------------------------
    @property
    def _declaring(self) -> bool:
        return self.book is None or self.book.declaring

    def _declare(self, name: str, value: Any, description: str = "", read_only: bool = False) -> Any:
        """Declare ``name`` with the type of its default (:class:`~.params.TypedParameters`), its description and,
        for the numbers of ``_RANGES``, its range; the value (override or default) as plain Python.  An override
        refused raises :class:`~.params.ParameterRefused` (one line naming the parameter)."""
        return self.params.declare(name, value, description or _describe(name), read_only=read_only,
                                   type_=_declared_type(name, value), value_range=_RANGES.get(name))

    def _typed(self, name: str, value: Any) -> Parameter:
        """``value`` as a Parameter of the declared type of ``name`` (the node's own read-back and revert)."""
        t = self.params.types[name]
        if t == Parameter.Type.DOUBLE:
            value = float(value)
        elif t == Parameter.Type.DOUBLE_ARRAY:
            value = [float(v) for v in value]
        elif t == Parameter.Type.INTEGER_ARRAY:
            value = [int(v) for v in value]
        return Parameter(name, t, value)

    def _set_own(self, params: list[Parameter]) -> None:
        """Set parameters from the node itself: no validation round, no configuration version."""
        if not params:
            return
        self._internal = True
        try:   # atomically: one parameter event, as one change
            r = self.set_parameters_atomically(params)
            if not r.successful:
                self.get_logger().error(f"internal parameter update refused: {r.reason}")
        finally:
            self._internal = False

    def _on_set(self, params: list[Parameter]) -> SetParametersResult:
        book = self.book
        if book is None or self._internal:   # config_file / variant themselves; the node's own updates
            return SetParametersResult(successful=True)
        pairs = _pairs(params)
        verdict = book.propose(pairs) if book.declaring else self.core.propose(pairs)
        log_lines(self.get_logger(), verdict.log)
        return SetParametersResult(successful=verdict.successful, reason=verdict.reason)

    def _post_set(self, params: list[Parameter]) -> None:
        if self._declaring:
            return
        if self._internal:
            self.core.book.record_own(_pairs(params))
            return
        with self._lock:
            em = self.core.commit(_pairs(params))
        self._emit(em)

    def poll(self) -> None:
        """Timer: swap in a finished build even when no block flows; report swaps and failed builds
        (:meth:`CompensatorCore.poll`)."""
        with self._lock:
            em = self.core.poll()
        self._emit(em)

    # -- what the core returned ------------------------------------------------------------------------------------
    def _emit(self, em: CompensatorOutput) -> None:
        """Publish, log and set what a core call returned (data path: called under the lock, so stamps leave in
        order)."""
        for vb in em.voltage:
            if vb.config is not None:
                self.pub_config.publish(String(data=json.dumps({**vb.config, "parameters": self._node_parameters()})))
            self.pub_u.publish(pack_block(vb.u, self.core.axes, vb.stamp))
        log_lines(self.get_logger(), em.log)
        if em.hold_timer == "start":
            if self._hold_timer.is_canceled():
                self._hold_timer.reset()
        elif em.hold_timer == "retime":
            self.destroy_timer(self._hold_timer)
            self._hold_timer = self.create_timer(self._hold_tick_period(), self._on_hold_tick)
            if self.core.pacer.point is None:
                self._hold_timer.cancel()
        if em.readback:   # only those the parameters do not hold yet
            self._set_own([self._typed(k, v) for k, v in em.readback.items()
                           if not same_value(self.get_parameter(k).value, v)])
        if em.revert:
            self._set_own([self._typed(k, v) for k, v in em.revert.items()])
        if em.diagnostics:
            self.publish_diagnostics()

    def _node_parameters(self) -> dict[str, Any]:
        """The node parameters recorded with each configuration version on ``~/config``."""
        return {n: (list(v) if hasattr(v, "typecode") else v) for n, v in
                ((n, self.get_parameter(n).value) for n in (*SETTING_NAMES, "config_file", "variant",
                                                            *FRONT_DEFAULTS))}

    # -- data path -------------------------------------------------------------------------------------------------
    def on_reference(self, msg: PointCloud2) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        if stamp in self._own_reference:   # a held point's block this node published itself
            return
        with self._lock:
            try:
                block = unpack_block(msg, self.core.axes)
            except BlockFormatError as exc:
                self._emit(self.core.reject("reference", str(exc)))
                return
            self._emit(self.core.on_reference(stamp, block, time.monotonic()))

    def _process_and_publish(self, block: np.ndarray, stamp: int | None) -> None:
        """One block through the core and out (``stamp`` None: continue the stream, as the held point does); one
        lock around the core and the publish.  A held point's blocks also go out on ``reference`` (what the stage
        is asked to do is recorded and plotted whatever its source); :meth:`on_reference` ignores them."""
        with self._lock:
            em = self.core.process(block, stamp, time.monotonic())
            if stamp is None:
                for vb in em.voltage:
                    self._own_reference.append(vb.stamp)
                    self.pub_ref.publish(pack_block(np.repeat(block[:1], vb.u.shape[0], axis=0), self.core.axes,
                                                    vb.stamp))
            self._emit(em)

    def _refresh_driver_gids(self, now: float) -> None:
        """The publisher GIDs of the paired driver on ``voltage_applied`` (looked up in the graph, at most every
        0.5 s)."""
        if now - self._gids_checked < 0.5:
            return
        self._gids_checked = now
        ns = self.get_namespace()
        self._driver_gids = {bytes(bytearray(i.endpoint_gid)) for i in
                             self.get_publishers_info_by_topic(self._applied_sub.topic_name)
                             if i.node_name == self.driver_name and i.node_namespace == ns}

    def _driver_publishes(self) -> bool:
        """Whether the paired driver publishes ``voltage_applied`` (the blocks are kept in flight only then)."""
        self._refresh_driver_gids(time.monotonic())
        return bool(self._driver_gids)

    def _sender(self, info: Any) -> str:
        """Empty when ``info`` (the message info) names a publisher of the paired driver, else who sent it."""
        gid = (info or {}).get("publisher_gid") if isinstance(info, dict) else None
        data = bytes(bytearray(gid.get("data", b""))) if isinstance(gid, dict) else b""
        if data and data in self._driver_gids:
            return ""
        self._gids_checked = -1.0   # a new driver may just have appeared: look again now
        self._refresh_driver_gids(time.monotonic())
        if data and data in self._driver_gids:
            return ""
        others = sorted(f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in
                        self.get_publishers_info_by_topic(self._applied_sub.topic_name)
                        if bytes(bytearray(i.endpoint_gid)) == data)
        return (f"sender {others[0] if others else 'unknown'} is not the paired driver "
                f"{self.get_namespace().rstrip('/')}/{self.driver_name} (parameter driver)")

    def on_applied(self, msg: PointCloud2, info: Any) -> None:
        if not self.core.wants_applied:
            return
        foreign = self._sender(info)
        try:
            u = unpack_block(msg, self.core.axes) if not foreign else np.zeros((0, len(self.core.axes)))
        except BlockFormatError as exc:
            with self._lock:
                log_lines(self.get_logger(), self.core.reject("voltage_applied", str(exc)).log)
            return
        with self._lock:
            em = self.core.on_applied(stamp_to_ns(msg.header.stamp), u, time.monotonic(), foreign=foreign)
        log_lines(self.get_logger(), em.log)

    def on_point(self, msg: PointStamped) -> None:
        self._emit(self.core.set_point([msg.point.x, msg.point.y, msg.point.z][:len(self.core.axes)]))

    def _hold_tick_period(self) -> float:
        """The hold timer's period [s]: half a block (the pacer absorbs the timer's jitter), within 1…50 ms."""
        return min(max(0.5 * self.core.pacer.block_period, 0.001), 0.05)

    def _on_hold_tick(self) -> None:
        """Timer: play the held point's blocks that are due (:class:`~piezo_ff_ros.core.hold_pacer.HoldPacer`)."""
        for _ in range(self.core.pacer.tick(time.monotonic())):
            self._process_and_publish(self.core.pacer.block(), None)

    def on_reset(self, request: Any, response: Any) -> Any:
        """``~/reset``: the cascade's state back to rest (and the hold point cleared)."""
        with self._lock:
            message = self.core.reset()
            self._hold_timer.cancel()
        response.success, response.message = True, message
        return response

    # -- diagnostics -----------------------------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        """The ``/diagnostics`` key/values (:meth:`CompensatorCore.status`)."""
        with self._lock:
            return self.core.status()

    def publish_diagnostics(self) -> None:
        with self._lock:
            level, msg, st = self.core.diagnostics()
        st = {**st, **writer_matches({"voltage": self.pub_u})}
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [DiagnosticStatus(level=_LEVEL[level], name=self.get_fully_qualified_name(),
                                       message=msg, hardware_id="compensator",
                                       values=diag_values(st))]
        self.pub_diag.publish(arr)

    def stop(self) -> None:
        self._hold_timer.cancel()


def _pairs(params: list[Parameter]) -> list[tuple[str, Any]]:
    """``(name, value)`` of rclpy parameters, arrays as lists."""
    return [(p.name, list(p.value) if hasattr(p.value, "typecode") or isinstance(p.value, tuple) else p.value)
            for p in params]


def main(argv: Sequence[str] | None = None) -> int:
    """``ros2 run piezo_ff_ros compensator``."""
    return run_node("compensator", CompensatorNode, lambda n: n.stop(), argv)


if __name__ == "__main__":
    sys.exit(main())
