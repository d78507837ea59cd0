"""MCAP in the rosbag2 format, without ROS: the recorder's writer and the replay reader.

Writing (:class:`McapRecorder`) produces what rosbag2's MCAP storage plugin writes, so ``ros2 bag info/play``,
Foxglove and ``rosbags`` open the file: header profile ``ros2``; one Schema per type, encoding ``ros2msg``, the full
definition text built like rosbag2's ``LocalMessageDefinitionSource`` from the ``.msg`` files shipped with the ROS
wheels (dependencies appended, sorted, depth-first, each once); Channels with message encoding ``cdr`` and metadata
``offered_qos_profiles`` (YAML, rosbag2 v9 string form) and ``topic_type_hash`` (RIHS01); ZSTD chunks; the Statistics
record; plus a Metadata record ``piezo_ff_ros`` holding the run configuration.  Chunks are small and flushed at
least every ``flush_interval`` seconds, so a killed recorder leaves a file that :func:`scan_mcap` reads up to its
last complete chunk.

Reading (:func:`read_run`) reassembles the contract's block topics (``reference``, ``voltage``, ``displacement``:
``sensor_msgs/msg/PointCloud2`` tables, see :mod:`.blocks`) into sample-aligned arrays by sample index, from our
recordings or any other ROS 2 MCAP writer (``rosbags`` bare ``.mcap``, a rosbag2 directory with ``metadata.yaml``).
"""
from __future__ import annotations

import json
import mmap
import os
import re
import struct
import sys
import threading
import time
from collections import Counter, defaultdict, deque
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping, Sequence

import numpy as np

from .blocks import BLOCK_TYPE, deserialize_block, deserialize_message, sample_period_ns
from .importers import canonical_axes
from .run import RunData

__all__ = [
    "METADATA_NAME", "BLOCK_ROLES", "ros2msg_definition", "type_hash", "qos_profiles_yaml", "block_qos_profile",
    "McapRecorder", "RecordingStopped", "McapContents", "scan_mcap", "iter_mcap_records", "read_run",
]

METADATA_NAME = "piezo_ff_ros"  #: name of the MCAP Metadata record holding the run configuration
BLOCK_ROLES = ("reference", "voltage", "displacement")  #: block topics by their last name component
EXPERIMENT_TYPE = "std_msgs/msg/String"
DIAGNOSTICS_TYPE = "diagnostic_msgs/msg/DiagnosticArray"
_PRIMITIVES = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32", "uint32",
               "int64", "uint64", "string", "wstring"}
# rosbag2's MSG_FIELD_TYPE_REGEX (rosbag2_storage_mcap/message_definition_encoding): the type of each field line
_FIELD_TYPE_RE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:<=[0-9]+)?(?:\[[^\]]*\])?\s+")
_DELIMITER = "=" * 80


# ----------------------------------------------------------------------------------------------------------------
# schema text and type hash, as rosbag2 builds them

def _share_dirs() -> list[Path]:
    dirs = [Path(sys.prefix) / "share"]
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            dirs.append(Path(prefix) / "share")
    return dirs


def _split_type(type_name: str) -> tuple[str, str]:
    parts = type_name.split("/")
    if len(parts) == 3 and parts[1] == "msg":
        return parts[0], parts[2]
    if len(parts) == 2:
        return parts[0], parts[1]
    raise ValueError(f"{type_name!r}: not a message type name (expected 'pkg/msg/Type')")


def _interface_file(type_name: str, suffix: str) -> Path | None:
    pkg, name = _split_type(type_name)
    for share in _share_dirs():
        p = share / pkg / "msg" / f"{name}{suffix}"
        if p.is_file():
            return p
    return None


@lru_cache(maxsize=None)
def _msg_text(type_name: str) -> str:
    p = _interface_file(type_name, ".msg")
    if p is not None:
        return p.read_text()
    # not installed as a ROS package here: fall back to rosbags' canonical text for the standard types
    from .blocks import typestore

    ts = typestore()
    full = f"{_split_type(type_name)[0]}/msg/{_split_type(type_name)[1]}"
    if full not in ts.types:
        raise ValueError(f"{type_name}: no .msg file under {[str(d) for d in _share_dirs()]} and not a known type")
    return ts.generate_msgdef(full, ros_version=2)[0].split("\n" + _DELIMITER)[0]


def _msg_dependencies(text: str, package: str) -> list[str]:
    deps = set()
    for match in _FIELD_TYPE_RE.finditer(text):
        t = match.group(1)
        if t in _PRIMITIVES:
            continue
        deps.add(t if "/" in t else f"{package}/{t}")
    return sorted(deps)


@lru_cache(maxsize=None)
def ros2msg_definition(type_name: str) -> str:
    """Full ``ros2msg`` schema text of ``type_name``, as rosbag2's ``LocalMessageDefinitionSource`` builds it.

    The type's ``.msg`` text, then for each dependency (sorted, depth-first, each once)
    ``"\\n" + "="*80 + "\\nMSG: pkg/Type\\n" + <its .msg text>``.
    """
    pkg, name = _split_type(type_name)
    seen: set[str] = set()

    def append(dep_pkg: str, dep_name: str) -> str:
        text = _msg_text(f"{dep_pkg}/msg/{dep_name}")
        out = text
        for dep in _msg_dependencies(text, dep_pkg):
            if dep not in seen:
                seen.add(dep)
                dpkg, dname = _split_type(dep)
                out += f"\n{_DELIMITER}\nMSG: {dpkg}/{dname}\n" + append(dpkg, dname)
        return out

    return append(pkg, name)


@lru_cache(maxsize=None)
def type_hash(type_name: str) -> str:
    """The type's RIHS01 hash (``RIHS01_…``) from the wheel's ``<Type>.json`` (else computed by rosbags)."""
    p = _interface_file(type_name, ".json")
    if p is not None:
        return json.loads(p.read_text())["type_hashes"][0]["hash_string"]
    from .blocks import typestore

    pkg, name = _split_type(type_name)
    return typestore().hash_rihs01(f"{pkg}/msg/{name}")


# ----------------------------------------------------------------------------------------------------------------
# QoS profiles in rosbag2's v9 YAML string form

_UNSPECIFIED = {"sec": 0, "nsec": 0}


def block_qos_profile(depth: int = 100) -> dict:
    """The contract's QoS for block topics (RELIABLE, KEEP_LAST ``depth``, VOLATILE), as a rosbag2 v9 dict."""
    return {"history": "keep_last", "depth": int(depth), "reliability": "reliable", "durability": "volatile",
            "deadline": dict(_UNSPECIFIED), "lifespan": dict(_UNSPECIFIED), "liveliness": "automatic",
            "liveliness_lease_duration": dict(_UNSPECIFIED), "avoid_ros_namespace_conventions": False}


