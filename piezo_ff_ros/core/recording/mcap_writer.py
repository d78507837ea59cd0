"""The recorder's MCAP writer: ROS 2 MCAP (rosbag2 profile) from raw CDR messages.

The file is what rosbag2's MCAP storage plugin writes, so ``ros2 bag info/play``, Foxglove and ``rosbags`` open it:
header profile ``ros2``; one Schema per type, encoding ``ros2msg`` (:mod:`.schemas`); Channels with message encoding
``cdr`` and metadata ``offered_qos_profiles`` (:mod:`.qos`) and ``topic_type_hash``; ZSTD chunks; the Statistics
record; plus a Metadata record ``piezo_ff_ros`` holding the run configuration.  Chunks are small and flushed at
least every ``flush_interval`` seconds, so a killed recorder leaves a file that
:func:`~.mcap_scan.scan_mcap` reads up to its last complete chunk.
"""
from __future__ import annotations

import json
import os
import threading
import time
from collections import Counter, deque
from pathlib import Path
from typing import Any, Iterable, Literal, Mapping

from .qos import qos_profiles_yaml
from .schemas import METADATA_NAME, ros2msg_definition, type_hash

__all__ = ["McapRecorder", "RecordingStopped"]

#: strict_chunks: a message record's header in a chunk (31 bytes), with room to spare
_RECORD_OVERHEAD = 64
#: strict_chunks: room kept in a chunk for the schema and channel records that may share it
_CHUNK_MARGIN = 8 * 1024


class RecordingStopped(OSError):
    """Writing failed (disk full, file-size limit, I/O error): the recorder ended the file at its last durable
    record boundary (readable by every MCAP reader) and accepts nothing more.  ``info`` says what was kept."""

    def __init__(self, text: str, info: dict[str, Any]) -> None:
        super().__init__(text)
        self.info = info


def _metadata_value(v: Any) -> str:
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
    strict_chunks
        Chunks hold at most ``chunk_size`` bytes of uncompressed records: the open chunk is closed before a message
        that would take it past (the MCAP writer itself closes a chunk only once it is over; a single larger message
        gets a chunk of its own).  The recorder node's chunks (docs/topics.md).

    Examples
    --------
    >>> rec = McapRecorder("run.mcap")                                                      # doctest: +SKIP
    >>> rec.register_topic("/displacement", "sensor_msgs/msg/PointCloud2", [block_qos_profile()])  # doctest: +SKIP
    >>> rec.write("/displacement", raw_cdr, log_time_ns=time.time_ns())                     # doctest: +SKIP
    >>> rec.close()                                                                         # doctest: +SKIP
    """

    def __init__(self, path: str | os.PathLike[str], *, chunk_size: int = 512 * 1024,
                 flush_interval: float | None = 1.0, compression: str = "zstd",
                 metadata: Mapping[str, Any] | None = None, library: str | None = None,
                 strict_chunks: bool = False) -> None:
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
        self._sequence: Counter[int] = Counter()
        self._metadata: dict[str, str] = {}
        self._flush_interval = flush_interval
        self._unflushed_since: float | None = None
        # strict_chunks: bytes of records in the open chunk (an upper bound) and what it may hold
        self._chunk_limit = int(chunk_size) - _CHUNK_MARGIN if strict_chunks else None
        self._chunk_bytes = 0
        self._last_pos = self._file.tell()
        self.message_count = 0
        self.bytes_in = 0
        self.closed = False
        #: why writing stopped early (None while all is well); then ``failure`` holds what was kept
        self.failed: str | None = None
        self.failure: dict[str, Any] = {}
        # record boundaries known to be on disk, with the message count up to each: where a failed file is cut
        self._durable: deque[tuple[int, int]] = deque([(self._file.tell(), 0)], maxlen=32)
        if metadata:
            self.set_metadata(metadata)

    # -- API used by the recorder node --------------------------------------------------------------------------
    def register_topic(self, topic: str, type_name: str, qos_profiles: Iterable[Any] | None = None) -> int:
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
            size = len(data) + _RECORD_OVERHEAD
            try:
                if self._chunk_limit is not None and self._chunk_bytes and \
                        self._chunk_bytes + size > self._chunk_limit:
                    self._close_chunk()       # before the message: the chunk stays within chunk_size
                self._writer.add_message(channel_id=cid, log_time=int(log_time_ns), data=data,
                                         publish_time=int(log_time_ns if publish_time_ns is None
                                                          else publish_time_ns),
                                         sequence=self._sequence[cid] & 0xFFFFFFFF)
                self.message_count += 1
                self.bytes_in += len(data)
                self._chunk_bytes += size
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
                    self._close_chunk()
                except OSError as exc:
                    self._stop_on_error(exc)

    def close(self) -> None:
        """Finish the file (summary, Statistics, footer) and close it; idempotent."""
        with self._lock:
            if self.closed:
                return
            try:
                self._writer.finish()  # type: ignore[no-untyped-call]  # mcap's Writer carries no annotations
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

    def _check_open(self) -> None:
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
        ending = b.end() + b"\x89MCAP0\r\n"  # type: ignore[no-untyped-call]  # mcap: no annotations
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

    def _close_chunk(self) -> None:
        """Close the open chunk and push the file to the OS (under the lock)."""
        self._writer.flush()  # type: ignore[no-untyped-call]  # mcap's Writer carries no annotations
        self._mark_durable()
        self._last_pos = self._file.tell()
        self._unflushed_since = None
        self._chunk_bytes = 0

    def _maybe_flush(self) -> None:
        pos = self._file.tell()
        if pos != self._last_pos:  # the writer has just written a full chunk: push it to the OS now
            self._file.flush()
            self._mark_durable()
            self._last_pos = pos
            self._unflushed_since = None
            self._chunk_bytes = 0
            return
        now = time.monotonic()
        if self._unflushed_since is None:
            self._unflushed_since = now
        if self._flush_interval is not None and now - self._unflushed_since >= self._flush_interval:
            self._close_chunk()

    def __enter__(self) -> "McapRecorder":
        return self

    def __exit__(self, *exc: object) -> Literal[False]:
        self.close()
        return False


# ----------------------------------------------------------------------------------------------------------------
# reader: records of one or more MCAP files, robust to truncation
