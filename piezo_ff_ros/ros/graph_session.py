"""Driving the node graph from a command (``piezo-ff demo``, ``piezo-ff commission``): one rclpy client node.

- :class:`GraphClient` — parameter pushes (``set_parameters_atomically``), Trigger services, the trajectory's state,
  the compensator's diagnostics and the recorder's status; :meth:`GraphClient.configure` switches the compensator's
  stages (or bypass) and waits until the new configuration runs; :meth:`GraphClient.play` resets driver and
  compensator to rest and plays one named experiment to its end;
- :func:`step_lifecycle` — configure/activate a managed node through its lifecycle services;
- :func:`driver_present` — is a driver already on the domain?

The graph's processes are started by :mod:`.launcher` (:func:`piezo_ff_ros.ros.sim_graph.sim_graph` for the
simulated one), which imports this module, never the reverse.

Import this module only after the ROS environment is set (:func:`piezo_ff_ros.ros.env.apply_ros_env_defaults`).
"""
from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, Mapping

from .service_call import call_service

if TYPE_CHECKING:
    from ..core.trajectories import Trajectory

STAGE_ORDER = ("vibration", "creep", "hysteresis")
BLOCK_TOPICS = ("/reference", "/voltage", "/displacement")
#: the block topics each node of the graph writes (its ``/diagnostics`` report ``matched.<topic>``); the
#: trajectory's ``reference`` writer waits for its own readers before it plays
BLOCK_WRITERS = {"compensator": ("voltage",), "driver": ("voltage_applied", "displacement")}


def stage_string(stages: Iterable[str]) -> str:
    """The compensator's diagnostics spelling of a stage set (e.g. ``'creep,hysteresis'``)."""
    return ",".join(k for k in STAGE_ORDER if k in set(stages))