def _policy_name(value) -> str:
    if isinstance(value, str):
        return value.lower()
    name = getattr(value, "name", None)  # rclpy QoS*Policy enums
    if name is None:
        raise ValueError(f"QoS policy {value!r}: expected a name")
    return str(name).lower()


def _duration(value) -> dict:
    if value is None:
        return dict(_UNSPECIFIED)
    if isinstance(value, Mapping):
        return {"sec": int(value["sec"]), "nsec": int(value["nsec"])}
    ns = getattr(value, "nanoseconds", None)  # rclpy.duration.Duration
    if ns is None:
        ns = int(value)
    sec, nsec = divmod(int(ns), 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


def _qos_dict(profile) -> dict:
    get = (lambda k, d=None: profile.get(k, d)) if isinstance(profile, Mapping) else \
        (lambda k, d=None: getattr(profile, k, d))
    return {
        "history": _policy_name(get("history", "keep_last")),
        "depth": int(get("depth", 0)),
        "reliability": _policy_name(get("reliability", "reliable")),
        "durability": _policy_name(get("durability", "volatile")),
        "deadline": _duration(get("deadline")),
        "lifespan": _duration(get("lifespan")),
        "liveliness": _policy_name(get("liveliness", "automatic")),
        "liveliness_lease_duration": _duration(get("liveliness_lease_duration")),
        "avoid_ros_namespace_conventions": bool(get("avoid_ros_namespace_conventions", False)),
    }


def qos_profiles_yaml(profiles: Iterable | None) -> str:
    """Offered QoS profiles (dicts or rclpy ``QoSProfile``-like objects) → rosbag2's v9 YAML string."""
    import yaml

    items = [_qos_dict(p) for p in (profiles or [])]
    return yaml.safe_dump(items, sort_keys=False, default_flow_style=False) if items else "[]"


# ----------------------------------------------------------------------------------------------------------------
# writer

class RecordingStopped(OSError):
    """Writing failed (disk full, file-size limit, I/O error): the recorder ended the file at its last durable
    record boundary (readable by every MCAP reader) and accepts nothing more.  ``info`` says what was kept."""

    def __init__(self, text: str, info: dict):
        super().__init__(text)
        self.info = info


def _metadata_value(v) -> str:
    if isinstance(v, str):
        return v
    return json.dumps(v, default=str)


class McapRecorder:
    """Write ROS 2 MCAP (rosbag2 profile) from raw CDR messages; thread-safe.

    Parameters
    ----------
    path
        Output ``.mcap`` file (created; an existing file is overwritten).
    chunk_size
        Uncompressed chunk size [bytes] at which a chunk is compressed and written (default 512 KiB: ~0.5 s of
        the 3 block topics at 20 kHz, 2 axes).
    flush_interval
        A chunk is also closed and the file flushed when the oldest unflushed message is older than this [s]
        (wall clock), so that a killed recorder loses at most about this much.  ``None`` disables.
    compression
        ``"zstd"`` (default), ``"lz4"`` or ``"none"``.
    metadata
        Optional initial run configuration, written at once as the ``piezo_ff_ros`` Metadata record.

    Examples
    --------
    >>> rec = McapRecorder("run.mcap")                                                      # doctest: +SKIP
    >>> rec.register_topic("/displacement", "sensor_msgs/msg/PointCloud2", [block_qos_profile()])  # doctest: +SKIP
    >>> rec.write("/displacement", raw_cdr, log_time_ns=time.time_ns())                     # doctest: +SKIP
    >>> rec.close()                                                                         # doctest: +SKIP
    """

    def __init__(self, path, *, chunk_size: int = 512 * 1024, flush_interval: float | None = 1.0,
                 compression: str = "zstd", metadata: Mapping | None = None, library: str | None = None):
        from mcap.writer import CompressionType, Writer

        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        if compression not in comp:
            raise ValueError(f"compression: {compression!r} not one of {sorted(comp)}")
        if int(chunk_size) < 1024:
            raise ValueError(f"chunk_size: {chunk_size} bytes is too small (≥ 1024)")
        self.path = Path(path)
        self._file = open(self.path, "wb")
        self._writer = Writer(self._file, chunk_size=int(chunk_size), compression=comp[compression])
        if library is None:
            from importlib.metadata import PackageNotFoundError, version

            try:
                library = f"piezo_ff_ros {version('piezo_ff_ros')}; mcap"
            except PackageNotFoundError:
                library = "piezo_ff_ros; mcap"
        self._writer.start(profile="ros2", library=library)
        self._file.flush()
        self._lock = threading.Lock()
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}
        self._sequence: Counter = Counter()
        self._metadata: dict[str, str] = {}
        self._flush_interval = flush_interval
        self._unflushed_since: float | None = None
        self._last_pos = self._file.tell()
        self.message_count = 0
        self.bytes_in = 0
        self.closed = False
        #: why writing stopped early (None while all is well); then ``failure`` holds what was kept
        self.failed: str | None = None
        self.failure: dict = {}
        # record boundaries known to be on disk, with the message count up to each: where a failed file is cut
        self._durable: deque[tuple[int, int]] = deque([(self._file.tell(), 0)], maxlen=32)
        if metadata:
            self.set_metadata(metadata)

    # -- API used by the recorder node --------------------------------------------------------------------------
    def register_topic(self, topic: str, type_name: str, qos_profiles: Iterable | None = None) -> int:
        """Declare ``topic`` of ``type_name`` (``pkg/msg/Type``); returns its channel id (idempotent).

        ``qos_profiles``: the publishers' offered profiles (rclpy ``QoSProfile``-like objects from
        ``node.get_publishers_info_by_topic(topic)[i].qos_profile``, or dicts such as :func:`block_qos_profile`).
        """
        with self._lock:
            self._check_open()
            if topic in self._channels:
                cid, known = self._channels[topic]
                if known != type_name:
                    raise ValueError(f"topic {topic}: already registered as {known}, not {type_name}")
                return cid
            sid = self._schemas.get(type_name)
            if sid is None:
                sid = self._writer.register_schema(name=type_name, encoding="ros2msg",
                                                   data=ros2msg_definition(type_name).encode())
                self._schemas[type_name] = sid
            cid = self._writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=sid,
                metadata={"offered_qos_profiles": qos_profiles_yaml(qos_profiles),
                          "topic_type_hash": type_hash(type_name)})
            self._channels[topic] = (cid, type_name)
            return cid

    def write(self, topic: str, raw_cdr: bytes, log_time_ns: int, publish_time_ns: int | None = None) -> None:
        """Append one CDR-serialised message (with its 4-byte encapsulation header) to a registered topic."""
        with self._lock:
            self._check_open()
            try:
                cid = self._channels[topic][0]
            except KeyError:
                raise ValueError(f"topic {topic}: not registered (call register_topic first)") from None
            self._sequence[cid] += 1
            data = bytes(raw_cdr)
            try:
                self._writer.add_message(channel_id=cid, log_time=int(log_time_ns), data=data,
                                         publish_time=int(log_time_ns if publish_time_ns is None
                                                          else publish_time_ns),
                                         sequence=self._sequence[cid] & 0xFFFFFFFF)
                self.message_count += 1
                self.bytes_in += len(data)
                self._maybe_flush()
            except OSError as exc:
                self._stop_on_error(exc)

    def set_metadata(self, metadata: Mapping[str, Any]) -> None:
        """Record run configuration (merged with earlier calls) as the ``piezo_ff_ros`` Metadata record.

        Values that are not strings are stored as JSON.  Written immediately (readers merge successive records,
        later keys win), so a killed recorder keeps it.  Suggested keys: ``sample_rate``, ``t0_ns``, ``axes``,
        ``block_size``, ``config_yaml``, ``parameters``, ``git_rev``.
        """
        with self._lock:
            self._check_open()
            new = {str(k): _metadata_value(v) for k, v in metadata.items()}
            self._metadata.update(new)
            try:
                self._writer.add_metadata(METADATA_NAME, new)
                self._file.flush()
                self._mark_durable()
            except OSError as exc:
                self._stop_on_error(exc)

    def flush(self) -> None:
        """Close the open chunk and flush the file (the data so far survives a crash)."""
        with self._lock:
            if not self.closed:
                try:
                    self._writer.flush()
                    self._mark_durable()
                except OSError as exc:
                    self._stop_on_error(exc)
                self._unflushed_since = None
                self._last_pos = self._file.tell()

    def close(self) -> None:
        """Finish the file (summary, Statistics, footer) and close it; idempotent."""
        with self._lock:
            if self.closed:
                return
            try:
                self._writer.finish()
                self._file.flush()
            except OSError as exc:
                self._stop_on_error(exc)
            self.closed = True
            self._file.close()

    # -- helpers -------------------------------------------------------------------------------------------------
    @property
    def topics(self) -> dict[str, str]:
        """Registered topics → type names."""
        return {t: tn for t, (_, tn) in self._channels.items()}

    def _check_open(self):
        if self.failed is not None:
            raise RecordingStopped(f"{self.path}: recording stopped ({self.failed})", self.failure)
        if self.closed:
            raise ValueError(f"{self.path}: recorder already closed")

    def _mark_durable(self) -> None:
        """After a successful flush: the file up to here is on disk and ends on a record boundary."""
        pos = self._file.tell()
        if pos != self._durable[-1][0]:
            self._durable.append((pos, self.message_count))

    def _stop_on_error(self, exc: OSError) -> None:
        """A write failed (disk full, file-size limit, I/O error): end the file cleanly and raise
        :class:`RecordingStopped`.

        The bytes after the last durable record boundary (a chunk cut short, the writer's buffer) are dropped:
        the file is truncated there and ended with a DataEnd and a Footer without summary section — valid MCAP that
        the ``mcap`` and ``rosbags`` readers open (they read it linearly) and that ``piezo-ff recover`` can re-index
        elsewhere.  Truncation frees the room the ending needs; if even that does not fit, an earlier boundary is
        tried.  The open Python file is never flushed again (its descriptor is pointed at /dev/null first).
        """
        from mcap.data_stream import RecordBuilder
        from mcap.records import DataEnd, Footer

        reason = exc.strerror or str(exc)
        fd = self._file.fileno()
        null = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(null, fd)          # the buffered writer's leftovers go nowhere, never after our footer
        finally:
            os.close(null)
        b = RecordBuilder()
        DataEnd(0).write(b)
        Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(b)
        ending = b.end() + b"\x89MCAP0\r\n"
        kept = None
        out = os.open(self.path, os.O_WRONLY)
        try:
            for pos, count in reversed(self._durable):
                try:
                    os.ftruncate(out, pos)
                    if os.pwrite(out, ending, pos) == len(ending):
                        kept = (pos, count)
                        break
                except OSError:
                    continue
        finally:
            os.close(out)
        self.closed = True
        try:
            self._file.close()
        except OSError:
            pass
        self.failed = reason
        if kept is None:
            self.failure = {"reason": reason, "readable": False, "kept_bytes": 0, "kept_messages": 0,
                            "lost_messages": self.message_count}
        else:
            self.failure = {"reason": reason, "readable": True, "kept_bytes": kept[0] + len(ending),
                            "kept_messages": kept[1], "lost_messages": self.message_count - kept[1]}
        where = (f"ended at {self.failure['kept_bytes']} bytes with {self.failure['kept_messages']} messages "
                 f"(the last complete chunk), readable" if kept else "could not be ended: use piezo-ff recover")
        raise RecordingStopped(f"{self.path}: write failed ({reason}): {where}; "
                               f"{self.failure['lost_messages']} message(s) written after it lost", self.failure)

    def _maybe_flush(self):
        pos = self._file.tell()
        if pos != self._last_pos:  # the writer has just written a full chunk: push it to the OS now
            self._file.flush()
            self._mark_durable()
            self._last_pos = pos
            self._unflushed_since = None
            return
        now = time.monotonic()
        if self._unflushed_since is None:
            self._unflushed_since = now
        if self._flush_interval is not None and now - self._unflushed_since >= self._flush_interval:
            self._writer.flush()
            self._mark_durable()
            self._last_pos = self._file.tell()
            self._unflushed_since = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


