"""Trajectory node: plays a :mod:`piezo_ff_ros.core.trajectories` trajectory as ``reference`` blocks [m].

The play loop, the lockstep window, the acknowledgement expiry and the parameter checks are
:class:`~piezo_ff_ros.core.trajectory_player.TrajectoryPlayer`'s; this node maps parameters, topics and services to
it, and tells it when the graph is ready.

Parameters (all reloadable; a new trajectory is validated in the on-set callback — rejected with the ConfigError
text naming the field — and used from the next start):

- ``trajectory``: the trajectory as JSON or YAML text (``core.trajectories.from_dict`` spec, e.g.
  ``{type: circle, radius: 2.0e-5, frequency: 1.0, revolutions: 3}``; a ``sequence`` of named segments publishes
  an ``experiment`` marker at each segment start); ``trajectory_file``: the same from a YAML/JSON file (wins when set),
  or a table of samples (``.npy``, or ``.csv`` with a header of axis names) played sample-exactly at ``sample_rate``;
- ``workspace_m`` (default 1e-4 m): a trajectory reaching beyond ±workspace_m on any axis is refused, naming the
  field (segments marked ``input: voltage`` are checked against ±``voltage_limit`` V instead); 0 disables;
- ``mode``: ``realtime`` (paced by the wall clock with sleep-until, stamps follow the wall clock) or ``lockstep`` (as
  fast as the graph answers, deterministic and lossless: at most ``window`` blocks in flight, the next block is
  sent when the ``displacement`` for an earlier one came back);
- ``block_size`` (samples, default 200), ``window`` (lockstep blocks in flight, default 4), ``sample_rate`` [Hz],
  ``autostart`` (bool), ``loop`` (bool), ``lockstep_timeout`` [s] (no displacement for this long while blocks are
  in flight → stop with an error; also how long playing waits for the graph), ``ack_timeout`` [s] (default 5;
  lockstep: a block not answered for this long is given up — its node died, or the driver dropped it — counted as
  ``unanswered_blocks`` in ``~/state`` with a WARN, so that a restarted compensator or driver rejoins the run; a
  displacement for a later stamp gives up the earlier blocks at once, the driver's stream never going back),
  ``t0_ns`` (stamp of sample index 0; 0 = the wall clock at start-up), ``min_subscribers`` (playing starts
  once ``reference``, ``voltage`` and ``displacement`` each have that many readers — 2 with a recorder — and, in
  lockstep, ``voltage`` and ``displacement`` a writer).

A table can also arrive as a message: a block (``sensor_msgs/PointCloud2``, the topic contract of docs/topics.md,
N samples × the axes, [m]) on ``~/table`` is written to ``table_dir`` (default: a temporary directory) as ``.npy``
and becomes ``trajectory_file`` through the same validation as a parameter change (so the parameters always say
what will play), played sample-exactly at ``sample_rate`` from the next start — for a client on another machine.

Services: ``~/start`` and ``~/stop`` (std_srvs/Trigger).  Topics: ``reference`` (blocks), ``experiment``
(std_msgs/String, transient-local: JSON ``{"name", "k0", "stamp_ns", "stages", …segment meta}``), ``~/state``
(std_msgs/String, transient-local: JSON ``{"state": idle|playing|finished|stopped|failed, "mode": realtime|lockstep,
"k", "blocks", …}``; the driver reads it: a lockstep run playing suspends the lockstep simulator's stale watchdog).
"""
from __future__ import annotations

import hashlib
import json
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from ..core.config import ConfigError
from ..core.trajectories import Trajectory
from ..core.trajectory_player import PlaySettings, TrajectoryPlayer, check_play_params, parse_trajectory
from ..core.units import sample_period_ns
from .common import (BLOCK_QOS, LATCHED_QOS, BlockFormatError, log_lines, pack_block, run_node, stamp_to_ns,
                     unpack_block)
from .params import TypedParameters, refuse_unknown_parameters

DEFAULT_TRAJECTORY = json.dumps({"type": "circle", "radius": 2.0e-5, "frequency": 1.0, "revolutions": 5})

__all__ = ["TrajectoryNode", "main", "parse_trajectory"]


class _NodeHost:
    """The player's clocks, waits and publishers: the system clocks and this node's topics."""

    def __init__(self, node: "TrajectoryNode") -> None:
        self.node = node

    def monotonic(self) -> float:
        return time.monotonic()

    def wall_ns(self) -> int:
        return time.time_ns()

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)

    def wait(self, cv: threading.Condition, seconds: float) -> None:
        cv.wait(seconds)

    def wait_graph(self, timeout: float, lockstep: bool) -> None:
        self.node.wait_graph(timeout, lockstep)

    def publish_reference(self, block: np.ndarray, axes: list[str], stamp_ns: int) -> None:
        self.node.pub_ref.publish(pack_block(block, axes, stamp_ns))

    def publish_experiment(self, info: dict[str, Any]) -> None:
        self.node.pub_exp.publish(String(data=json.dumps(info, default=str)))

    def publish_state(self, state: dict[str, Any]) -> None:
        self.node.pub_state.publish(String(data=json.dumps(state)))

    def log(self, level: int, text: str) -> None:
        log_lines(self.node.get_logger(), [(level, text)])


