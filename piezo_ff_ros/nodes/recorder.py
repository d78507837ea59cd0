"""Recorder node: raw (CDR) subscriptions to chosen topics written to MCAP in the rosbag2 format.

Uses :class:`piezo_ff_ros.core.recording.mcap_io.McapRecorder` (profile ``ros2``, ``ros2msg`` schemas with full
definitions, ``cdr`` messages, ``offered_qos_profiles`` + ``topic_type_hash`` per channel, Statistics, and a
``piezo_ff_ros`` Metadata record with the run configuration).  SIGINT/SIGTERM finish the file cleanly; a killed
recorder leaves a file readable up to its last flushed chunk (flushed at least every ``flush_interval`` s).

Parameters: ``output`` (file, default ``run_<UTC time>.mcap``), ``topics`` (default reference, voltage,
displacement, voltage_applied, experiment, /diagnostics, /parameter_events, compensator/config and the plotter's
plot_reference/voltage/displacement/error; relative names resolve in the node's namespace),
``config_file``/``variant`` (the PiezoConfig stored in the metadata), ``metadata`` (extra JSON object),
``flush_interval`` [s], ``discovery_period`` [s] (how often topics of unknown type are looked up in the graph),
``t0_ns`` and ``block_size`` (the run's sample origin [ns] and block size, written to the metadata; 0 = not given:
``t0_ns`` is then taken from the trajectory's first ``experiment`` marker, ``stamp_ns − k0·dt``, else from the
compensator's first configuration version, and ``block_size`` is left out).  Never from whatever block comes first:
a stray or hostile block must not set the run's origin.
Topic ``~/status`` (std_msgs/String, transient-local JSON: ``{"recording": path, "topics": {...}, "subscribed": [...],
"publishers": {topic: matched publisher count}, "error": null or why recording stopped}``, republished when a count
changes) lets a launcher wait until the recorder is actually connected to the publishers before a run starts.

A write that fails (disk full, file-size limit, I/O error) stops the recording, not the node: the file is ended at
its last complete chunk (readable by every MCAP reader, see :class:`~piezo_ff_ros.core.recording.mcap_io.
RecordingStopped`), one ERROR is logged and ``/diagnostics`` reports ERROR (every second from then on) with what was
kept and how many messages were dropped; the exit code at SIGINT is then 1 (the recording is incomplete).
"""
from __future__ import annotations

import importlib
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Sequence

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from ..core.config import load_config
from ..core.recording.blocks import MAX_BLOCK_SAMPLES, peek_block_samples, sample_period_ns
from ..core.recording.mcap_io import McapRecorder, RecordingStopped
from .common import CONFIG_QOS, LATCHED_QOS, RECORD_QOS, diag_values, run_node
from .params import refuse_unknown_parameters

DEFAULT_TOPICS = ["reference", "voltage", "displacement", "experiment", "/diagnostics", "/parameter_events",
                  "compensator/config", "voltage_applied",
                  # the plotter's decimated topics (nodes/plotter.py): a run.mcap opened in Foxglove plots them
                  "plot_reference", "plot_voltage", "plot_displacement", "plot_error"]
KNOWN_TYPES = {"reference": "sensor_msgs/msg/PointCloud2", "voltage": "sensor_msgs/msg/PointCloud2",
               "displacement": "sensor_msgs/msg/PointCloud2", "experiment": "std_msgs/msg/String",
               "joint_states": "sensor_msgs/msg/JointState", "reference_point": "geometry_msgs/msg/PointStamped",
               "diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
               "parameter_events": "rcl_interfaces/msg/ParameterEvent", "config": "std_msgs/msg/String",
               "voltage_applied": "sensor_msgs/msg/PointCloud2",
               **dict.fromkeys(("plot_reference", "plot_voltage", "plot_displacement", "plot_error"),
                               "geometry_msgs/msg/PointStamped")}
#: the experiment markers are transient-local: a recorder started late still gets the current segment
_LATCHED = {"experiment"}
#: chunks hold at most this many bytes of uncompressed records (docs/topics.md; McapRecorder's strict_chunks)
CHUNK_LIMIT = 512 * 1024
_EVENTS_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)