class GraphClient:
    """The command's own rclpy node (own context): services, trajectory state, diagnostics, recorder status."""

    def __init__(self, name: str = "piezo_ff_client", domain_id: int | None = None) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rcl_interfaces.srv import SetParametersAtomically
        from rclpy.executors import SingleThreadedExecutor
        from std_msgs.msg import String
        from std_srvs.srv import Trigger

        from ..nodes.common import LATCHED_QOS

        self.rclpy = rclpy
        self.context = rclpy.Context()
        if domain_id is None:
            rclpy.init(context=self.context)
        else:
            rclpy.init(context=self.context, domain_id=int(domain_id))
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.states: list[dict[str, Any]] = []
        self.comp_diag: dict[str, Any] = {}
        self.diag: dict[str, dict[str, str]] = {}   # the last /diagnostics values of each node, by node name
        self.hinf: dict[str, Any] | None = None    # γ/orders of the compensator's H∞ design, from its diagnostics
        self.recorder: dict[str, Any] = {}
        self.node.create_subscription(String, "/trajectory/state", lambda m: self.states.append(json.loads(m.data)),
                                      LATCHED_QOS)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 50)
        self.node.create_subscription(String, "/recorder/status", lambda m: self.recorder.update(json.loads(m.data)),
                                      LATCHED_QOS)
        from rcl_interfaces.srv import GetParameters

        self.set_comp: Any = self.node.create_client(SetParametersAtomically, "/compensator/set_parameters_atomically")
        self.get_comp: Any = self.node.create_client(GetParameters, "/compensator/get_parameters")
        self.GetParameters = GetParameters
        self.set_traj: Any = self.node.create_client(SetParametersAtomically, "/trajectory/set_parameters_atomically")
        self.reset_comp: Any = self.node.create_client(Trigger, "/compensator/reset")
        self.reset_drv: Any = self.node.create_client(Trigger, "/driver/reset")
        self.start: Any = self.node.create_client(Trigger, "/trajectory/start")
        self.Trigger = Trigger
        self.SetAtomic = SetParametersAtomically

    def _on_diag(self, msg: Any) -> None:
        for st in msg.status:
            self.diag[st.name.rsplit("/", 1)[-1]] = {kv.key: kv.value for kv in st.values}
            if st.name.endswith("compensator"):
                self.comp_diag = {kv.key: kv.value for kv in st.values}
                self.comp_diag["_t"] = time.monotonic()
                if "hinf" in self.comp_diag:
                    self.hinf = json.loads(self.comp_diag["hinf"])

    # -- plumbing --------------------------------------------------------------------------------------------------
    def spin_until(self, cond: Callable[[], object], timeout: float, what: str) -> None:
        """Spin until ``cond()`` is true; RuntimeError naming ``what`` after ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        while not cond():
            if time.monotonic() > deadline:
                raise RuntimeError(f"timed out after {timeout:g} s waiting for {what}")
            self.executor.spin_once(timeout_sec=0.02)

    def spin_for(self, seconds: float) -> None:
        """Spin the client's executor for ``seconds``."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.02)

    def call(self, client: Any, request: Any, timeout: float = 30.0) -> Any:
        """Call a service and wait for its reply (RuntimeError when unavailable or too slow)."""
        if not client.wait_for_service(timeout_sec=timeout):
            raise RuntimeError(f"service {client.srv_name} not available")
        try:
            return call_service(client, request, lambda t: self.executor.spin_once(timeout_sec=t), timeout)
        except TimeoutError:
            raise RuntimeError(f"timed out after {timeout:g} s waiting for reply of {client.srv_name}") from None

    def set_params(self, client: Any, values: Mapping[str, Any]) -> None:
        """Set parameters atomically through ``client`` (a ``set_parameters_atomically`` client); RuntimeError if
        the node rejects them."""
        from rclpy.parameter import Parameter

        req = self.SetAtomic.Request(parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])
        res = self.call(client, req).result
        if not res.successful:
            raise RuntimeError(f"{client.srv_name} rejected {sorted(values)[:6]}…: {res.reason}")

    def changed_params(self, values: Mapping[str, Any]) -> dict[str, Any]:
        """The entries of ``values`` that differ from the compensator's current parameters (a push of values that
        already run creates no configuration version, so nothing would be waited for)."""
        from rclpy.parameter import parameter_value_to_python

        names = list(values)
        if not names:
            return {}
        res = self.call(self.get_comp, self.GetParameters.Request(names=names))
        out: dict[str, Any] = {}
        for name, pv in zip(names, res.values):
            if not _same_value(parameter_value_to_python(pv), values[name]):
                out[name] = values[name]
        return out

    def trigger(self, client: Any) -> None:
        """Call a ``Trigger`` service; RuntimeError with its message when it reports failure."""
        res = self.call(client, self.Trigger.Request())
        if not res.success:
            raise RuntimeError(f"{client.srv_name}: {res.message}")

    def node_names(self) -> set[str]:
        """Fully qualified names of the nodes on the domain."""
        return {(ns.rstrip("/") + "/" + n) for n, ns in self.node.get_node_names_and_namespaces()}

    def close(self) -> None:
        """Destroy the client node and shut its context down."""
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)

    # -- graph operations ------------------------------------------------------------------------------------------
    def recorder_connected(self) -> bool:
        """The recorder reports a matched publisher on every block topic (its readers have matched them)."""
        return all(self.recorder.get("publishers", {}).get(t, 0) >= 1 for t in BLOCK_TOPICS)

    def writers_unmatched(self) -> dict[str, str]:
        """``{node.topic: why}`` for each block writer of the graph that has not matched every reader of its topic
        (from the nodes' ``matched.<topic>`` diagnostics; empty when all have)."""
        out = {}
        for node, topics in BLOCK_WRITERS.items():
            d = self.diag.get(node, {})
            for t in topics:
                if t == "displacement" and d.get("has_sensor") == "False":
                    continue
                readers = self.node.count_subscribers("/" + t)
                matched = d.get(f"matched.{t}")
                if matched is None or int(matched) < readers:
                    out[f"{node}.{t}"] = f"matched {matched or 'not reported'} of {readers} readers"
        return out

    def wait_recorder_connected(self, timeout: float = 120.0, check: Callable[[], None] | None = None) -> None:
        """Before the first sample is sent: the recorder's readers have matched every block publisher, and every
        block writer (compensator, driver) has matched every reader of its topic — a writer sends nothing to a
        reader it has not matched yet (discovery is asymmetric), so the first blocks of a run would be missing from
        the recording (seen on a loaded machine).  ``check``: called at each spin (e.g. the launched nodes alive).
        """
        def ready() -> bool:
            if check is not None:
                check()
            return self.recorder_connected() and not self.writers_unmatched()
        try:
            self.spin_until(ready, timeout, "the recorder and the block writers to match")
        except RuntimeError as exc:
            raise RuntimeError(f"{exc}: recorder {self.recorder.get('publishers', {})}, writers "
                               f"{self.writers_unmatched() or 'all matched'}") from None

    def configure(self, stages: Iterable[str] = (), bypass: bool = False, params: Mapping[str, Any] | None = None,
                  timeout: float = 900.0, say: Callable[[str], None] = lambda m: None) -> bool:
        """Push ``params`` (flat config parameters) and the stage switches atomically; wait until they run.

        ``bypass``: reference blocks are voltages, forwarded unchanged (S0).  Returns False when the compensator
        could not build the configuration (its last error is in ``comp_diag['last_error']``).
        """
        if bypass:
            self.set_params(self.set_comp, {**(params or {}), "bypass": True})
            return True
        want = {f"cascade.{k}": k in set(stages) for k in STAGE_ORDER}
        stage_str = stage_string(stages)
        failed_before = self.comp_diag.get("failed_builds", "0")
        version_before = self.comp_diag.get("config_version")
        changed = bool(self.changed_params(params)) if params else False
        self.set_params(self.set_comp, {**(params or {}), "bypass": False, **want})
        if "vibration" in stages and self.comp_diag.get("stages") != stage_str:
            say("  (the compensator builds the vibration compensator in the background …)")

        def done() -> bool:
            d = self.comp_diag
            if d.get("failed_builds", "0") != failed_before:
                return True
            return (d.get("stages") == stage_str and d.get("pending_version") == "None"
                    and (not changed or d.get("config_version") != version_before))

        self.spin_until(done, timeout, f"compensator configuration {stage_str or 'none'}")
        return self.comp_diag.get("stages") == stage_str and self.comp_diag.get("failed_builds", "0") == failed_before

    def play(self, name: str, trajectory: Trajectory, meta: Mapping[str, Any], timeout: float = 3600.0) -> float:
        """Reset driver and compensator to rest, play ``trajectory`` as segment ``name``; returns the wall time."""
        from ..core.trajectories import TrajectorySequence

        self.trigger(self.reset_drv)
        self.trigger(self.reset_comp)
        seq = TrajectorySequence([(name, trajectory, meta)])
        self.set_params(self.set_traj, {"trajectory": json.dumps(seq.to_dict())})
        n_before = len(self.states)
        t0 = time.perf_counter()
        self.trigger(self.start)
        ends = ("finished", "failed", "stopped")
        self.spin_until(lambda: any(s["state"] in ends for s in self.states[n_before:]), timeout,
                        f"experiment {name}")
        end = [s for s in self.states[n_before:] if s["state"] in ends][0]
        if end["state"] != "finished":
            raise RuntimeError(f"experiment {name}: trajectory {end['state']}: {end.get('error', '')}")
        return time.perf_counter() - t0


