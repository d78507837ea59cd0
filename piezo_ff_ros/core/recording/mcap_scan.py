"""Reading the records of one or more MCAP files (or a rosbag2 directory), robust to truncation and corruption."""
from __future__ import annotations

import mmap
import struct
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

from .schemas import METADATA_NAME

__all__ = ["McapContents", "scan_mcap", "iter_mcap_records", "new_loss_account", "MAX_LISTED_RANGES"]


@dataclass
class McapContents:
    """Everything read from an MCAP file (or a rosbag2 directory): topics, raw messages, metadata.

    ``messages[topic]`` is a list of ``(log_time_ns, publish_time_ns, raw_cdr)`` in file order.
    ``truncated`` is set (with ``error``) when the data ended early or was corrupt after a readable prefix.
    """

    source: str
    profile: str = ""
    library: str = ""
    topics: dict[str, str] = field(default_factory=dict)  # topic -> type name
    encodings: dict[str, str] = field(default_factory=dict)  # topic -> message encoding
    channel_metadata: dict[str, dict[str, str]] = field(default_factory=dict)  # topic -> channel metadata
    messages: dict[str, list[tuple[int, int, bytes]]] = field(default_factory=lambda: defaultdict(list))
    metadata: list[tuple[str, dict[str, str]]] = field(default_factory=list)  # [(name, {k: v})] in file order
    statistics: Any = None
    truncated: bool = False
    error: str | None = None
    files: list[str] = field(default_factory=list)
    # per file: what could not be read (see iter_mcap_records)
    losses: list[dict[str, Any]] = field(default_factory=list)

    def loss_summary(self) -> dict[str, Any]:
        """What could not be read, summed over the files: chunk/message/byte counts and lost log-time ranges."""
        out: dict[str, Any] = {"chunks_total": 0, "chunks_lost": 0, "messages_lost": 0, "bytes_skipped": 0, "records_skipped": 0,
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

    def metadata_record(self, name: str = METADATA_NAME) -> dict[str, str]:
        """The Metadata records called ``name``, merged in file order (later keys win)."""
        out: dict[str, str] = {}
        for n, d in self.metadata:
            if n == name:
                out.update(d)
        return out


_MCAP_MAGIC = b"\x89MCAP0\r\n"
_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_MESSAGE_INDEX = 1, 2, 3, 4, 5, 6, 7
_OP_DATA_END = 0x0F
_COMPRESSIONS = (b"", b"lz4", b"zstd")
#: the bytes a file is read from (memory-mapped, or empty)
_Buf = mmap.mmap | bytes
#: lost time ranges (and errors, outlier stamps) listed individually; the counts are always complete
MAX_LISTED_RANGES = 50


def new_loss_account() -> dict[str, Any]:
    """The reader's account of what it could not read (every count is a lower bound on what was lost)."""
    return {"chunks_total": 0, "chunks_lost": 0, "messages_lost": 0, "messages_lost_by_channel": Counter(),
            "lost_time_ranges_ns": [], "bytes_skipped": 0, "records_skipped": 0, "orphan_messages": 0,
            "truncated": False, "footer": False, "errors": []}


def _plausible_opcode(op: int) -> bool:
    # 0x01–0x0F are the spec's records, 0x80–0xFF user records; 0x00 and 0x10–0x7F are reserved: damage
    return 0x01 <= op <= 0x0F or op >= 0x80


def _chunk_header_at(buf: _Buf, pos: int) -> tuple[int, int, int] | None:
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


def _find_next_chunk(buf: _Buf, start: int) -> int | None:
    """Offset of the next complete Chunk record at or after ``start`` (resynchronisation after damaged framing)."""
    i = start
    while True:
        i = buf.find(b"\x06", i)
        if i < 0:
            return None
        if _chunk_header_at(buf, i) is not None:
            return i
        i += 1


def _partial_chunk_times(buf: _Buf, pos: int) -> tuple[int, int] | None:
    if pos + 9 + 16 <= len(buf) and buf[pos] == _OP_CHUNK:
        t0, t1 = struct.unpack_from("<QQ", buf, pos + 9)
        if t0 <= t1:
            return int(t0), int(t1)
    return None


def _lose_chunk(loss: dict[str, Any], times: tuple[int, int] | None, why: str) -> None:
    loss["chunks_lost"] += 1
    if times is not None and len(loss["lost_time_ranges_ns"]) < MAX_LISTED_RANGES:
        loss["lost_time_ranges_ns"].append([int(times[0]), int(times[1])])
    if len(loss["errors"]) < MAX_LISTED_RANGES:
        loss["errors"].append(why)


def iter_mcap_records(path: str | Path, loss: dict[str, Any] | None = None) -> Iterator[Any]:
    """Every record of an MCAP file, in file order, with the records inside chunks expanded; damage-tolerant.

    Unlike ``mcap``'s stream reader, which stops at the first bad record, this walks the top-level records
    itself: a chunk whose payload fails its CRC or decompression is skipped (the MessageIndex records after it
    give the count of messages lost per channel, its header the log-time range); damaged framing (an absurd
    record length, a reserved opcode) is skipped up to the next self-consistent Chunk record; a file that ends
    inside a record (a killed writer) ends the walk.  Everything skipped is accounted in ``loss`` (see
    :func:`new_loss_account`).  Raises ``ValueError`` if the file does not start with the MCAP magic.
    """
    from io import BytesIO

    from mcap.data_stream import ReadDataStream
    from mcap.records import (Attachment, Channel, Chunk, Footer, Header, Message, MessageIndex, Metadata, Schema,
                              Statistics)
    from mcap.stream_reader import breakup_chunk

    parsers = {_OP_HEADER: Header.read, _OP_FOOTER: Footer.read, _OP_SCHEMA: Schema.read,
               _OP_CHANNEL: Channel.read, _OP_CHUNK: Chunk.read, _OP_MESSAGE_INDEX: MessageIndex.read,
               0x09: Attachment.read, 0x0B: Statistics.read, 0x0C: Metadata.read}
    loss = new_loss_account() if loss is None else loss
    path = Path(path)
    buf: mmap.mmap | bytes
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

    loss = new_loss_account()
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    by_channel: dict[int, list[tuple[int, int, bytes]]] = defaultdict(list)
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
        owner = channels.get(cid)
        if owner is None:
            loss["orphan_messages"] += len(msgs)
            continue
        out.messages[owner.topic].extend(msgs)
    by_topic: Counter[str] = Counter()
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


def scan_mcap(path: str | Path) -> McapContents:
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