def message_class(type_name: str) -> Any:
    """``pkg/msg/Type`` → the Python message class."""
    pkg, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


def git_rev() -> str:
    """The checkout's commit (``unknown`` outside a git checkout)."""
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).resolve().parent, timeout=2,
                              capture_output=True, text=True).stdout.strip() or "unknown"
    except Exception:  # noqa: BLE001 - not a checkout
        return "unknown"


class RecorderNode(Node):
    """See the module docstring."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("recorder", **kwargs)
        default_out = time.strftime("run_%Y%m%dT%H%M%SZ.mcap", time.gmtime())
        out: str = self.declare_parameter("output", default_out).value
        topics: list[str] = list(self.declare_parameter("topics", DEFAULT_TOPICS).value)
        cfg_file: str = self.declare_parameter("config_file", "").value
        variant: str = self.declare_parameter("variant", "").value
        extra_text: str = self.declare_parameter("metadata", "{}").value
        flush = float(self.declare_parameter("flush_interval", 1.0).value)
        period = float(self.declare_parameter("discovery_period", 0.5).value)
        t0_param = int(self.declare_parameter("t0_ns", 0).value)
        block_size = int(self.declare_parameter("block_size", 0).value)
        refuse_unknown_parameters(self)   # every parameter declared; before the output file is created
        try:
            extra = json.loads(extra_text) if extra_text else {}
            if not isinstance(extra, dict):
                raise ValueError("not an object")
        except ValueError as exc:
            raise ValueError(f"metadata: expected a JSON object ({exc})") from None
        cfg = load_config(cfg_file or None, variant or None)
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        self.rec = McapRecorder(out, flush_interval=flush, chunk_size=CHUNK_LIMIT, strict_chunks=True)
        self.rec.set_metadata({"sample_rate": cfg.sample_rate, "axes": list(cfg.axes), "config_yaml": cfg.to_yaml(),
                               "config_name": cfg.name, "variant": cfg.variant, "git_rev": git_rev(),
                               "recorder": {"topics": topics, "started_ns": time.time_ns()},
                               **extra})
        self.node_parameters = {"recorder": {"output": str(out), "topics": topics, "config_file": cfg_file,
                                             "variant": variant, "flush_interval": flush}}
        self.rec.set_metadata({"parameters": self.node_parameters})
        self.period_ns = sample_period_ns(cfg.sample_rate)
        if t0_param < 0 or t0_param % self.period_ns:
            raise ValueError(f"t0_ns: {t0_param} is not a stamp on the {self.period_ns} ns sample grid")
        if not 0 <= block_size <= MAX_BLOCK_SAMPLES:
            raise ValueError(f"block_size: {block_size} is outside [0, {MAX_BLOCK_SAMPLES}] samples")
        self.t0_ns: int | None = None
        self.config_versions: list[dict] = []
        if block_size:
            self.rec.set_metadata({"block_size": block_size})
        if t0_param:
            self._set_t0(t0_param)
        self.topics = {self.resolve_topic_name(t): t for t in topics}
        self.types: dict[str, str] = {}
        self.subs: dict[str, Any] = {}
        self.counts: dict[str, int] = {}
        self._matched: dict[str, int] = {}
        self.error: str | None = None      # why recording stopped early
        self.dropped = 0                    # messages received after that
        self.oversized = 0                  # block messages too large for the contract (not recorded)
        self._oversized_logged = -1e9
        self.pub_status = self.create_publisher(String, "~/status", LATCHED_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._subscribe_known()
        self.create_timer(period, self._discover)
        self.get_logger().info(f"recording {sorted(self.topics)} to {out}")

    def _subscribe_known(self) -> None:
        for full, given in self.topics.items():
            tn = KNOWN_TYPES.get(full.rsplit("/", 1)[-1])
            if tn is not None:
                self._subscribe(full, tn)
        self._status()

    def _discover(self) -> None:
        matched = {t: s.get_publisher_count() for t, s in self.subs.items() if s is not None}
        if matched != self._matched:
            self._matched = matched
            self._status()
        missing = [t for t in self.topics if t not in self.subs]
        if not missing:
            return
        graph = dict(self.get_topic_names_and_types())
        for t in missing:
            if graph.get(t):
                self._subscribe(t, graph[t][0])
                self._status()

    def _subscribe(self, topic: str, type_name: str) -> None:
        try:
            cls = message_class(type_name)
        except (ImportError, AttributeError, ValueError) as exc:
            self.get_logger().error(f"{topic}: cannot record type {type_name} ({exc})")
            self.subs[topic] = None
            return
        last = topic.rsplit("/", 1)[-1]
        qos = LATCHED_QOS if last in _LATCHED else (_EVENTS_QOS if last == "parameter_events" else RECORD_QOS)
        if type_name == "std_msgs/msg/String" and last == "config":
            qos = CONFIG_QOS
        self.types[topic] = type_name
        self.counts[topic] = 0
        self.subs[topic] = self.create_subscription(
            cls, topic, lambda data, info, t=topic: self._on_message(t, data, info), qos, raw=True)

    def _on_message(self, topic: str, data: bytes, info: Any) -> None:
        if self.error is not None:
            self.dropped += 1
            return
        if self.types.get(topic) == "sensor_msgs/msg/PointCloud2" and \
                (peek_block_samples(data) or 0) > MAX_BLOCK_SAMPLES:   # read from the first bytes: no work
            self.oversized += 1   # more than any block of the contract: not written (it would bloat the file)
            now = time.monotonic()
            if now - self._oversized_logged > 1.0:
                self._oversized_logged = now
                self.get_logger().error(f"{topic}: a block of {peek_block_samples(data)} samples is larger than "
                                        f"any block of the contract ({MAX_BLOCK_SAMPLES}): not recorded "
                                        f"({self.oversized} so far)")
            return
        try:
            self._record(topic, data, info)
        except RecordingStopped as exc:
            self._stopped(exc)

    def _stopped(self, exc: RecordingStopped) -> None:
        """Writing failed: the file is already ended (readable); say so once, then every second on /diagnostics."""
        self.error = f"recording stopped: {exc}"
        self.get_logger().error(self.error)
        self._status()
        self._publish_error()
        self.create_timer(1.0, self._publish_error)

    def _publish_error(self) -> None:
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        values = {"recording": str(self.rec.path), **self.rec.failure, "dropped_after_stop": self.dropped,
                  **{f"count.{t}": n for t, n in self.counts.items()}}
        arr.status = [DiagnosticStatus(level=DiagnosticStatus.ERROR, name=self.get_fully_qualified_name(),
                                       message=self.error or "", hardware_id="recorder", values=diag_values(values))]
        self.pub_diag.publish(arr)

    def _record(self, topic: str, data: bytes, info: Any) -> None:
        now = time.time_ns()
        if topic not in self.rec.topics:
            offered = [p.qos_profile for p in self.get_publishers_info_by_topic(topic)]
            self.rec.register_topic(topic, self.types[topic], offered)
        src = info.get("source_timestamp") if isinstance(info, dict) else getattr(info, "source_timestamp", None)
        self.rec.write(topic, data, log_time_ns=now, publish_time_ns=src or now)
        self.counts[topic] += 1
        last = topic.rsplit("/", 1)[-1]
        try:
            if last == "config" and self.types.get(topic) == "std_msgs/msg/String":
                self._config_version(data)
            elif last == "experiment" and self.t0_ns is None and self.types.get(topic) == "std_msgs/msg/String":
                self._t0_from_marker(data)
        except RecordingStopped:
            raise
        except Exception as exc:  # noqa: BLE001 - metadata is best effort; the message itself is recorded
            self.get_logger().warning(f"{topic}: metadata not updated ({exc})")

    def _set_t0(self, t0_ns: int) -> None:
        """The run's sample origin: written to the metadata, the configuration versions' ``k0`` from it."""
        self.t0_ns = int(t0_ns)
        self.rec.set_metadata({"t0_ns": self.t0_ns})
        for v in self.config_versions:
            v["k0"] = (v["stamp_ns"] - self.t0_ns) // self.period_ns
        if self.config_versions:
            self.rec.set_metadata({"config_versions": self.config_versions})

    def _t0_from_marker(self, data: bytes) -> None:
        """``t0_ns = stamp_ns − k0·dt`` of the trajectory's first experiment marker (the trajectory's own origin)."""
        from rclpy.serialization import deserialize_message

        d = json.loads(deserialize_message(data, String).data)
        k0, stamp = d.get("k0"), d.get("stamp_ns")
        if isinstance(k0, int) and isinstance(stamp, int) and not isinstance(k0, bool) and k0 >= 0 \
                and stamp % self.period_ns == 0:
            self._set_t0(stamp - k0 * self.period_ns)

    def _config_version(self, data: bytes) -> None:
        """A configuration version of the compensator (``~/config``): stored with the sample index where it took
        effect; ``config_yaml`` becomes the live configuration's (first version), ``parameters`` the node's."""
        from rclpy.serialization import deserialize_message

        d = json.loads(deserialize_message(data, String).data)
        entry = {"version": d["version"], "stamp_ns": d["stamp_ns"],
                 "k0": None if self.t0_ns is None else (d["stamp_ns"] - self.t0_ns) // self.period_ns,
                 "config_yaml": d["config_yaml"], "parameters": d.get("parameters", {})}
        if self.t0_ns is None and entry["version"] == 1 and isinstance(entry["stamp_ns"], int) \
                and entry["stamp_ns"] % self.period_ns == 0:   # no parameter, no marker: the compensator's origin
            self.t0_ns = int(entry["stamp_ns"])
            self.rec.set_metadata({"t0_ns": self.t0_ns})
            entry["k0"] = 0
        self.config_versions = [v for v in self.config_versions if v["version"] != entry["version"]] + [entry]
        self.config_versions.sort(key=lambda v: v["version"])
        meta: dict[str, Any] = {"config_versions": self.config_versions}
        if len(self.config_versions) == 1 or entry["version"] == min(v["version"] for v in self.config_versions):
            meta["config_yaml"] = entry["config_yaml"]
            self.node_parameters["compensator"] = entry["parameters"]
            meta["parameters"] = self.node_parameters
        self.rec.set_metadata(meta)

    def _status(self) -> None:
        self.pub_status.publish(String(data=json.dumps({"recording": str(self.rec.path),
                                                        "topics": {t: self.types.get(t) for t in self.topics},
                                                        "subscribed": sorted(t for t, s in self.subs.items() if s),
                                                        "publishers": self._matched, "error": self.error})))

    def finish(self) -> None:
        """Close the recording; RuntimeError (exit code 1) when it stopped early (disk full, I/O error)."""
        if not self.rec.closed:
            try:
                self.rec.close()
            except RecordingStopped as exc:
                self.error = f"recording stopped: {exc}"
            if self.error is None:
                size = self.rec.path.stat().st_size if self.rec.path.exists() else 0
                print(f"recorder: wrote {self.rec.message_count} messages ({size} bytes) to {self.rec.path}: "
                      + ", ".join(f"{t} {n}" for t, n in sorted(self.counts.items()))
                      + (f"; {self.oversized} oversized block message(s) not recorded" if self.oversized else ""),
                      file=sys.stderr)
        if self.error is not None:   # exit code 1 (run_node), one line: the recording is incomplete
            f = self.rec.failure
            raise RuntimeError(f"{self.error}; {self.dropped} message(s) received afterwards dropped"
                               if f else self.error)


def main(argv: Sequence[str] | None = None) -> int:
    """``ros2 run piezo_ff_ros recorder``."""
    return run_node("recorder", RecorderNode, lambda n: n.finish(), argv)


if __name__ == "__main__":
    sys.exit(main())