class TrajectoryNode(Node):
    """See the module docstring."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("trajectory", **kwargs)
        self._ready = False
        self.add_on_set_parameters_callback(self._on_set)
        self.traj: Trajectory | None = None     # set below (the on-set callback runs during the declarations)
        self.params = params = TypedParameters(self)   # after _on_set: the type check runs first
        d = params.declare
        p: dict[str, Any] = {
            "trajectory": d("trajectory", DEFAULT_TRAJECTORY, "the trajectory: a spec as JSON or YAML"),
            "trajectory_file": d("trajectory_file", "", "a spec file (YAML/JSON) or a table (.npy, .csv); wins "
                                 "when set"),
            "mode": d("mode", "realtime", "realtime (paced by the clock) or lockstep (as fast as the graph answers)"),
            "block_size": d("block_size", 200, "samples per reference block"),
            "window": d("window", 4, "lockstep: blocks in flight at most"),
            "sample_rate": d("sample_rate", 20000.0, "samples per second [Hz] (read-only after start-up)"),
            "autostart": d("autostart", False, "start playing once the node is up"),
            "loop": d("loop", False, "play again at the end"),
            "lockstep_timeout": d("lockstep_timeout", 10.0, "lockstep: no displacement for this long fails the run; "
                                  "also how long playing waits for the graph [s]"),
            "ack_timeout": d("ack_timeout", 5.0, "lockstep: a block not answered for this long is given up [s]"),
            "t0_ns": d("t0_ns", 0, "stamp of sample index 0 [ns] (0: the wall clock at start-up)"),
            "min_subscribers": d("min_subscribers", 1, "readers each block topic needs before playing"),
            # reference preview [s]: play the trajectory this far ahead, so that a plant with an input delay (e.g.
            # `piezo-ff diagnose --apply` → reference_preview.delay_s) lands on time; trajectories are pure
            # functions of the sample index, so the preview is exact
            "preview_s": d("preview_s", 0.0, "play the trajectory this far ahead [s]"),
            # workspace: a trajectory beyond ±workspace_m [m] is refused (0: off); voltage segments: ±voltage_limit
            "workspace_m": d("workspace_m", 1e-4, "a trajectory beyond ±workspace_m [m] is refused (0: no check)"),
            "voltage_limit": d("voltage_limit", 200.0, "bound of segments marked input: voltage [V]"),
            "table_dir": d("table_dir", "", "where tables received on ~/table are saved ('' = a temporary directory)"),
        }
        refuse_unknown_parameters(self)
        self.traj = parse_trajectory(p["trajectory"], p["trajectory_file"], float(p["sample_rate"]),
                                     float(p["workspace_m"]), float(p["voltage_limit"]))
        self.fs = float(p["sample_rate"])
        self.pub_ref = self.create_publisher(PointCloud2, "reference", BLOCK_QOS)
        self.pub_exp = self.create_publisher(String, "experiment", LATCHED_QOS)
        self.pub_state = self.create_publisher(String, "~/state", LATCHED_QOS)
        self.player = TrajectoryPlayer(_NodeHost(self), sample_period_ns(self.fs), int(p["t0_ns"]))
        self.create_subscription(PointCloud2, "displacement", self.on_displacement, BLOCK_QOS)
        self.create_subscription(PointCloud2, "~/table", self.on_table, LATCHED_QOS)
        self._tmp_tables: tempfile.TemporaryDirectory | None = None
        self.create_service(Trigger, "~/start", self.on_start)
        self.create_service(Trigger, "~/stop", self.on_stop)
        self._ready = True
        self.player.set_state("idle", mode=self.param("mode"))
        self.get_logger().info(f"trajectory ready: {type(self.traj).__name__}, mode {self.param('mode')}, "
                               f"t0_ns {self.player.t0_ns}")
        if p["autostart"]:
            self.start()

    def _trajectory(self) -> Trajectory:
        """The trajectory to play (always set once the node is built)."""
        if self.traj is None:
            raise RuntimeError("trajectory node: no trajectory yet")
        return self.traj

    def param(self, name: str) -> Any:
        return self.get_parameter(name).value

    # -- parameters ------------------------------------------------------------------------------------------------
    def _on_set(self, params: list[Parameter]) -> SetParametersResult:
        values = {p.name: p.value for p in params}
        try:
            check_play_params(values)
            if self._ready and "sample_rate" in values:
                raise ConfigError("sample_rate", "read-only after start-up")
            if "trajectory" in values or "trajectory_file" in values:
                text = values.get("trajectory", self.param("trajectory") if self._ready else "")
                file = values.get("trajectory_file", self.param("trajectory_file") if self._ready else "")
                if text or file:
                    ws = values.get("workspace_m", self.param("workspace_m") if self._ready else 0.0)
                    vlim = values.get("voltage_limit", self.param("voltage_limit") if self._ready else 200.0)
                    traj = parse_trajectory(text, file, self.fs if self._ready else 20000.0, float(ws), float(vlim))
                    if self._ready:
                        self.traj = traj
        except ConfigError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def on_table(self, msg: PointCloud2) -> None:
        """A table as a block message: saved as .npy, then set as ``trajectory_file`` (validated like any change)."""
        log = self.get_logger()
        try:
            table = np.ascontiguousarray(unpack_block(msg, tuple(self._trajectory().axes)), dtype=np.float64)
        except BlockFormatError as exc:
            log.error(f"~/table: refused ({exc})")
            return
        folder = str(self.param("table_dir"))
        if not folder:
            if self._tmp_tables is None:
                self._tmp_tables = tempfile.TemporaryDirectory(prefix="piezo_ff_tables_")
            folder = self._tmp_tables.name
        path = Path(folder) / f"table_{hashlib.sha256(table.tobytes()).hexdigest()[:16]}.npy"
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            np.save(path, table, allow_pickle=False)
        except OSError as exc:
            log.error(f"table_dir: cannot write {path} ({exc})")
            return
        res = self.set_parameters_atomically([Parameter("trajectory_file", value=str(path)),
                                              Parameter("trajectory", value="")])
        if res.successful:
            log.info(f"~/table: {table.shape[0]} samples × {table.shape[1]} axes → trajectory_file {path} "
                     "(played from the next start)")
        else:
            log.error(f"~/table: refused ({res.reason})")

    # -- play ------------------------------------------------------------------------------------------------------
    def on_start(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.success, response.message = self.start()
        return response

    def on_stop(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        was = self.player.playing
        self.stop()
        response.success, response.message = True, ("stopped" if was else "was not playing")
        return response

    def start(self) -> tuple[bool, str]:
        """Play the current trajectory with the current parameters (from the stream's next sample)."""
        settings = PlaySettings.from_params({name: self.param(name) for name in
                                             ("mode", "block_size", "window", "preview_s", "loop",
                                              "lockstep_timeout", "ack_timeout")})
        return self.player.start(self._trajectory(), self.fs, settings)

    def stop(self, join: bool = True) -> None:
        self.player.stop(join)

    def on_displacement(self, msg: PointCloud2) -> None:
        self.player.on_ack(stamp_to_ns(msg.header.stamp), int(msg.width))

    def wait_graph(self, timeout: float, lockstep: bool) -> None:
        """Before playing: every block topic has ``min_subscribers`` readers (e.g. 2 = next node + recorder)."""
        need = int(self.param("min_subscribers"))
        deadline = time.monotonic() + timeout
        settle = False
        while not self.player.stopping:
            # reference: every reader discovered is matched by our own writer (discovered is not enough: a reader
            # this writer has not matched yet misses the first blocks — a recorder after a restart of this node lost
            # 3 of them)
            ref_matched = self.pub_ref.get_subscription_count()
            counts = {"reference": min(self.count_subscribers("reference"), ref_matched),
                      "voltage": self.count_subscribers("voltage"),
                      "displacement": self.count_subscribers("displacement")}  # includes our own
            # lockstep needs the whole chain; realtime may feed a compensator (or any reader) alone
            writers = {"voltage": self.count_publishers("voltage"),
                       "displacement": self.count_publishers("displacement")} if lockstep else {}
            if all(c >= need for c in counts.values()) and all(w >= 1 for w in writers.values()) \
                    and ref_matched >= self.count_subscribers("reference"):
                break
            settle = True
            if time.monotonic() > deadline:
                raise TimeoutError(f"graph not ready after {timeout} s: subscribers {counts} (need {need} each), "
                                   f"publishers {writers} (need 1 each)")
            time.sleep(0.05)
        if settle:
            time.sleep(0.5)  # graph discovery precedes endpoint matching by a little


def main(argv: list[str] | None = None) -> int:
    return run_node("trajectory", TrajectoryNode, lambda n: n.stop(), argv)


if __name__ == "__main__":
    sys.exit(main())