# ----------------------------------------------------------------------------------------------------------------
# reader: records of one or more MCAP files, robust to truncation

@dataclass
class McapContents:
    """Everything read from an MCAP file (or a rosbag2 directory): topics, raw messages, metadata.

    ``messages[topic]`` is a list of ``(log_time_ns, publish_time_ns, raw_cdr)`` in file order.
    ``truncated`` is set (with ``error``) when the data ended early or was corrupt after a readable prefix.
    """

    source: str
    profile: str = ""
    library: str = ""
    topics: dict = field(default_factory=dict)  # topic -> type name
    encodings: dict = field(default_factory=dict)  # topic -> message encoding
    channel_metadata: dict = field(default_factory=dict)  # topic -> channel metadata
    messages: dict = field(default_factory=lambda: defaultdict(list))
    metadata: list = field(default_factory=list)  # [(name, {k: v})] in file order
    statistics: Any = None
    truncated: bool = False
    error: str | None = None
    files: list = field(default_factory=list)
    losses: list = field(default_factory=list)  # per file: what could not be read (see iter_mcap_records)

    def loss_summary(self) -> dict:
        """What could not be read, summed over the files: chunk/message/byte counts and lost log-time ranges."""
        out = {"chunks_total": 0, "chunks_lost": 0, "messages_lost": 0, "bytes_skipped": 0, "records_skipped": 0,
               "orphan_messages": 0, "lost_time_ranges_ns": [], "messages_lost_by_topic": {}, "truncated": False,
               "errors": []}
        for loss in self.losses:
            for key in ("chunks_total", "chunks_lost", "messages_lost", "bytes_skipped", "records_skipped",
                        "orphan_messages"):
                out[key] += loss[key]
            out["lost_time_ranges_ns"] += loss["lost_time_ranges_ns"]
            out["errors"] += loss["errors"]
            out["truncated"] |= loss["truncated"]
            for t, k in loss["messages_lost_by_topic"].items():
                out["messages_lost_by_topic"][t] = out["messages_lost_by_topic"].get(t, 0) + k
        return out

    def metadata_record(self, name: str = METADATA_NAME) -> dict:
        """The Metadata records called ``name``, merged in file order (later keys win)."""
        out: dict = {}
        for n, d in self.metadata:
            if n == name:
                out.update(d)
        return out


