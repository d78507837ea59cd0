"""Trajectory node: plays a :mod:`piezo_ff_ros.core.trajectories` trajectory as ``reference`` blocks [m].

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
import math
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from ..core.config.loader import safe_yaml
from ..core.config import ConfigError
from ..core.trajectories import Sequence, Table, Trajectory, check_workspace, from_dict
from .common import BLOCK_QOS, LATCHED_QOS, BlockFormatError, dt_ns, pack_block, run_node, stamp_to_ns, unpack_block

DEFAULT_TRAJECTORY = json.dumps({"type": "circle", "radius": 2.0e-5, "frequency": 1.0, "revolutions": 5})


def parse_trajectory(text: str = "", file: str = "", sample_rate: float = 20000.0, workspace_m: float = 0.0,
                     voltage_limit: float | None = None) -> Trajectory:
    """Trajectory from spec text (JSON/YAML), a spec file or a table file (.npy/.csv, at ``sample_rate``), checked
    against the workspace; ConfigError naming the field otherwise."""
    traj = _parse(text, file, sample_rate)
    check_workspace(traj, workspace_m, voltage_limit, fs=sample_rate)
    return traj


def _parse(text: str, file: str, sample_rate: float) -> Trajectory:
    if file:
        p = Path(file)
        if not p.is_file():
            raise ConfigError("trajectory_file", f"{file}: no such file")
        if p.suffix.lower() in (".npy", ".csv"):
            try:
                return Table(file=str(p), sample_rate=sample_rate)
            except ConfigError as exc:
                raise ConfigError(f"trajectory_file.{exc.field}", exc.reason) from None
        text = p.read_text()
    spec = safe_yaml(text, "trajectory") if text.strip() else None   # size/depth/alias limits: no crash, no stall
    if spec is None:
        raise ConfigError("trajectory", "empty")
    return from_dict(spec, prefix="trajectory")


class TrajectoryNode(Node):
    """See the module docstring."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("trajectory", **kwargs)
        self._ready = False
        self.add_on_set_parameters_callback(self._on_set)
        self.traj: Trajectory | None = None     # set below (the on-set callback runs during the declarations)
        p: dict[str, Any] = {
            "trajectory": self.declare_parameter("trajectory", DEFAULT_TRAJECTORY).value,
            "trajectory_file": self.declare_parameter("trajectory_file", "").value,
            "mode": self.declare_parameter("mode", "realtime").value,
            "block_size": self.declare_parameter("block_size", 200).value,
            "window": self.declare_parameter("window", 4).value,
            "sample_rate": self.declare_parameter("sample_rate", 20000.0).value,
            "autostart": self.declare_parameter("autostart", False).value,
            "loop": self.declare_parameter("loop", False).value,
            "lockstep_timeout": self.declare_parameter("lockstep_timeout", 10.0).value,
            "ack_timeout": self.declare_parameter("ack_timeout", 5.0).value,
            "t0_ns": self.declare_parameter("t0_ns", 0).value,
            "min_subscribers": self.declare_parameter("min_subscribers", 1).value,
            # reference preview [s]: play the trajectory this far ahead, so that a plant with an input delay (e.g.
            # `piezo-ff diagnose --apply` → reference_preview.delay_s) lands on time; trajectories are pure
            # functions of the sample index, so the preview is exact
            "preview_s": self.declare_parameter("preview_s", 0.0).value,
            # workspace: a trajectory beyond ±workspace_m [m] is refused (0: off); voltage segments: ±voltage_limit
            "workspace_m": self.declare_parameter("workspace_m", 1e-4).value,
            "voltage_limit": self.declare_parameter("voltage_limit", 200.0).value,
            "table_dir": self.declare_parameter("table_dir", "").value,
        }
        self.traj = parse_trajectory(p["trajectory"], p["trajectory_file"], float(p["sample_rate"]),
                                     float(p["workspace_m"]), float(p["voltage_limit"]))
        self.fs = float(p["sample_rate"])
        self.period_ns = dt_ns(self.fs)
        t0 = int(p["t0_ns"]) or time.time_ns()
        self.t0_ns = t0 // self.period_ns * self.period_ns
        self.k_stream = 0            # stream sample index of the next block (never goes back)
        self._cv = threading.Condition()
        self._inflight: dict[int, float] = {}    # lockstep: stamp → when sent (monotonic)
        self.unanswered = 0                       # lockstep blocks given up (never answered)
        self._last_ack = time.monotonic()
        self._play_thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.state: dict[str, Any] = {"state": "idle"}
        self._run_mode: str | None = None          # the mode of the run being played (the parameter may change)
        self.pub_ref = self.create_publisher(PointCloud2, "reference", BLOCK_QOS)
        self.pub_exp = self.create_publisher(String, "experiment", LATCHED_QOS)
        self.pub_state = self.create_publisher(String, "~/state", LATCHED_QOS)
        self.create_subscription(PointCloud2, "displacement", self.on_displacement, BLOCK_QOS)
        self.create_subscription(PointCloud2, "~/table", self.on_table, LATCHED_QOS)
        self._tmp_tables: tempfile.TemporaryDirectory | None = None
        self.create_service(Trigger, "~/start", self.on_start)
        self.create_service(Trigger, "~/stop", self.on_stop)
        self._ready = True
        self._set_state("idle")
        self.get_logger().info(f"trajectory ready: {type(self.traj).__name__}, mode {self.param('mode')}, "
                               f"t0_ns {self.t0_ns}")
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
            if "mode" in values and values["mode"] not in ("realtime", "lockstep"):
                raise ConfigError("mode", f"must be 'realtime' or 'lockstep', got {values['mode']!r}")
            for name in ("block_size", "window"):
                if name in values and (not isinstance(values[name], int) or values[name] < 1):
                    raise ConfigError(name, f"must be an integer ≥ 1, got {values[name]!r}")
            if "block_size" in values and values["block_size"] > 20000:
                raise ConfigError("block_size", "must be ≤ 20000 (the driver's default max_block)")
            if "preview_s" in values and (isinstance(values["preview_s"], bool)
                                          or not isinstance(values["preview_s"], (int, float))
                                          or not 0.0 <= values["preview_s"] <= 1.0):
                raise ConfigError("preview_s", f"must be a number of seconds in [0, 1], got {values['preview_s']!r}")
            for name in ("workspace_m",):
                if name in values and (isinstance(values[name], bool) or not isinstance(values[name], (int, float))
                                       or not 0.0 <= values[name] < math.inf):
                    raise ConfigError(name, f"must be a number of metres >= 0 (0: no check), got {values[name]!r}")
            for name in ("sample_rate", "lockstep_timeout", "ack_timeout", "voltage_limit"):
                if name in values and (isinstance(values[name], bool) or not isinstance(values[name], (int, float))
                                       or not values[name] > 0):
                    raise ConfigError(name, f"must be a number > 0, got {values[name]!r}")
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
        was = self._play_thread is not None and self._play_thread.is_alive()
        self.stop()
        response.success, response.message = True, ("stopped" if was else "was not playing")
        return response

    def start(self) -> tuple[bool, str]:
        if self._play_thread is not None and self._play_thread.is_alive():
            return False, "already playing (call ~/stop first)"
        self._stop.clear()
        self._play_thread = threading.Thread(target=self._play, name="trajectory-play", daemon=True)
        self._play_thread.start()
        return True, f"playing {type(self.traj).__name__} from sample {self.k_stream}"

    def stop(self, join: bool = True) -> None:
        self._stop.set()
        with self._cv:
            self._cv.notify_all()
        if join and self._play_thread is not None:
            self._play_thread.join(timeout=5.0)

    def on_displacement(self, msg: PointCloud2) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        end_k = (stamp - self.t0_ns) // self.period_ns + int(msg.width)
        with self._cv:
            self._inflight.pop(stamp, None)
            # blocks stamped before this one will never be answered (dropped as late, or their node died)
            self._give_up([s for s in self._inflight if s < stamp], "the driver answered a later block")
            self._last_ack = time.monotonic()
            # the driver may have published samples of its own (stale ramp): never reuse their indices
            self.k_stream = max(self.k_stream, end_k) if end_k > 0 else self.k_stream
            self._cv.notify_all()

    def _give_up(self, stamps: list[int], why: str) -> None:
        """Lockstep (under ``_cv``): stop waiting for these blocks; counted, WARN, in ``~/state``."""
        if not stamps:
            return
        for s in stamps:
            self._inflight.pop(s, None)
        self.unanswered += len(stamps)
        self.get_logger().warning(f"lockstep: {len(stamps)} block(s) never answered ({why}), given up: "
                                  f"{self.unanswered} so far")
        self.state["unanswered_blocks"] = self.unanswered
        self.pub_state.publish(String(data=json.dumps(self.state)))

    def _expire(self, ack_timeout: float) -> None:
        now = time.monotonic()
        self._give_up([s for s, t in self._inflight.items() if now - t > ack_timeout],
                      f"no displacement within ack_timeout {ack_timeout} s")

    def _wait_graph(self, timeout: float, lockstep: bool) -> None:
        """Before playing: every block topic has ``min_subscribers`` readers (e.g. 2 = next node + recorder)."""
        need = int(self.param("min_subscribers"))
        deadline = time.monotonic() + timeout
        settle = False
        while not self._stop.is_set():
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

    def _set_state(self, state: str, **extra: Any) -> None:
        self.state = {"state": state, "mode": self._run_mode or self.param("mode"), "k": int(self.k_stream),
                      "unanswered_blocks": self.unanswered, **extra}
        self.pub_state.publish(String(data=json.dumps(self.state)))

    def _marker(self, name: str, k0: int, meta: dict[str, Any], k1: int | None = None) -> None:
        info = {"name": name, "k0": int(k0), "stamp_ns": int(self.t0_ns + k0 * self.period_ns),
                "stages": meta.get("stages"), **{k: v for k, v in meta.items() if k != "stages"}}
        if k1 is not None:   # the segment's own end: samples a clocked device holds after it are not part of it
            info["k1"] = int(k1)
        self.pub_exp.publish(String(data=json.dumps(info, default=str)))

    def _play(self) -> None:
        traj, fs = self._trajectory(), self.fs
        mode, n_blk, window = self.param("mode"), int(self.param("block_size")), int(self.param("window"))
        self._run_mode = mode
        preview = int(round(float(self.param("preview_s")) * self.fs))  # samples played ahead
        loop, timeout = bool(self.param("loop")), float(self.param("lockstep_timeout"))
        ack_timeout = float(self.param("ack_timeout"))
        total = traj.n_samples(fs)
        segs = traj.segments(fs) if isinstance(traj, Sequence) else []
        axes = list(traj.axes)
        blocks = 0
        try:
            self._wait_graph(timeout, mode == "lockstep")
            while True:
                with self._cv:
                    if mode == "realtime":  # stamps follow the wall clock (exact latency measurement)
                        self.k_stream = max(self.k_stream, (time.time_ns() - self.t0_ns) // self.period_ns)
                    start = self.k_stream
                self._set_state("playing", start=int(start), total=None if math.isinf(total) else int(total))
                k = 0
                next_wall = time.monotonic()
                seg_i = 0
                while (math.isinf(total) or k < total) and not self._stop.is_set():
                    n = n_blk if math.isinf(total) else int(min(n_blk, total - k))
                    while seg_i < len(segs) and segs[seg_i].start < k + n:
                        s = segs[seg_i]
                        self._marker(s.name, start + s.start, s.meta,
                                     None if math.isinf(s.stop) else start + int(s.stop))
                        seg_i += 1
                    block = traj.block(k + preview, n, fs)
                    kk = start + k
                    stamp = self.t0_ns + kk * self.period_ns
                    if mode == "realtime":
                        delay = next_wall - time.monotonic()
                        if delay > 0:
                            time.sleep(delay)
                        next_wall += n / fs
                    else:
                        with self._cv:
                            if not self._inflight:   # the timeout runs while something is in flight
                                self._last_ack = time.monotonic()
                            while len(self._inflight) >= window and not self._stop.is_set():
                                self._cv.wait(0.1)
                                self._expire(ack_timeout)
                                if time.monotonic() - self._last_ack > timeout:
                                    raise TimeoutError(f"lockstep: no displacement for {timeout} s "
                                                       "(is the driver running?)")
                            self._inflight[stamp] = time.monotonic()
                    self.pub_ref.publish(pack_block(block, axes, stamp))
                    with self._cv:
                        self.k_stream = max(self.k_stream, kk + n)
                    k += n
                    blocks += 1
                if mode == "lockstep":  # the run is finished when its last displacement came back
                    with self._cv:
                        self._last_ack = time.monotonic()
                        while self._inflight and not self._stop.is_set():
                            self._cv.wait(0.1)
                            self._expire(ack_timeout)
                            if time.monotonic() - self._last_ack > timeout:
                                raise TimeoutError(f"lockstep: {len(self._inflight)} block(s) never answered")
                if self._stop.is_set() or not loop:
                    break
            self._set_state("stopped" if self._stop.is_set() else "finished", blocks=blocks)
            self.get_logger().info(f"trajectory {self.state['state']}: {blocks} blocks")
        except TimeoutError as exc:
            self.get_logger().error(str(exc))
            with self._cv:
                self._inflight.clear()
            self._set_state("failed", error=str(exc), blocks=blocks)
        except Exception as exc:  # noqa: BLE001 - context shut down while stopping, or a bad trajectory
            if not self._stop.is_set():
                self.get_logger().error(f"trajectory: {exc}")
                try:
                    self._set_state("failed", error=str(exc), blocks=blocks)
                except Exception:  # noqa: BLE001
                    pass


def main(argv: list[str] | None = None) -> int:
    return run_node("trajectory", TrajectoryNode, lambda n: n.stop(), argv)


if __name__ == "__main__":
    sys.exit(main())
