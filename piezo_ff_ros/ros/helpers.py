"""What ``ros2 topic pub``, ``ros2 param get/set/list``, ``ros2 topic echo`` and ``ros2 lifecycle`` do for this
package's graph, for environments without the ``ros2`` CLI (the pip wheels ship rclpy but not ros2cli).

Used by the ``piezo-ff hold | param | echo | lifecycle`` commands.  Each call opens its own short-lived rclpy
context on the caller's ``ROS_DOMAIN_ID`` (0 when unset, like ``ros2``), with localhost discovery.  Errors are
:class:`HelperError` with one line that says what to do (an unknown parameter name lists the close ones).
"""
from __future__ import annotations

import difflib
import math
import os
import time
from typing import Any, Callable, Iterator, Sequence

import yaml

#: how long a helper waits for a node, a service or a publisher to show up [s]
DEFAULT_TIMEOUT = 10.0


class HelperError(ValueError):
    """A helper could not do what it was asked (one line, for the command's error message)."""


class Session:
    """A short-lived rclpy node on the graph's domain (context manager)."""

    def __init__(self, name: str = "piezo_ff_cli", timeout: float = DEFAULT_TIMEOUT) -> None:
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"   # never multicast off this machine
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.timeout = timeout
        self.rclpy = rclpy
        self.context = rclpy.Context()
        domain = os.environ.get("ROS_DOMAIN_ID", "0") or "0"
        rclpy.init(context=self.context, domain_id=int(domain))
        self.domain = int(domain)
        self.node = rclpy.create_node(f"{name}_{os.getpid()}", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def __enter__(self) -> "Session":
        return self

    def __exit__(self, *exc: object) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()

    def spin_until(self, cond: Callable[[], object], what: str, timeout: float | None = None) -> None:
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        while not cond():
            if time.monotonic() > deadline:
                raise HelperError(f"{what} (ROS_DOMAIN_ID={self.domain}: the graph's? the launcher prints it)")
            self.executor.spin_once(timeout_sec=0.02)

    def call(self, srv_type: Any, service: str, request: Any) -> Any:
        client: Any = self.node.create_client(srv_type, service)
        try:
            self.spin_until(client.service_is_ready, f"no service {service} within {self.timeout:g} s: is the "
                                                     "node running?")
            from .service_call import call_service

            try:
                return call_service(client, request, lambda t: self.executor.spin_once(timeout_sec=t), self.timeout)
            except TimeoutError:
                raise HelperError(f"no reply from {service} within {self.timeout:g} s (ROS_DOMAIN_ID={self.domain}: "
                                  "the graph's? the launcher prints it)") from None
        finally:
            self.node.destroy_client(client)


def node_path(name: str) -> str:
    """``driver`` → ``/driver``; ``/tube1/driver`` unchanged."""
    return name if name.startswith("/") else "/" + name


# -- parameters --------------------------------------------------------------------------------------------------
def _value_to_python(pv: Any) -> Any:
    from rclpy.parameter import parameter_value_to_python

    return parameter_value_to_python(pv)


def list_parameters(s: Session, node: str) -> list[str]:
    """Every parameter name of ``node``."""
    from rcl_interfaces.srv import ListParameters

    return sorted(s.call(ListParameters, f"{node_path(node)}/list_parameters", ListParameters.Request()).result.names)


def _unknown(s: Session, node: str, name: str) -> HelperError:
    names = list_parameters(s, node)
    close = difflib.get_close_matches(name, names, n=5, cutoff=0.5)
    close += [n for n in names if name and name in n and n not in close][:5 - len(close)]
    hint = f"did you mean {', '.join(close)}?" if close else f"`piezo-ff param list {node}` lists its {len(names)}"
    return HelperError(f"{node_path(node)} has no parameter {name!r}: {hint}")


def get_parameter(s: Session, node: str, name: str) -> Any:
    """The value of ``name`` on ``node`` (HelperError with "did you mean" for an unknown name)."""
    from rcl_interfaces.msg import ParameterType
    from rcl_interfaces.srv import GetParameters

    res = s.call(GetParameters, f"{node_path(node)}/get_parameters", GetParameters.Request(names=[name]))
    if not res.values or res.values[0].type == ParameterType.PARAMETER_NOT_SET:
        raise _unknown(s, node, name)
    return _value_to_python(res.values[0])


def parse_value(text: str, current: Any) -> Any:
    """The command-line ``text`` as a value of the parameter's current type.

    A string parameter takes ``text`` as it is (a YAML document such as ``config_yaml`` stays a string — ``ros2
    param set`` parses it into a mapping and fails); others parse it as YAML (``1e-5``, ``true``, ``[1, 2]``), an
    integer widened to a double where the parameter is a double.
    """
    if isinstance(current, str):
        return text
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise HelperError(f"value {text!r}: not YAML ({str(exc).splitlines()[0]})") from None
    if isinstance(current, bool) or isinstance(value, bool):
        if not (isinstance(current, bool) and isinstance(value, bool)):
            raise HelperError(f"value {text!r}: expected a {type(current).__name__}")
        return value
    if isinstance(current, float) and isinstance(value, int):
        return float(value)
    if isinstance(current, (list, tuple)) and isinstance(value, list):
        if current and all(isinstance(v, float) for v in current):
            return [float(v) for v in value]
        return value
    if current is not None and not isinstance(value, type(current)):
        raise HelperError(f"value {text!r}: expected a {type(current).__name__} like the current {current!r}")
    return value


def set_parameter(s: Session, node: str, name: str, text: str) -> tuple[Any, Any]:
    """Set ``name`` on ``node`` from ``text`` (see :func:`parse_value`); returns (old, new) as the node reads them
    back.  HelperError with the node's reason when it rejects the value (the old value keeps running)."""
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    old = get_parameter(s, node, name)
    value = parse_value(text, old)
    req = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
    res = s.call(SetParameters, f"{node_path(node)}/set_parameters", req).results[0]
    if not res.successful:
        raise HelperError(f"{node_path(node)} rejected {name}: {res.reason}")
    return old, get_parameter(s, node, name)


# -- topics ------------------------------------------------------------------------------------------------------
def hold_point(s: Session, xyz: Sequence[float], topic: str = "reference_point", frame: str = "piezo") -> None:
    """Publish one ``geometry_msgs/PointStamped`` on ``topic`` once a subscriber (the compensator) has matched."""
    from geometry_msgs.msg import PointStamped

    vals = [float(v) for v in xyz]
    if not 1 <= len(vals) <= 3 or not all(math.isfinite(v) for v in vals):
        raise HelperError(f"point {list(xyz)}: 1 to 3 finite coordinates [m] expected")
    pub = s.node.create_publisher(PointStamped, topic, 10)
    s.spin_until(lambda: pub.get_subscription_count() > 0, f"no subscriber of {pub.topic_name} within "
                                                           f"{s.timeout:g} s: is the compensator running?")
    msg = PointStamped()
    msg.header.stamp = s.node.get_clock().now().to_msg()
    msg.header.frame_id = frame
    vals += [0.0] * (3 - len(vals))
    msg.point.x, msg.point.y, msg.point.z = vals
    pub.publish(msg)
    # a reliable publisher: wait until the subscriber has it before the process ends
    from rclpy.duration import Duration

    pub.wait_for_all_acked(Duration(seconds=s.timeout))


def message_to_dict(msg: Any) -> Any:
    """A ROS message as plain Python (nested dicts/lists; byte arrays summarised) for printing as YAML/JSON."""
    if hasattr(msg, "get_fields_and_field_types"):
        out = {}
        for field, ftype in msg.get_fields_and_field_types().items():
            value = getattr(msg, field)
            if ftype in ("sequence<uint8>", "uint8[]") or (hasattr(value, "tobytes") and field == "data"):
                out[field] = f"<{len(value)} bytes>"
            else:
                out[field] = message_to_dict(value)
        return out
    if isinstance(msg, (list, tuple)) or hasattr(msg, "tolist"):
        return [message_to_dict(v) for v in (msg.tolist() if hasattr(msg, "tolist") else msg)]
    if isinstance(msg, bytes):
        return msg.decode(errors="replace") if len(msg) == 1 else f"<{len(msg)} bytes>"
    return msg


def echo(s: Session, topic: str, count: int, timeout: float) -> Iterator[dict[str, Any]]:
    """Yield up to ``count`` messages of ``topic`` (its type found in the graph) as dicts; HelperError when the
    topic does not show up, with the topics that do."""
    import importlib

    from ..nodes.common import BLOCK_QOS

    name = topic if topic.startswith("/") else "/" + topic
    types: dict[str, list[str]] = {}

    def found() -> bool:
        types.update(dict(s.node.get_topic_names_and_types()))
        return bool(types.get(name))

    try:
        s.spin_until(found, f"no topic {name}")
    except HelperError:
        known = sorted(t for t in types if not t.startswith("/_"))
        close = difflib.get_close_matches(name, known, n=3, cutoff=0.5)
        raise HelperError(f"no topic {name} on ROS_DOMAIN_ID={s.domain}" + (
            f": did you mean {', '.join(close)}?" if close else f" (topics: {', '.join(known) or 'none'})")) from None
    pkg, kind, cls_name = types[name][0].split("/")
    cls = getattr(importlib.import_module(f"{pkg}.{kind}"), cls_name)
    got: list[Any] = []
    sub = s.node.create_subscription(cls, name, got.append, BLOCK_QOS)
    try:
        n = 0
        deadline = time.monotonic() + timeout
        while n < count:
            if time.monotonic() > deadline:
                raise HelperError(f"{name}: {n} of {count} message(s) within {timeout:g} s")
            s.executor.spin_once(timeout_sec=0.05)
            while got and n < count:
                n += 1
                yield message_to_dict(got.pop(0))
    finally:
        s.node.destroy_subscription(sub)


def lifecycle(s: Session, node: str, transition: str | None) -> str:
    """``ros2 lifecycle set NODE TRANSITION`` (None: ``get``): the state the node is in afterwards."""
    from lifecycle_msgs.srv import ChangeState, GetState

    path = node_path(node)
    if transition is not None:
        req = ChangeState.Request()
        req.transition.label = transition
        if not s.call(ChangeState, f"{path}/change_state", req).success:
            state = s.call(GetState, f"{path}/get_state", GetState.Request()).current_state.label
            raise HelperError(f"{path}: transition {transition} failed; it is {state} (its log says why)")
    return str(s.call(GetState, f"{path}/get_state", GetState.Request()).current_state.label)