_MCAP_MAGIC = b"\x89MCAP0\r\n"
_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_MESSAGE_INDEX = 1, 2, 3, 4, 5, 6, 7
_OP_DATA_END = 0x0F
_COMPRESSIONS = (b"", b"lz4", b"zstd")
_MAX_RANGES = 50  # lost time ranges listed individually (the counts are always complete)


def _new_loss() -> dict:
    """The reader's account of what it could not read (every count is a lower bound on what was lost)."""
    return {"chunks_total": 0, "chunks_lost": 0, "messages_lost": 0, "messages_lost_by_channel": Counter(),
            "lost_time_ranges_ns": [], "bytes_skipped": 0, "records_skipped": 0, "orphan_messages": 0,
            "truncated": False, "footer": False, "errors": []}


def _plausible_opcode(op: int) -> bool:
    # 0x01–0x0F are the spec's records, 0x80–0xFF user records; 0x00 and 0x10–0x7F are reserved: damage
    return 0x01 <= op <= 0x0F or op >= 0x80


def _chunk_header_at(buf, pos: int) -> tuple[int, int, int] | None:
    """If a complete, self-consistent Chunk record starts at ``pos``: (total length, start_time, end_time)."""
    n = len(buf)
    if pos + 9 + 40 > n or buf[pos] != _OP_CHUNK:
        return None
    length = struct.unpack_from("<Q", buf, pos + 1)[0]
    if pos + 9 + length > n:
        return None
    t_start, t_end, _usize, _crc, clen = struct.unpack_from("<QQQII", buf, pos + 9)
    if clen not in (0, 3, 4) or t_end < t_start:
        return None
    if bytes(buf[pos + 9 + 32:pos + 9 + 32 + clen]) not in _COMPRESSIONS:
        return None
    (dlen,) = struct.unpack_from("<Q", buf, pos + 9 + 32 + clen)
    if 32 + clen + 8 + dlen != length:
        return None
    return 9 + length, t_start, t_end


def _find_next_chunk(buf, start: int) -> int | None:
    """Offset of the next complete Chunk record at or after ``start`` (resynchronisation after damaged framing)."""
    i = start
    while True:
        i = buf.find(b"\x06", i)
        if i < 0:
            return None
        if _chunk_header_at(buf, i) is not None:
            return i
        i += 1


def _partial_chunk_times(buf, pos: int) -> tuple[int, int] | None:
    if pos + 9 + 16 <= len(buf) and buf[pos] == _OP_CHUNK:
        t0, t1 = struct.unpack_from("<QQ", buf, pos + 9)
        if t0 <= t1:
            return int(t0), int(t1)
    return None


def _lose_chunk(loss: dict, times: tuple[int, int] | None, why: str) -> None:
    loss["chunks_lost"] += 1
    if times is not None and len(loss["lost_time_ranges_ns"]) < _MAX_RANGES:
        loss["lost_time_ranges_ns"].append([int(times[0]), int(times[1])])
    if len(loss["errors"]) < _MAX_RANGES:
        loss["errors"].append(why)


