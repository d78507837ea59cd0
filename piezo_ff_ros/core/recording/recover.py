"""Rewrite a damaged MCAP file (a recorder killed with SIGKILL, a corrupt chunk, a file cut short) as a complete one.

A killed writer leaves no summary section and no footer, which the ``mcap`` seeking reader and ``rosbags`` refuse.
:func:`recover_mcap` reads every record that survives (:func:`~.mcap_scan.iter_mcap_records`, which skips corrupt
chunks and stops where the file ends) and writes them again — header, schemas, channels with their metadata
(QoS, type hash), messages with their times and sequence numbers, metadata records, attachments — with the
``mcap`` writer, which adds chunk and message indexes, statistics, the summary and the footer.  Nothing is
re-encoded: message payloads are copied byte for byte.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["recover_mcap"]


def recover_mcap(src: str | Path, dst: str | Path, *, compression: str = "zstd",
                 chunk_size: int = 512 * 1024) -> dict[str, Any]:
    """Write the readable content of ``src`` to a new, complete MCAP file ``dst``.

    Parameters
    ----------
    src, dst
        Input file and output file (``dst`` must not be ``src``; an existing ``dst`` is overwritten — the CLI
        refuses that unless asked).
    compression
        Chunk compression of the output: ``"zstd"`` (default), ``"lz4"`` or ``"none"``.
    chunk_size
        Uncompressed chunk size of the output [bytes].

    Returns
    -------
    dict
        What was read and written: ``messages_written``, ``channels``, ``schemas``, ``metadata_records``,
        ``attachments``, plus the reader's loss account (``chunks_total``, ``chunks_lost``, ``messages_lost``,
        ``lost_time_ranges_ns``, ``bytes_skipped``, ``orphan_messages``, ``truncated``, ``footer``, ``errors``).

    Raises
    ------
    ValueError
        ``src`` is not MCAP, holds nothing readable, or ``dst`` is ``src``.
    """
    from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
    from mcap.writer import CompressionType, Writer

    from .mcap_scan import iter_mcap_records, new_loss_account

    src, dst = Path(src), Path(dst)
    if not src.is_file():
        raise FileNotFoundError(f"{src}: no such file")
    if dst.exists() and dst.resolve() == src.resolve():
        raise ValueError(f"{dst}: the output would overwrite the input; choose another --out")
    comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
    if compression not in comp:
        raise ValueError(f"compression: {compression!r} not one of {sorted(comp)}")

    loss = new_loss_account()
    header = None
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    messages: list[Message] = []
    metadata: list[Metadata] = []
    attachments: list[Attachment] = []
    for rec in iter_mcap_records(src, loss):
        if isinstance(rec, Message):
            messages.append(rec)
        elif isinstance(rec, Channel):
            channels.setdefault(rec.id, rec)
        elif isinstance(rec, Schema):
            schemas.setdefault(rec.id, rec)
        elif isinstance(rec, Metadata):
            metadata.append(rec)
        elif isinstance(rec, Attachment):
            attachments.append(rec)
        elif isinstance(rec, Header) and header is None:
            header = rec
    if header is None or (not channels and not messages and not metadata):
        why = "; ".join(loss["errors"][:3]) or "no records"
        raise ValueError(f"{src}: unreadable MCAP, nothing recoverable ({why})")

    messages.sort(key=lambda m: m.log_time)  # stable: file order among equal times
    written = orphans = 0
    with open(dst, "wb") as f:
        writer = Writer(f, chunk_size=int(chunk_size), compression=comp[compression])
        writer.start(profile=header.profile, library=header.library)
        schema_ids: dict[int, int] = {}
        for sid, sch in sorted(schemas.items()):
            schema_ids[sid] = writer.register_schema(name=sch.name, encoding=sch.encoding, data=sch.data)
        channel_ids: dict[int, int] = {}
        for cid, ch in sorted(channels.items()):
            if ch.schema_id != 0 and ch.schema_id not in schema_ids:
                continue  # its schema was lost: the channel's messages cannot be decoded by anyone
            channel_ids[cid] = writer.register_channel(
                topic=ch.topic, message_encoding=ch.message_encoding,
                schema_id=schema_ids.get(ch.schema_id, 0), metadata=dict(ch.metadata))
        for md in metadata:
            writer.add_metadata(md.name, dict(md.metadata))
        for att in attachments:
            writer.add_attachment(create_time=att.create_time, log_time=att.log_time, name=att.name,
                                  media_type=att.media_type, data=att.data)
        for m in messages:
            new_cid = channel_ids.get(m.channel_id)
            if new_cid is None:
                orphans += 1
                continue
            writer.add_message(channel_id=new_cid, log_time=m.log_time, data=m.data, publish_time=m.publish_time,
                               sequence=m.sequence)
            written += 1
        writer.finish()  # type: ignore[no-untyped-call]  # mcap's Writer.finish carries no annotations
    loss["orphan_messages"] += orphans
    loss["messages_lost_by_topic"] = {
        (channels[cid].topic if cid in channels else f"channel {cid}"): k
        for cid, k in loss.pop("messages_lost_by_channel").items()}
    return {"source": str(src), "output": str(dst), "messages_written": written, "channels": len(channel_ids),
            "schemas": len(schema_ids), "metadata_records": len(metadata), "attachments": len(attachments), **loss}
