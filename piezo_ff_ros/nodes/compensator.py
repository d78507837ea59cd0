"""Compensator node: ``reference`` blocks [m] → the cascade (H∞ C(s) → creep⁻¹ → hysteresis⁻¹) → ``voltage`` [V].

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
``set_parameters_atomically`` service.  Every parameter is statically typed, with a description and, for
numbers, a range.

Other parameters: ``config_file`` and ``variant`` (read-only: the base configuration), ``crossfade`` [s] (output
crossfade at a swap), ``block_size`` (samples per block generated from a held ``reference_point``),
``hold_timeout`` [s] (the held point is played only while no ``reference`` block arrived for this long; played
from one executor timer, paced by :class:`~piezo_ff_ros.core.hold_pacer.HoldPacer`),
``bypass`` (bool: the reference blocks are voltages [V] forwarded unchanged, for open-loop characterisation such as
the paper's S0 experiments; the cascade is not run).
``resync`` (bool, default true): follow ``voltage_applied`` (the driver's applied voltage, same block layout
and stamps as ``voltage``) and rebuild the hysteresis and creep states when what was applied differs from what
was sent (clamps, safe ramps, stalls).  ``workspace`` (double[], ``[min_x, max_x, min_y, max_y]`` [m]; default
the config's ``limits.workspace``, empty = none): references outside are clamped, with a WARN and a count.
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
from typing import Any, Sequence

import numpy as np
import yaml

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PointStamped
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType,
                                SetParametersResult)
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from ..core.config import ConfigError, PiezoConfig, load_config
from ..core.hold_pacer import HoldPacer
from ..core.hot_swap import HotSwapCascade
from ..core.param_map import config_to_params, is_config_param, needs_synthesis, params_to_config
from ..core.tracking.front import FRONT_DEFAULTS, TrackingFront, front_settings, is_front_param
from ..core.tracking.linear import controller_matrices
from .common import (BLOCK_QOS, CONFIG_QOS, BlockFormatError, diag_values, dt_ns, pack_block, run_node, stamp_to_ns,
                     unpack_block, writer_matches)

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


def _ptype(name: str, value: Any) -> int:
    """The static ROS type of a parameter from its default value (empty arrays: from the name)."""
    if isinstance(value, bool):
        return ParameterType.PARAMETER_BOOL
    if isinstance(value, int):
        return ParameterType.PARAMETER_INTEGER
    if isinstance(value, float):
        return ParameterType.PARAMETER_DOUBLE
    if isinstance(value, str):
        return ParameterType.PARAMETER_STRING
    if name.endswith("_deg") or (value and all(isinstance(v, int) and not isinstance(v, bool) for v in value)):
        return ParameterType.PARAMETER_INTEGER_ARRAY
    return ParameterType.PARAMETER_DOUBLE_ARRAY


_PY_TYPE = {ParameterType.PARAMETER_BOOL: Parameter.Type.BOOL, ParameterType.PARAMETER_INTEGER: Parameter.Type.INTEGER,
            ParameterType.PARAMETER_DOUBLE: Parameter.Type.DOUBLE,
            ParameterType.PARAMETER_STRING: Parameter.Type.STRING,
            ParameterType.PARAMETER_INTEGER_ARRAY: Parameter.Type.INTEGER_ARRAY,
            ParameterType.PARAMETER_DOUBLE_ARRAY: Parameter.Type.DOUBLE_ARRAY}


_TYPE_NAMES = {ParameterType.PARAMETER_BOOL: "a bool", ParameterType.PARAMETER_INTEGER: "an integer",
               ParameterType.PARAMETER_DOUBLE: "a double", ParameterType.PARAMETER_STRING: "a string",
               ParameterType.PARAMETER_INTEGER_ARRAY: "an integer array",
               ParameterType.PARAMETER_DOUBLE_ARRAY: "a double array", ParameterType.PARAMETER_BYTE_ARRAY: "a byte array",
               ParameterType.PARAMETER_BOOL_ARRAY: "a bool array",
               ParameterType.PARAMETER_STRING_ARRAY: "a string array"}


_ARRAY_TYPES = (Parameter.Type.BYTE_ARRAY, Parameter.Type.BOOL_ARRAY, Parameter.Type.INTEGER_ARRAY,
                Parameter.Type.DOUBLE_ARRAY, Parameter.Type.STRING_ARRAY)


def _coerce(parameter: Parameter, declared: int) -> None:
    """Make ``parameter`` the declared type where that loses nothing: integer → double (``ros2 param set … 1``
    stays a double), integer array → double array, an empty array of any type (rclpy types ``[]`` as bytes) →
    the declared array type.  Anything else is left for rclpy to refuse."""
    t, v = parameter.type_, parameter.value
    new: tuple[Any, Any] | None = None
    if declared == ParameterType.PARAMETER_DOUBLE and t == Parameter.Type.INTEGER and abs(v) < 2 ** 53:
        new = (Parameter.Type.DOUBLE, float(v))
    elif declared == ParameterType.PARAMETER_DOUBLE_ARRAY and t == Parameter.Type.INTEGER_ARRAY:
        new = (Parameter.Type.DOUBLE_ARRAY, [float(x) for x in v])
    elif declared in (ParameterType.PARAMETER_DOUBLE_ARRAY, ParameterType.PARAMETER_INTEGER_ARRAY) \
            and t in _ARRAY_TYPES and len(v) == 0 and t != _PY_TYPE[declared]:
        new = (_PY_TYPE[declared], [])
    if new is not None:   # rclpy's Parameter has no public setter; the same object goes on to the callbacks
        parameter._type_, parameter._value = new


def _descriptor(name: str, value: Any, description: str = "", read_only: bool = False) -> ParameterDescriptor:
    t = _ptype(name, value)
    d = ParameterDescriptor(name=name, type=t, description=description or _describe(name), read_only=read_only)
    if name in _RANGES:
        lo, hi = _RANGES[name]
        if t == ParameterType.PARAMETER_INTEGER:
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=0)]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]
    return d


def _same(a: Any, b: Any) -> bool:
    """Parameter values equal (``array('d')`` and list compare by content)."""
    if isinstance(a, (list, tuple)) or hasattr(a, "typecode") or isinstance(b, (list, tuple)) or hasattr(b, "typecode"):
        try:
            return list(a) == list(b)
        except TypeError:
            return False
    return a == b and type(a) is type(b)


def parse_config_yaml(text: str) -> dict:
    """Stage parameters from a YAML mapping: flat dotted names, nested sections, or a params file
    (``<node>: ros__parameters: …``); one-line :class:`ConfigError` otherwise."""
    try:
        d = yaml.safe_load(text) if text.strip() else {}
    except yaml.YAMLError as exc:
        raise ConfigError("config_yaml", f"not YAML ({str(exc).splitlines()[0]})") from None
    if d is None:
        return {}
    if not isinstance(d, dict):
        raise ConfigError("config_yaml", "expected a mapping of stage parameters")
    if len(d) == 1:   # a params file: {node or /**: {ros__parameters: {...}}}
        (only,) = d.values()
        if isinstance(only, dict) and "ros__parameters" in only:
            d = only["ros__parameters"]

    def flatten(prefix: str, m: dict[str, Any], out: dict[str, Any]) -> dict[str, Any]:
        for k, v in m.items():
            key = f"{prefix}{k}"
            if isinstance(v, dict):
                flatten(key + ".", v, out)
            else:
                out[key] = v
        return out

    flat = flatten("", d, {})
    bad = [k for k in flat if not is_config_param(k)]
    if bad:
        raise ConfigError("config_yaml", f"not a stage parameter: {bad[0]}")
    return flat


class CompensatorNode(Node):
    """See the module docstring."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("compensator", **kwargs)
        self._values: dict = {}
        self._types: dict = {}
        self._candidate: tuple[dict[str, Any], Any, bool] | None = None
        self._declaring = True
        self._internal = False        # the node sets its own parameters (revert, config_yaml mirror)
        self.base = None
        self._lock = threading.RLock()
        # on-set BEFORE the declarations, so that params-file and -p overrides are validated too
        self.add_on_set_parameters_callback(self._on_set)
        self.add_post_set_parameters_callback(self._post_set)
        cfg_file = self._declare("config_file", "", "base configuration file (YAML); empty = the packaged "
                                 "pt230_94.yaml", read_only=True)
        variant = self._declare("variant", "", "named variant of the base configuration", read_only=True)
        self.base = load_config(cfg_file or None, variant or None)
        self.crossfade = self._declare("crossfade", 0.01, "output crossfade at a configuration swap [s]")
        self.block_size = self._declare("block_size", 200, "samples per block played from a held reference_point")
        self.hold_timeout = self._declare("hold_timeout", 0.2, "the held point plays once no reference block came "
                                          "for this long [s]")
        self.bypass = self._declare("bypass", False, "forward reference blocks as voltages [V] (open loop)")
        self.resync = self._declare("resync", True, "rebuild the hysteresis/creep states from voltage_applied "
                                    "when it differs from what was sent")
        ws = self.base.limits.workspace
        self.workspace = self._declare("workspace", [float(v) for pair in (ws or ()) for v in pair],
                                       "reference limits [m], [min, max] per axis, flat; empty = none")
        self._declare("config_yaml", "", "a YAML mapping of stage parameters applied as one atomic change "
                      "(then cleared)")
        self._front_values = {n: self._declare(n, v, "tracking front (docs/tracking.md)")
                              for n, v in FRONT_DEFAULTS.items()}
        for name, value in config_to_params(self.base).items():
            self._values[name] = self._declare(name, value)
        self._declaring = False
        cfg = params_to_config(self._values, self.base)  # cross-field check of everything that was loaded
        self.cfg = cfg
        self.axes = cfg.axes
        self._check_workspace(self.workspace)
        self.period_ns = dt_ns(cfg.sample_rate)
        self.get_logger().info("building the compensator cascade" +
                               (" (H∞ synthesis)" if cfg.cascade.vibration and cfg.vibration.controller is None
                                else ""))
        self.hs = HotSwapCascade(cfg, crossfade_samples=int(round(self.crossfade * cfg.sample_rate)))
        self.front = TrackingFront(cfg, controller_matrices(self.hs.active), self._front_values)
        self._front_candidate: tuple[dict[str, Any], Any] | None = None
        self.blocks = 0
        self.rejected_blocks = 0
        self.input = {"gaps": 0, "gap_samples": 0, "late_blocks": 0, "workspace_clamped_samples": 0}
        self._expected_k = None
        self.applied_rejected = 0
        self.last_error = ""
        self._seen_failed = 0
        self._announced_version: int | None = None
        self._next_stamp = None
        self._last_block_wall = 0.0
        self.pacer = HoldPacer(cfg.sample_rate, self.block_size, self.hold_timeout)
        self._last_ws_warn = 0.0

        self.pub_u = self.create_publisher(PointCloud2, "voltage", BLOCK_QOS)
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
        self.get_logger().info(f"compensator ready: config v{self.hs.version}, stages "
                               f"{ {k: getattr(cfg.cascade, k) for k in ('vibration', 'creep', 'hysteresis')} }")

    # -- parameters ------------------------------------------------------------------------------------------------
    def _declare(self, name: str, value: Any, description: str = "", read_only: bool = False) -> Any:
        desc = _descriptor(name, value, description, read_only)
        self._types[name] = desc.type
        if isinstance(value, list) and not value:   # rclpy would type an empty list as a byte array
            p: Any = self.declare_parameter(name, _PY_TYPE[desc.type], desc)   # uninitialised unless overridden
            if p.type_ == Parameter.Type.NOT_SET:
                self._set_own([self._typed(name, [])])
            v = self.get_parameter(name).value
        else:
            v = self.declare_parameter(name, value, desc).value
        return list(v) if isinstance(v, (list, tuple)) or hasattr(v, "typecode") else v

    def _apply_descriptor(self, parameter: Parameter, descriptor: ParameterDescriptor | None = None,
                          check_read_only: bool = True) -> SetParametersResult:
        """rclpy's type/range check, after the lossless coercions (an integer where a double is declared, an empty
        array of any type), with the parameter's name in front of a refusal (one line, field first)."""
        t = getattr(self, "_types", {}).get(parameter.name)   # rclpy declares use_sim_time before __init__ runs
        if t is not None:
            _coerce(parameter, t)
        result = super()._apply_descriptor(parameter, descriptor, check_read_only)
        if not result.successful and not result.reason.startswith(parameter.name):
            expected = _TYPE_NAMES.get(t, str(t))
            reason = result.reason
            if reason.startswith("Wrong parameter type"):
                got = _TYPE_NAMES.get(int(parameter.type_), str(parameter.type_))
                try:
                    kept = f" (kept: {self.get_parameter(parameter.name).value!r})"
                except Exception:  # noqa: BLE001 - not declared/initialised yet
                    kept = ""
                reason = f"expected {expected}, got {got} {parameter.value!r}{kept}"
            result.reason = f"{parameter.name}: {reason}"
        return result

    def _typed(self, name: str, value: Any) -> Parameter:
        t = self._types[name]
        if t == ParameterType.PARAMETER_DOUBLE:
            value = float(value)
        elif t == ParameterType.PARAMETER_DOUBLE_ARRAY:
            value = [float(v) for v in value]
        elif t == ParameterType.PARAMETER_INTEGER_ARRAY:
            value = [int(v) for v in value]
        return Parameter(name, _PY_TYPE[t], value)

    def _set_own(self, params: list[Parameter]) -> None:
        """Set parameters from the node itself: no validation round, no configuration version."""
        self._internal = True
        try:   # atomically: one parameter event, as one change
            r = self.set_parameters_atomically(params)
            if not r.successful:
                self.get_logger().error(f"internal parameter update refused: {r.reason}")
        finally:
            self._internal = False

    def _on_set(self, params: list[Parameter]) -> SetParametersResult:
        if self.base is None or self._internal:   # config_file / variant themselves; the node's own updates
            return SetParametersResult(successful=True)
        updates = {}
        yaml_updates = None
        for p in params:
            if p.name == "config_yaml":
                try:
                    yaml_updates = parse_config_yaml(p.value)
                    for k in yaml_updates:
                        if k not in self._types and not self._declaring:
                            raise ConfigError(k, "unknown parameter")
                except ConfigError as exc:
                    self.get_logger().error(f"config_yaml rejected: {exc}")
                    return SetParametersResult(successful=False, reason=str(exc))
                updates.update(yaml_updates)
            elif p.name == "workspace":
                try:
                    self._check_workspace(list(p.value or []))
                except ConfigError as exc:
                    return SetParametersResult(successful=False, reason=str(exc))
            elif is_front_param(p.name):
                merged_front = {**getattr(self, "_front_values", FRONT_DEFAULTS),
                                **{q.name: q.value for q in params if is_front_param(q.name)}}
                try:
                    front_settings(merged_front)
                    if not self._declaring:   # built here (≈ 0.3 s) so that a bad learning file is refused now
                        self._front_candidate = (merged_front, TrackingFront(
                            self.hs.cfg, controller_matrices(self.hs.active), merged_front))
                except ConfigError as exc:
                    return SetParametersResult(successful=False, reason=str(exc))
            elif is_config_param(p.name):
                updates[p.name] = list(p.value) if hasattr(p.value, "typecode") or isinstance(p.value, tuple) \
                    else p.value
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
        self._candidate = (updates, cand, yaml_updates is not None)
        return SetParametersResult(successful=True)

    def _check_workspace(self, flat: list) -> None:
        if self.base is None:
            return
        n = len(self.base.axes)
        if flat and (len(flat) != 2 * n or not all(np.isfinite(flat))
                     or any(flat[2 * i] >= flat[2 * i + 1] for i in range(n))):
            raise ConfigError("workspace", f"expected [min, max] per axis ({2 * n} finite values, min < max), "
                                           f"got {list(flat)}")

    def _post_set(self, params: list[Parameter]) -> None:
        if self._declaring:
            return
        if self._internal:
            for p in params:
                if is_config_param(p.name):
                    self._values[p.name] = list(p.value) if hasattr(p.value, "typecode") else p.value
            return
        for p in params:
            if p.name == "crossfade":
                self.crossfade = float(p.value)
                with self._lock:
                    self.hs.crossfade_samples = int(round(self.crossfade * self.cfg.sample_rate))
            elif p.name == "block_size":
                self.block_size = int(p.value)
                self.pacer.set_block_size(self.block_size)
                self.destroy_timer(self._hold_timer)
                self._hold_timer = self.create_timer(self._hold_tick_period(), self._on_hold_tick)
                if self.pacer.point is None:
                    self._hold_timer.cancel()
            elif p.name == "hold_timeout":
                self.hold_timeout = float(p.value)
                self.pacer.hold_timeout = self.hold_timeout
            elif p.name == "bypass":
                self.bypass = bool(p.value)
            elif p.name == "resync":
                self.resync = bool(p.value)
            elif p.name == "workspace":
                self.workspace = list(p.value)
        if self._front_candidate is not None:
            values, front = self._front_candidate
            self._front_candidate = None
            with self._lock:
                self._front_values, self.front = values, front
            self.get_logger().info(f"tracking front: preview {'on' if front.preview else 'off'} (reference needed "
                                   f"{front.preview_s:g} s ahead), learning {front.learning_file or 'off'}")
        if self._candidate is None:
            return
        updates, cand, from_yaml = self._candidate
        self._candidate = None
        self._values.update(updates)
        if from_yaml:   # the stage parameters read back what now runs; config_yaml is a one-shot input
            own = [self._typed(k, v) for k, v in updates.items() if not _same(self.get_parameter(k).value, v)]
            self._set_own(own + [self._typed("config_yaml", "")])
        with self._lock:
            target = self.hs.pending_cfg or self.hs.cfg
            if cand == target:
                self.get_logger().info(f"parameters set to the values that run ({', '.join(sorted(updates))}): "
                                       "no new configuration")
                return
            bg = any(needs_synthesis(n) for n in updates) or self.hs.needs_background(cand)
            v = self.hs.request(cand, background=bg)
        self.get_logger().info(f"configuration v{v} requested ({', '.join(sorted(updates))})" +
                               ("; building in the background" if bg else ""))
        self.publish_diagnostics()

    def poll(self) -> None:
        """Timer: swap in a finished build even when no block flows; report swaps and failed builds (including
        those the data path found first: :meth:`HotSwapCascade.process` polls too)."""
        with self._lock:
            self.hs.poll()
            failed = self.hs.failed_builds
            error = self.hs.last_error
            version, cfg = self.hs.version, self.hs.cfg
        if failed != self._seen_failed:
            self._seen_failed = failed
            self.last_error = error
            self.get_logger().error(error + f"; parameters reverted to the running configuration v{version}")
            self._revert_to(cfg)
            self.publish_diagnostics()
        if self.cfg is not cfg:
            self.cfg = cfg
            if self.front.active:   # the preview inverts the running cascade: rebuild it for the new one
                with self._lock:
                    old = self.front
                    self.front = TrackingFront(cfg, controller_matrices(self.hs.active), self._front_values)
                    self.front.continue_from(old)
            self.get_logger().info(f"configuration v{version} active")
            self.publish_diagnostics()

    def _revert_to(self, cfg: PiezoConfig) -> None:
        """Parameters back to ``cfg``'s values: only those that differ, without a new configuration version."""
        running = config_to_params(cfg)
        changed = [self._typed(k, v) for k, v in running.items() if not _same(self._values.get(k), v)]
        if changed:
            self._set_own(changed)
            self._values.update(running)

    # -- data path -------------------------------------------------------------------------------------------------
    def on_reference(self, msg: PointCloud2) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        try:
            block = unpack_block(msg, self.axes)
            if not np.all(np.isfinite(block)):
                raise BlockFormatError("NaN/Inf in the reference")
        except BlockFormatError as exc:
            with self._lock:
                self.rejected_blocks += 1
                self.last_error = f"reference block rejected: {exc}"
            self.get_logger().error(self.last_error)
            return
        now = time.monotonic()
        # after a pause (no block for hold_timeout) a jump in the stamps is a new stream, not lost blocks
        restart = now - self._last_block_wall > max(self.hold_timeout, 0.5)
        self._last_block_wall = now
        self.pacer.note_block(now)
        self._process_and_publish(block, stamp, from_topic=True, restart=restart)

    def _clamp_to_workspace(self, block: np.ndarray) -> np.ndarray:
        ws = self.workspace
        if not ws:
            return block
        lo, hi = np.asarray(ws[0::2]), np.asarray(ws[1::2])
        out = np.clip(block, lo, hi)
        n = int(np.count_nonzero(np.any(out != block, axis=1)))
        if n:
            self.input["workspace_clamped_samples"] += n
            now = time.monotonic()
            if now - self._last_ws_warn > 1.0:
                self._last_ws_warn = now
                self.get_logger().warning(f"reference outside the workspace {ws} [m]: {n} samples clamped "
                                       f"(total {self.input['workspace_clamped_samples']})")
        return out

    def _process_and_publish(self, block: np.ndarray, stamp: Any, from_topic: bool = False,
                             restart: bool = False) -> None:
        # one lock around state, counters, stamps and publish (the background H∞ build swaps the cascade under it)
        with self._lock:
            if stamp is None:   # held point: continue the sample stream (or start it on the wall clock)
                stamp = self._next_stamp if self._next_stamp is not None else \
                    time.time_ns() // self.period_ns * self.period_ns
            k0 = stamp // self.period_ns
            if from_topic and not restart and self._expected_k is not None and k0 != self._expected_k:
                if k0 > self._expected_k:
                    self.input["gaps"] += 1
                    self.input["gap_samples"] += int(k0 - self._expected_k)
                    self.get_logger().warning(f"reference gap: {k0 - self._expected_k} samples missing before stamp "
                                           f"{stamp}")
                else:
                    self.input["late_blocks"] += 1
            if from_topic:
                self._expected_k = k0 + block.shape[0]
            if self.bypass:
                u = block
            else:
                # in flight only while a driver reports what it applied (else nothing would ever confirm them)
                track = self.resync and self._applied_sub.get_publisher_count() > 0
                x = self._clamp_to_workspace(block)
                u = self.hs.process(self.front.process(x) if self.front.active else x, k0=k0 if track else None)
            self.blocks += 1
            self._next_stamp = stamp + block.shape[0] * self.period_ns
            if self.hs.version != self._announced_version:
                self._announced_version = self.hs.version
                self._announce(stamp)
            self.pub_u.publish(pack_block(u, self.axes, stamp))

    def _announce(self, stamp: int) -> None:
        node_params = {n: (list(v) if hasattr(v, "typecode") else v) for n, v in
                       ((n, self.get_parameter(n).value) for n in ("crossfade", "block_size", "hold_timeout",
                                                                   "bypass", "resync", "workspace", "config_file",
                                                                   "variant", *FRONT_DEFAULTS))}
        self.pub_config.publish(String(data=json.dumps({
            "version": self.hs.version, "stamp_ns": int(stamp), "config_yaml": self.hs.cfg.to_yaml(),
            "parameters": node_params})))

    def on_applied(self, msg: PointCloud2) -> None:
        if not self.resync:
            return
        try:
            u = unpack_block(msg, self.axes)
        except BlockFormatError as exc:
            self.applied_rejected += 1
            self.get_logger().error(f"voltage_applied block rejected: {exc}")
            return
        with self._lock:
            result = self.hs.applied(stamp_to_ns(msg.header.stamp) // self.period_ns, u)
        if result == "resync":
            self.get_logger().warning("applied voltage differs from the command: hysteresis/creep states "
                                      f"re-synchronised ({self.hs.resyncs} so far)", throttle_duration_sec=1.0)
    def on_point(self, msg: PointStamped) -> None:
        p = [msg.point.x, msg.point.y, msg.point.z][:len(self.axes)]
        if not np.all(np.isfinite(p)):
            self.get_logger().error("reference_point rejected: NaN/Inf")
            return
        self.pacer.set_point(p)
        if self._hold_timer.is_canceled():
            self._hold_timer.reset()

    def _hold_tick_period(self) -> float:
        """The hold timer's period [s]: half a block (the pacer absorbs the timer's jitter), within 1…50 ms."""
        return min(max(0.5 * self.pacer.block_period, 0.001), 0.05)

    def _on_hold_tick(self) -> None:
        """Timer: play the held point's blocks that are due (:class:`~piezo_ff_ros.core.hold_pacer.HoldPacer`)."""
        for _ in range(self.pacer.tick(time.monotonic())):
            self._process_and_publish(self.pacer.block(), None)

    def on_reset(self, request: Any, response: Any) -> Any:
        """``~/reset``: the cascade's state back to rest (and the hold point cleared)."""
        with self._lock:
            self.hs.reset()
            self.front.reset()
            self.pacer.clear()
            self._hold_timer.cancel()
            self._next_stamp = None
            self._expected_k = None
        response.success, response.message = True, f"compensator states reset (config v{self.hs.version})"
        return response

    # -- diagnostics -----------------------------------------------------------------------------------------------
    def status(self) -> dict:
        with self._lock:
            return self._status()

    def _status(self) -> dict:
        st = {**self.hs.status(), "bypass": self.bypass, "blocks": self.blocks, "rejected_blocks": self.rejected_blocks,
              **{f"input_{k}": v for k, v in self.input.items()}, "applied_rejected": self.applied_rejected,
              "stages": ",".join(k for k in ("vibration", "creep", "hysteresis") if getattr(self.hs.cfg.cascade, k)),
              "order": self.hs.cfg.cascade.order,
              # re-synchronisation needs the paper order (commuted: the voltage leaves C(s), not the hysteresis⁻¹)
              "resync_active": bool(self.resync and self.hs.active.can_follow), "preview_s": self.front.preview_s,
              "learning_file": self.front.learning_file}
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
        st = {**self.status(), **writer_matches({"voltage": self.pub_u})}
        warn = [k for k in ("failed_builds", "rejected_blocks", "input_gaps", "input_late_blocks",
                            "input_workspace_clamped_samples") if st.get(k)]
        level = DiagnosticStatus.WARN if warn else DiagnosticStatus.OK
        msg = f"config v{st['config_version']}"
        if st["failed_builds"] and self.last_error:
            msg += f"; {self.last_error}"
        if warn:
            msg += "; " + ", ".join(f"{k} {st[k]}" for k in warn)
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [DiagnosticStatus(level=level, name=self.get_fully_qualified_name(),
                                       message=msg, hardware_id="compensator",
                                       values=diag_values(st))]
        self.pub_diag.publish(arr)

    def stop(self) -> None:
        self._hold_timer.cancel()


def _short(d: dict) -> str:
    parts = []
    for k, v in d.items():
        s = repr(v)
        parts.append(f"{k}={s if len(s) < 80 else s[:77] + '...'}")
    return ", ".join(parts)


def main(argv: Sequence[str] | None = None) -> int:
    """``ros2 run piezo_ff_ros compensator``."""
    return run_node("compensator", CompensatorNode, lambda n: n.stop(), argv)


if __name__ == "__main__":
    sys.exit(main())