def iter_mcap_records(path, loss: dict | None = None) -> Iterator:
    """Every record of an MCAP file, in file order, with the records inside chunks expanded; damage-tolerant.

    Unlike ``mcap``'s stream reader, which stops at the first bad record, this walks the top-level records
    itself: a chunk whose payload fails its CRC or decompression is skipped (the MessageIndex records after it
    give the count of messages lost per channel, its header the log-time range); damaged framing (an absurd
    record length, a reserved opcode) is skipped up to the next self-consistent Chunk record; a file that ends
    inside a record (a killed writer) ends the walk.  Everything skipped is accounted in ``loss`` (see
    :func:`_new_loss`).  Raises ``ValueError`` if the file does not start with the MCAP magic.
    """
    from io import BytesIO

    from mcap.data_stream import ReadDataStream
    from mcap.records import (Attachment, Channel, Chunk, Footer, Header, Message, MessageIndex, Metadata, Schema,
                              Statistics)
    from mcap.stream_reader import breakup_chunk

    parsers = {_OP_HEADER: Header.read, _OP_FOOTER: Footer.read, _OP_SCHEMA: Schema.read,
               _OP_CHANNEL: Channel.read, _OP_CHUNK: Chunk.read, _OP_MESSAGE_INDEX: MessageIndex.read,
               0x09: Attachment.read, 0x0B: Statistics.read, 0x0C: Metadata.read}
    loss = _new_loss() if loss is None else loss
    path = Path(path)
    with open(path, "rb") as f:
        try:
            buf = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        except ValueError:  # empty file
            buf = b""
    try:
        if bytes(buf[:len(_MCAP_MAGIC)]) != _MCAP_MAGIC:
            raise ValueError(f"{path}: not an MCAP file (bad magic {bytes(buf[:8])!r})")
        n, pos, after_lost_chunk = len(buf), len(_MCAP_MAGIC), False
        while True:
            if pos + 9 > n:
                loss["truncated"] = True
                if pos < n:
                    loss["errors"].append(f"{n - pos} trailing byte(s) at offset {pos}: a record cut short")
                break
            op = buf[pos]
            (length,) = struct.unpack_from("<Q", buf, pos + 1)
            end = pos + 9 + length
            if not _plausible_opcode(op) or end > n:
                nxt = _find_next_chunk(buf, pos + 1)
                times = _partial_chunk_times(buf, pos)
                if nxt is None:
                    loss["truncated"] = True
                    if op == _OP_CHUNK:
                        _lose_chunk(loss, times, f"offset {pos}: the last chunk is cut short "
                                                 f"({n - pos} of {9 + length} bytes on disk)")
                    else:
                        loss["bytes_skipped"] += n - pos
                        loss["errors"].append(f"offset {pos}: damaged or cut-short record (opcode {op:#04x}, "
                                              f"length {length}); {n - pos} byte(s) to the end unreadable")
                    break
                loss["bytes_skipped"] += nxt - pos
                _lose_chunk(loss, times if op == _OP_CHUNK else None,
                            f"offset {pos}: damaged record framing (opcode {op:#04x}, length {length}); "
                            f"{nxt - pos} byte(s) skipped to the next chunk")
                after_lost_chunk = False  # what was lost there cannot be counted
                pos = nxt
                continue
            parse = parsers.get(op)
            if op == _OP_MESSAGE:
                parse = lambda s, _n=length: Message.read(s, _n)  # noqa: E731
            if op != _OP_MESSAGE_INDEX:
                after_lost_chunk = False
            if parse is None:  # DataEnd, indexes, summary offsets, user records: nothing to read in them
                pos = end
                continue
            try:
                rec = parse(ReadDataStream(BytesIO(buf[pos + 9:end])))
            except Exception as exc:  # noqa: BLE001 - struct/unicode errors of a damaged record
                if op == _OP_CHUNK:
                    loss["chunks_total"] += 1
                    _lose_chunk(loss, _partial_chunk_times(buf, pos), f"offset {pos}: unreadable chunk header "
                                                                       f"({type(exc).__name__})")
                    after_lost_chunk = True
                else:
                    loss["records_skipped"] += 1
                    loss["errors"].append(f"offset {pos}: unreadable record (opcode {op:#04x}, "
                                          f"{type(exc).__name__})")
                pos = end
                continue
            pos = end
            if op == _OP_CHUNK:
                loss["chunks_total"] += 1
                try:
                    inner = breakup_chunk(rec, validate_crc=True)
                except Exception as exc:  # noqa: BLE001 - CRC mismatch, zstd/lz4 errors, records cut inside
                    _lose_chunk(loss, (rec.message_start_time, rec.message_end_time),
                                f"offset {pos - 9 - length}: corrupt chunk ({type(exc).__name__}: {exc})"[:300])
                    after_lost_chunk = True
                    continue
                yield from inner
            elif op == _OP_MESSAGE_INDEX:
                if after_lost_chunk:
                    loss["messages_lost"] += len(rec.records)
                    loss["messages_lost_by_channel"][rec.channel_id] += len(rec.records)
            else:
                yield rec
                if op == _OP_FOOTER:
                    loss["footer"] = True
                    break
    finally:
        if isinstance(buf, mmap.mmap):
            buf.close()


def _scan_one(path: Path, out: McapContents) -> None:
    from mcap.records import Channel, Header, Message, Metadata, Schema, Statistics

    loss = _new_loss()
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    by_channel: dict[int, list] = defaultdict(list)
    n_messages = 0
    for rec in iter_mcap_records(path, loss):
        if isinstance(rec, Message):
            by_channel[rec.channel_id].append((rec.log_time, rec.publish_time, rec.data))
            n_messages += 1
        elif isinstance(rec, Channel):
            channels.setdefault(rec.id, rec)
        elif isinstance(rec, Schema):
            schemas.setdefault(rec.id, rec)
        elif isinstance(rec, Metadata):
            out.metadata.append((rec.name, dict(rec.metadata)))
        elif isinstance(rec, Header):
            out.profile, out.library = rec.profile, rec.library
        elif isinstance(rec, Statistics):
            out.statistics = rec
    if not channels and n_messages == 0 and not out.metadata:
        why = "; ".join(loss["errors"][:3]) or "no records"
        raise ValueError(f"{path}: unreadable MCAP, nothing recoverable ({why})")
    # channels are resolved at the end: a Channel record may come after its messages (repeated in a later chunk
    # or in the summary section) when the chunk that first held it was lost
    for cid, ch in sorted(channels.items()):
        sch = schemas.get(ch.schema_id)
        out.topics.setdefault(ch.topic, sch.name if sch else "")
        out.encodings.setdefault(ch.topic, ch.message_encoding)
        out.channel_metadata.setdefault(ch.topic, dict(ch.metadata))
    for cid, msgs in by_channel.items():
        ch = channels.get(cid)
        if ch is None:
            loss["orphan_messages"] += len(msgs)
            continue
        out.messages[ch.topic].extend(msgs)
    by_topic = Counter()
    for cid, k in loss.pop("messages_lost_by_channel").items():
        by_topic[channels[cid].topic if cid in channels else f"channel {cid}"] += k
    loss["messages_lost_by_topic"] = dict(by_topic)
    loss["file"] = str(path)
    out.losses.append(loss)
    problems = []
    if loss["chunks_lost"]:
        span = sum(t1 - t0 for t0, t1 in loss["lost_time_ranges_ns"]) / 1e9
        problems.append(f"skipped {loss['chunks_lost']} corrupt or cut-short chunk(s) of {loss['chunks_total']} "
                        f"(≥ {loss['messages_lost']} message(s) lost, {len(loss['lost_time_ranges_ns'])} log-time "
                        f"range(s) totalling {span:.3g} s; meta['loss'] lists them)")
    if loss["orphan_messages"]:
        problems.append(f"{loss['orphan_messages']} message(s) on channels whose definition was lost")
    if loss["records_skipped"]:
        problems.append(f"{loss['records_skipped']} unreadable record(s) skipped")
    if loss["truncated"]:
        problems.append(f"data ends early after {n_messages} messages (no footer: a writer that was killed or a "
                        "file cut short)")
    if problems:
        out.truncated = True
        msg = f"{path.name}: " + "; ".join(problems)
        out.error = msg if out.error is None else f"{out.error}; {msg}"
    out.files.append(str(path))


def _rosbag2_files(directory: Path) -> list[Path]:
    import yaml

    meta = directory / "metadata.yaml"
    if not meta.is_file():
        files = sorted(directory.glob("*.mcap"))
        if not files:
            raise ValueError(f"{directory}: a directory without metadata.yaml or .mcap files is not a rosbag2 bag")
        return files
    try:
        info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
        rel = info.get("relative_file_paths") or []
    except Exception as exc:
        raise ValueError(f"{meta}: malformed rosbag2 metadata ({exc})") from None
    files = [directory / r for r in rel]
    missing = [str(p) for p in files if not p.exists()]
    if missing:
        raise ValueError(f"{meta}: listed storage files missing: {missing}")
    return files