def step_lifecycle(node: str, transitions: Iterable[str], domain_id: int | None = None,
                   timeout: float = 60.0) -> str:
    """Step a managed node (``/driver``) through ``transitions`` (labels: ``configure``, ``activate``, …) through
    its ``<node>/change_state`` service, as ``ros2 lifecycle set`` does; returns the state it ends in.

    RuntimeError naming the transition and the state the node is left in when one fails (the node's log says why).
    """
    import rclpy
    from lifecycle_msgs.srv import ChangeState, GetState
    from rclpy.executors import SingleThreadedExecutor

    from .env import apply_ros_env_defaults

    apply_ros_env_defaults(domain_id=domain_id)   # localhost discovery in this process too
    context = rclpy.Context()
    if domain_id is None:
        rclpy.init(context=context)
    else:
        rclpy.init(context=context, domain_id=int(domain_id))
    try:
        client_node = rclpy.create_node("piezo_ff_lifecycle", context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(client_node)

        def call(srv: Any, request: Any) -> Any:
            if not srv.wait_for_service(timeout_sec=timeout):
                raise RuntimeError(f"service {srv.srv_name} not available after {timeout:g} s")
            try:
                return call_service(srv, request, lambda t: executor.spin_once(timeout_sec=t), timeout)
            except TimeoutError:
                raise RuntimeError(f"no reply from {srv.srv_name} after {timeout:g} s") from None

        change: Any = client_node.create_client(ChangeState, f"{node}/change_state")
        get: Any = client_node.create_client(GetState, f"{node}/get_state")
        for label in transitions:
            req = ChangeState.Request()
            req.transition.label = label
            if not call(change, req).success:
                state = call(get, GetState.Request()).current_state.label
                raise RuntimeError(f"{node}: transition {label} failed, the node is {state} (its log says why)")
        return str(call(get, GetState.Request()).current_state.label)
    finally:
        context.try_shutdown()


def _same_value(a: Any, b: Any) -> bool:
    """Parameter values equal as the compensator compares them (arrays element-wise, ints as floats)."""
    if isinstance(a, (list, tuple)) or isinstance(b, (list, tuple)) or hasattr(a, "tolist"):
        a = list(a.tolist() if hasattr(a, "tolist") else a)
        b = list(b.tolist() if hasattr(b, "tolist") else b)
        return len(a) == len(b) and all(_same_value(x, y) for x, y in zip(a, b))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return float(a) == float(b)
    return a == b


def driver_present(client: GraphClient, timeout: float = 3.0) -> bool:
    """True if a node named ``driver`` or a subscriber of ``/voltage`` shows up within ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if any(n.endswith("/driver") for n in client.node_names()) or client.node.count_subscribers("/voltage"):
            return True
        client.spin_for(0.2)
    return False


def displacement_present(client: GraphClient, timeout: float = 5.0) -> bool:
    """True if a ``/displacement`` publisher (a driver whose device has a sensor) shows up within ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if client.node.count_publishers("/displacement") > 0:
            return True
        client.spin_for(0.2)
    return False