def _scan_db3(path: Path, out: McapContents) -> None:
    from rosbags.rosbag2 import Reader

    try:
        with Reader(path.parent) as reader:
            for conn in reader.connections:
                out.topics.setdefault(conn.topic, conn.msgtype)
                out.encodings.setdefault(conn.topic, "cdr")
            for conn, t, raw in reader.messages():
                out.messages[conn.topic].append((t, t, bytes(raw)))
    except Exception as exc:
        raise ValueError(f"{path}: cannot read rosbag2 sqlite storage ({type(exc).__name__}: {exc})") from None
    out.files.append(str(path))


def scan_mcap(path) -> McapContents:
    """Read all records of an MCAP file or a rosbag2 directory (``metadata.yaml`` + ``.mcap``/``.db3`` files).

    Uses the non-seeking stream reader, so a file cut short (a killed recorder) is read up to its last complete
    chunk and flagged ``truncated``.  Raises ``ValueError`` for a file that is not MCAP or has nothing readable,
    ``FileNotFoundError`` if the path does not exist.
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such file or directory")
    out = McapContents(source=str(p))
    files = _rosbag2_files(p) if p.is_dir() else [p]
    if any(f.suffix == ".db3" for f in files):
        _scan_db3(files[0], out)  # sqlite storage: rosbags reads the whole bag directory
        return out
    for f in files:
        _scan_one(f, out)
    return out


# ----------------------------------------------------------------------------------------------------------------
# run reassembly

def _pick_topic(contents: McapContents, role: str, type_name: str, namespace: str | None) -> str | None:
    cands = [t for t, tn in contents.topics.items() if tn == type_name and t.rstrip("/").split("/")[-1] == role]
    if namespace is not None:
        want = "/" + "/".join(x for x in (namespace.strip("/"), role) if x)
        cands = [t for t in cands if t == want or t.lstrip("/") == want.lstrip("/")]
    if len(cands) > 1:
        raise ValueError(f"several {role} topics {sorted(cands)}; choose one with namespace=")
    return cands[0] if cands else None


def _infer_dt_ns(stamp_lists: list[list[tuple[int, int]]]) -> int | None:
    """Most common (stamp difference / block width) over consecutive blocks of each topic."""
    votes: Counter = Counter()
    for blocks in stamp_lists:
        srt = sorted(blocks)
        for (s0, n0), (s1, _) in zip(srt, srt[1:]):
            d = s1 - s0
            if n0 > 0 and d > 0 and d % n0 == 0:
                votes[d // n0] += 1
    return votes.most_common(1)[0][0] if votes else None


#: a gap between blocks is bridged (kept as NaN rows) up to this many samples, or the number of samples the
#: recording holds if larger; beyond that, the blocks on the smaller side are outliers (memory stays ≤ ~2× the data)
MIN_BRIDGED_GAP = 1_000_000


def _split_outliers(decoded: dict[str, list[tuple[int, np.ndarray]]], dt_ns: int):
    """Keep the blocks of the main time span; return ``(kept, outliers)`` per role.

    Blocks (all topics together) are grouped into clusters separated by gaps larger than
    ``max(MIN_BRIDGED_GAP, samples held)`` sample periods; the cluster holding the most samples is the recording,
    the others are outliers (never allocated).
    """
    items = sorted((s, s + len(b) * dt_ns, role, i) for role, blks in decoded.items() for i, (s, b) in enumerate(blks))
    if not items:
        return decoded, {}
    per_role = Counter()
    for role, blks in decoded.items():
        per_role[role] = sum(len(b) for _, b in blks)
    max_gap_ns = max(MIN_BRIDGED_GAP, max(per_role.values())) * dt_ns
    clusters, cur, cur_end, cur_n = [], [], None, 0
    for start, end, role, i in items:
        if cur and start - cur_end > max_gap_ns:
            clusters.append((cur_n, cur))
            cur, cur_n, cur_end = [], 0, None
        cur.append((role, i))
        cur_n += (end - start) // dt_ns
        cur_end = end if cur_end is None else max(cur_end, end)
    clusters.append((cur_n, cur))
    if len(clusters) == 1:
        return decoded, {r: [] for r in decoded}
    main = set(max(clusters, key=lambda c: c[0])[1])
    kept = {r: [blk for i, blk in enumerate(blks) if (r, i) in main] for r, blks in decoded.items()}
    outs = {r: [blk for i, blk in enumerate(blks) if (r, i) not in main] for r, blks in decoded.items()}
    return kept, outs


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) ranges where ``mask`` is True."""
    if not mask.any():
        return []
    d = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def _diagnostics_summary(raw_msgs) -> dict:
    summary = {"messages": 0, "malformed": 0, "status": {}}
    for _, _, raw in raw_msgs:
        try:
            msg = deserialize_message(raw, DIAGNOSTICS_TYPE)
        except ValueError:
            summary["malformed"] += 1
            continue
        summary["messages"] += 1
        for st in msg.status:
            level = int(st.level[0] if isinstance(st.level, (bytes, bytearray)) else st.level)
            entry = summary["status"].setdefault(st.name, {"count": 0, "max_level": 0, "errors": 0})
            entry["count"] += 1
            entry["max_level"] = max(entry["max_level"], level)
            entry["errors"] += int(level >= 2)
            entry.update(level=level, message=st.message, hardware_id=st.hardware_id,
                         values={kv.key: kv.value for kv in st.values})
    return summary


def _as_int(v) -> int:
    """An integer from JSON (an integral float too); ``ValueError`` otherwise (bools, text, 1.5)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (isinstance(v, float) and not v.is_integer()):
        raise ValueError(f"not an integer: {v!r}")
    return int(v)


def _experiment_markers(raw_msgs, t0_ns: int, dt_ns: int, warnings: list) -> list[dict]:
    markers, seen = [], set()
    for log_time, _, raw in raw_msgs:
        try:
            text = deserialize_message(raw, EXPERIMENT_TYPE).data
        except ValueError:
            warnings.append("experiment: undecodable message skipped")
            continue
        try:
            info = json.loads(text)
            if not isinstance(info, dict):
                raise TypeError
        except (TypeError, ValueError):
            warnings.append(f"experiment: marker {text[:60]!r} is not a JSON object; skipped")
            continue
        try:
            if "stamp_ns" in info:
                q, r = divmod(_as_int(info["stamp_ns"]) - t0_ns, dt_ns)
                k0 = q + (2 * r >= dt_ns)
            elif "k0" in info:
                k0 = _as_int(info["k0"])
            else:
                warnings.append(f"experiment: marker {info.get('name')!r} has neither k0 nor stamp_ns; skipped")
                continue
            for key in ("k1", "n"):
                if key in info:
                    info[key] = _as_int(info[key])
        except (TypeError, ValueError):
            warnings.append(f"experiment: marker {text[:60]!r}: k0/stamp_ns/k1/n not integers; skipped")
            continue
        key = (str(info.get("name", info.get("experiment", ""))), k0)  # Experiment.meta() says "experiment"
        if key in seen:  # transient-local redelivery or several publishers: one marker
            continue
        seen.add(key)
        markers.append({"name": key[0], "k0": int(k0), "stages": info.get("stages"), "info": info,
                        "log_time_ns": int(log_time)})
    markers.sort(key=lambda m: m["k0"])
    return markers


def read_run(path, *, namespace: str | None = None, sample_rate: float | None = None,
             trim: bool = True) -> RunData:
    """Reassemble a ROS 2 recording of the topic contract into a sample-aligned :class:`RunData`.

    Parameters
    ----------
    path
        ``.mcap`` file (ours or any ROS 2 MCAP writer's) or rosbag2 directory.
    namespace
        Pick ``/<namespace>/reference`` … when the file holds several namespaces.
    sample_rate
        Override [Hz]; default from the ``piezo_ff_ros`` metadata record, else inferred from the block stamps.
    trim
        Keep only the span where every recorded block topic has started and not yet ended (the recorder starts
        and stops between topics); interior gaps stay NaN.

    Returns
    -------
    RunData
        ``t`` [s] = sample index / fs (index 0 = ``t0_ns``), ``u`` [V], ``y`` [m], ``reference`` [m] or None;
        NaN where a topic is absent or has a gap.  ``meta`` holds: ``source``, ``truncated``/``truncation_error``,
        ``topics`` (type and count), ``sample_rate``, ``dt_ns``, ``t0_ns``, ``k_offset`` (run index of array
        row 0), ``blocks`` (per role: topic, count, block sizes, ``gaps`` [(k_start, k_stop)] in run indices,
        ``missing_samples``, ``missing_blocks``, ``duplicates``, ``conflicts``, ``off_grid``, ``malformed``),
        ``segments`` (experiment markers: name, k0, k1, start/stop array rows, stages, ``complete``),
        ``metadata`` (the ``piezo_ff_ros`` record), ``diagnostics`` (counts and last status values per name),
        ``warnings``.

    Raises
    ------
    ValueError
        Not MCAP, nothing readable, no block topic, inconsistent axes, no overlapping data.
    """
    contents = scan_mcap(path)
    warnings: list[str] = []
    if contents.truncated:
        warnings.append(contents.error)
    non_cdr = {t: e for t, e in contents.encodings.items() if e != "cdr"}
    if non_cdr:
        warnings.append(f"topics with a non-CDR encoding ignored: {non_cdr}")
    md = contents.metadata_record()

    roles = {r: _pick_topic(contents, r, BLOCK_TYPE, namespace) for r in BLOCK_ROLES}
    roles = {r: t for r, t in roles.items() if t is not None and contents.encodings.get(t) == "cdr"}
    if not roles:
        raise ValueError(f"{path}: no block topic (reference/voltage/displacement of type {BLOCK_TYPE}); "
                         f"topics found: {contents.topics or 'none'}")

    # decode every block
    axes = None
    if "axes" in md:
        try:
            axes = json.loads(md["axes"])
        except ValueError:
            axes = [a.strip() for a in md["axes"].split(",") if a.strip()]
        if not (isinstance(axes, list) and axes and all(isinstance(a, str) and a for a in axes)
                and len(set(axes)) == len(axes)):
            warnings.append(f"metadata axes {md['axes']!r} is not a list of distinct names; taken from the blocks")
            axes = None
        else:
            axes = canonical_axes(axes)  # columns by name, in the fixed x, y, z order whatever the writer's order
    decoded: dict[str, list[tuple[int, np.ndarray]]] = {}
    malformed: Counter = Counter()
    topic_counts = {t: len(contents.messages.get(t, [])) for t in contents.topics}
    for role, topic in roles.items():
        out = decoded[role] = []
        raws = contents.messages.pop(topic, [])  # decoded below: the raw bytes are released topic by topic
        for _, _, raw in raws:
            try:
                if axes is None:  # no metadata: the first block's field names, in the fixed x, y, z order
                    axes = canonical_axes(deserialize_block(raw)[2])
                stamp, block, names = deserialize_block(raw, axes)
            except ValueError as exc:
                if malformed[role] == 0:
                    warnings.append(f"{topic}: malformed block skipped ({exc})")
                malformed[role] += 1
                continue
            out.append((stamp, block))
        del raws
    if axes is None or not any(decoded.values()):
        raise ValueError(f"{path}: the block topics {sorted(roles.values())} hold no decodable block")

    # sample grid
    if sample_rate is not None:
        try:
            dt_ns = sample_period_ns(sample_rate)
        except ValueError as exc:
            raise ValueError(f"{path}: --sample-rate/sample_rate= {exc}") from None
    elif "sample_rate" in md:
        try:
            sample_rate = float(md["sample_rate"])
            dt_ns = sample_period_ns(sample_rate)
        except ValueError as exc:
            warnings.append(f"metadata sample_rate {md['sample_rate']!r} unusable ({exc}); inferred from stamps")
            sample_rate = None
        else:  # the stamps are the contract's ground truth: a metadata rate they contradict is not used
            from_stamps = _infer_dt_ns([[(s, len(b)) for s, b in blks] for blks in decoded.values()])
            if from_stamps is not None and from_stamps != dt_ns:
                warnings.append(f"metadata sample_rate {md['sample_rate']!r} Hz contradicts the block stamps "
                                f"({1e9 / from_stamps:g} Hz: {from_stamps} ns per sample); the stamps are used")
                dt_ns = from_stamps
    if sample_rate is None:
        dt_ns = _infer_dt_ns([[(s, len(b)) for s, b in blks] for blks in decoded.values()])
        if dt_ns is None:
            raise ValueError(f"{path}: cannot infer the sample rate (fewer than two consecutive blocks, no "
                             "sample_rate metadata); pass sample_rate=")
    fs = 1e9 / dt_ns
    # stamps far outside the span of the data (a clock glitch, a corrupt stamp) are set aside and reported: the
    # arrays are sized from the data, never from the stamp span
    decoded, outliers = _split_outliers(decoded, dt_ns)
    for role, outs in outliers.items():
        if outs:
            warnings.append(f"{roles[role]}: {len(outs)} block(s) stamped outside the recording's span ignored "
                            f"(stamps {[s for s, _ in outs[:5]]} ns{' …' if len(outs) > 5 else ''})")
    all_stamps = [s for blks in decoded.values() for s, _ in blks]
    t0_ns = None
    if "t0_ns" in md:
        try:
            t0_ns = int(md["t0_ns"])
        except ValueError:
            warnings.append(f"metadata t0_ns {md['t0_ns']!r} is not an integer; the first stamp is used")
    if t0_ns is not None:
        phases = Counter((s - t0_ns) % dt_ns for s in all_stamps)
        if phases.most_common(1)[0][0] != 0:  # most stamps off the metadata's grid: that t0 is not the stamps'
            warnings.append(f"metadata t0_ns {md['t0_ns']!r} is not on the block stamps' {dt_ns} ns grid; the "
                            "first stamp is used")
            t0_ns = None
    if t0_ns is None:
        t0_ns = min(all_stamps)

    def index_of(stamp: int) -> int:  # nearest sample index (off-grid stamps are rounded, and counted below)
        q, r = divmod(stamp - t0_ns, dt_ns)
        return q + int(2 * r >= dt_ns)

    # place blocks by sample index
    k_first = min(index_of(s) for s in all_stamps)
    k_end = max(index_of(s) + len(b) for blks in decoded.values() for s, b in blks)
    length = int(k_end - k_first)
    arrays, covered, info = {}, {}, {}
    for role in list(decoded):
        blks = decoded.pop(role)  # placed below: each role's decoded blocks are released once in its array
        arr = np.full((length, len(axes)), np.nan)
        cov = np.zeros(length, dtype=bool)
        dup = conflicts = off_grid = 0
        seen_k0 = set()
        sizes = Counter()
        for stamp, block in blks:
            q = index_of(stamp)
            off_grid += int((stamp - t0_ns) % dt_ns != 0)
            a = int(q - k_first)
            b = a + len(block)
            sizes[len(block)] += 1
            if q in seen_k0 or cov[a:b].any():
                dup += 1
                if not np.array_equal(arr[a:b], block, equal_nan=True):
                    conflicts += 1  # keep the first copy; a conflicting second one is reported
                continue
            seen_k0.add(q)
            arr[a:b] = block
            cov[a:b] = True
        arrays[role], covered[role] = arr, cov
        idx = np.flatnonzero(cov)
        lo, hi = (int(idx[0]), int(idx[-1]) + 1) if idx.size else (0, 0)
        gaps = [(a + lo, b + lo) for a, b in _runs(~cov[lo:hi])]
        typical = sizes.most_common(1)[0][0] if sizes else 0
        missing = int(sum(b - a for a, b in gaps))
        info[role] = {
            "topic": roles[role], "count": len(blks), "block_sizes": sorted(sizes), "first_k": lo + k_first,
            "end_k": hi + k_first, "gaps": [(a + k_first, b + k_first) for a, b in gaps],
            "missing_samples": missing, "missing_blocks": int(np.ceil(missing / typical)) if typical else 0,
            "duplicates": dup, "conflicts": conflicts, "off_grid": off_grid, "malformed": malformed[role],
            "outliers": len(outliers.get(role, [])),
            "outlier_stamps_ns": [int(st) for st, _ in outliers.get(role, [])[:_MAX_RANGES]],
        }
        if off_grid:
            warnings.append(f"{roles[role]}: {off_grid} block stamps off the {dt_ns} ns sample grid (rounded)")

    # common span
    start, stop = 0, length
    if trim:
        present = [i for i in info.values() if i["count"] > 0]
        start = max(i["first_k"] for i in present) - k_first
        stop = min(i["end_k"] for i in present) - k_first
        if stop <= start:
            raise ValueError(f"{path}: the block topics do not overlap in time "
                             f"({ {r: (i['first_k'], i['end_k']) for r, i in info.items()} })")
    k_offset = int(start + k_first)
    n = int(stop - start)
    t = (np.arange(n, dtype=np.int64) + k_offset) * (dt_ns / 1e9)

    def take(role):
        if role in arrays:
            return arrays[role][start:stop]
        return None

    u, y, ref = take("voltage"), take("displacement"), take("reference")
    if u is None:
        warnings.append("no voltage topic: u is NaN")
        u = np.full((n, len(axes)), np.nan)
    if y is None:
        warnings.append("no displacement topic: y is NaN")
        y = np.full((n, len(axes)), np.nan)

    # experiment segments
    exp_topic = _pick_topic(contents, "experiment", EXPERIMENT_TYPE, namespace)
    markers = _experiment_markers(contents.messages.get(exp_topic, []), t0_ns, dt_ns, warnings) \
        if exp_topic else []
    segments = []
    for i, m in enumerate(markers):
        k1 = markers[i + 1]["k0"] if i + 1 < len(markers) else k_offset + n
        if "k1" in m["info"]:
            k1 = min(k1, int(m["info"]["k1"]))
        elif "n" in m["info"]:
            k1 = min(k1, m["k0"] + int(m["info"]["n"]))
        s_row, e_row = max(m["k0"] - k_offset, 0), min(k1 - k_offset, n)
        complete = m["k0"] >= k_offset and k1 <= k_offset + n and e_row > s_row and all(
            covered[r][s_row + start:e_row + start].all() for r in covered)
        segments.append({"name": m["name"], "k0": m["k0"], "k1": int(k1), "start": int(s_row),
                         "stop": int(max(e_row, s_row)), "stages": m["stages"], "complete": bool(complete),
                         "info": m["info"]})

    diag_topic = next((t for t, tn in contents.topics.items() if tn == DIAGNOSTICS_TYPE
                       and t.rstrip("/").split("/")[-1] == "diagnostics"), None)
    diagnostics = _diagnostics_summary(contents.messages.get(diag_topic, [])) if diag_topic else {"messages": 0}

    meta = {
        "source": str(path), "format": "rosbag2" if Path(path).is_dir() else "mcap", "profile": contents.profile,
        "library": contents.library, "truncated": contents.truncated, "truncation_error": contents.error,
        "topics": {t: {"type": tn, "count": topic_counts.get(t, 0)} for t, tn in contents.topics.items()},
        "sample_rate": fs, "dt_ns": int(dt_ns), "t0_ns": int(t0_ns), "k_offset": k_offset, "axes": tuple(axes),
        "blocks": info, "segments": segments, "metadata": md, "diagnostics": diagnostics, "warnings": warnings,
        "trimmed": {"head": int(start), "tail": int(length - stop)}, "loss": contents.loss_summary(),
    }
    return RunData(t=t, u=u, y=y, axes=tuple(axes), reference=ref, meta=meta)
