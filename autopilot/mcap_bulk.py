"""An MCAP file written in bulk: every tick's messages built at once with numpy, in chunks
with their message indexes and a full summary (the format of mcap.dev's specification).

What it is: :func:`write_ticks` writes a file of ``channels`` whose per-tick messages have a
fixed size (a :class:`TickStream`: a payload template and the varying numbers at their byte
offsets, from :func:`autopilot.ros2msg.encode`), plus a few one-off messages at the first
stamp. A tick's records (MCAP Message records: opcode 0x05, u64 length, u16 channel id,
u32 sequence, u64 log time, u64 publish time, payload) lie side by side in one row of a
``(ticks, bytes)`` array; one numpy structured view names every varying field of the row,
so a column of the flight is written into all its messages with one assignment, and the rows
are the chunks' records as they are (the file is written from the array, no copy).

Why not the ``mcap`` library's ``Writer``: its ``add_message`` costs about 10 us a message in
Python (five messages a tick, 0.6 s for a 120 s flight) against about 1-2 us a tick here. The
library still writes the small records (header, schemas, channels, metadata, chunk indexes,
statistics, summary offsets, footer: :mod:`mcap.records`), and its reader is the test.

Layout: messages in tick order, a tick's channels in ``streams`` order (so log times never
decrease in file order); uncompressed chunks of whole ticks (about :data:`CHUNK_BYTES`;
compressing costs more than the flight: lz4 on 12 MB is tens of milliseconds), each followed
by one Message Index record per channel in it; the summary repeats schemas and channels and
holds the statistics, chunk indexes and the metadata index; CRCs of chunks are 0 (the
specification's "not computed"), the summary's is computed.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from autopilot.ros2msg import Offsets

__all__ = ["CHUNK_BYTES", "Channel", "McapMissingError", "TickStream", "write_ticks"]

CHUNK_BYTES = 1 << 20  # chunks of about 1 MiB: what viewers seek by
MAGIC = b"\x89MCAP0\r\n"
OP_CHUNK, OP_MESSAGE_INDEX = 0x06, 0x07
_MSG_HEADER = struct.Struct("<BQHIQQ")  # opcode, length, channel id, sequence, log time, publish time
_INDEX_ENTRY = np.dtype([("log_time", "<u8"), ("offset", "<u8")])

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


class McapMissingError(RuntimeError):
    """The ``mcap`` package is not installed."""


@dataclass(frozen=True)
class Channel:
    """One channel and its schema (ids are given in order from 1)."""

    topic: str
    schema_name: str
    schema_data: bytes
    schema_encoding: str = "ros2msg"
    message_encoding: str = "cdr"
    metadata: Mapping[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class TickStream:
    """A message per tick on channel ``channel`` (an index into the channels): the payload
    ``template`` with ``values[path]`` (one number per tick) written at ``offsets[path]``;
    ticks where ``valid`` is False have no message (None: every tick has one)."""

    channel: int
    template: bytes
    offsets: Offsets
    values: Mapping[str, npt.ArrayLike]
    valid: BoolArray | None = None


def _records() -> Any:
    try:
        from mcap import records
        from mcap.data_stream import RecordBuilder
        from mcap.opcode import Opcode
    except ImportError as exc:  # a plain dependency (pyproject.toml); say so if it was left out
        raise McapMissingError("writing an MCAP log needs the 'mcap' package: pip install mcap") from exc
    return records, RecordBuilder, Opcode


class _Rows:
    """Every tick's records side by side in one row (a record per stream), and the numpy view
    that names the varying fields of a row; :meth:`fill` builds the rows of ticks [a, b)."""

    def __init__(self, streams: Sequence[TickStream], ids: Sequence[int], log_ns: IntArray) -> None:
        heads: list[bytes] = []
        fields: list[tuple[str, int, Any]] = []  # (dtype, offset in the row, one value per tick)
        at = 0
        rec_at = []
        for s in streams:
            rec_at.append(at)
            heads.append(_MSG_HEADER.pack(0x05, 22 + len(s.template), ids[s.channel], 0, 0, 0) + s.template)
            seq = np.arange(log_ns.size) if s.valid is None else np.cumsum(s.valid) - 1
            own: list[tuple[str, int, Any]] = [("<u4", 11, seq), ("<u8", 15, log_ns), ("<u8", 23, log_ns)]
            own += [(s.offsets[p][1], _MSG_HEADER.size + s.offsets[p][0], v) for p, v in s.values.items()]
            fields += [(dt, at + off, v) for dt, off, v in own]
            at += _MSG_HEADER.size + len(s.template)
        # fields of one dtype side by side (a position and its quaternion, a run row) are written
        # as one (ticks, k) block: a few wide assignments a chunk rather than one per number
        groups: list[tuple[str, int, list[Any]]] = []
        for dt, off, v in sorted(fields, key=lambda f: f[1]):
            last = groups[-1] if groups else None
            if last is not None and last[0] == dt and last[1] + np.dtype(dt).itemsize * len(last[2]) == off:
                last[2].append(v)
            else:
                groups.append((dt, off, [v]))
        self.row = np.frombuffer(b"".join(heads), dtype=np.uint8)
        self.dtype = np.dtype({"names": [f"f{i}" for i in range(len(groups))],
                               "formats": [(dt, (len(vs),)) for dt, _, vs in groups],
                               "offsets": [off for _, off, _ in groups], "itemsize": at})  # fmt: skip
        self.cols = [[np.broadcast_to(np.asarray(v, dtype=dt), log_ns.shape) for v in vs]
                     for dt, _, vs in groups]  # fmt: skip
        self.rec_at = np.asarray(rec_at, dtype=np.int64)
        self.rec_bytes = np.diff(np.append(self.rec_at, at))

    def fill(self, buf: npt.NDArray[np.uint8], a: int, b: int) -> npt.NDArray[np.uint8]:
        """The rows of ticks [a, b) in ``buf`` (at least b - a rows); returns them."""
        rows = buf[: b - a]
        rows[:] = self.row
        view = rows.view(self.dtype)[:, 0]
        for name, cols in zip(self.dtype.names or (), self.cols, strict=True):
            np.stack([c[a:b] for c in cols], axis=1, out=view[name])  # straight into the rows
        return rows


def write_ticks(
    path: Path | str, channels: Sequence[Channel], log_ns: IntArray, streams: Sequence[TickStream], *,
    once: Sequence[tuple[int, bytes]] = (), metadata: tuple[str, Mapping[str, str]] | None = None,
    library: str = "heli-tlc-sitl", chunk_bytes: int = CHUNK_BYTES,
) -> Path:  # fmt: skip
    """Write the MCAP file ``path``: ``channels`` (ids 1, 2, ...), the ``once`` messages
    (channel index, payload) at ``log_ns[0]``, then per tick ``k`` (stamped ``log_ns[k]``, ns,
    non-decreasing) the messages of ``streams`` in their order; returns the path."""
    records, RecordBuilder, Opcode = _records()
    log_ns = np.asarray(log_ns, dtype=np.int64)
    if log_ns.size and (log_ns[0] < 0 or np.any(np.diff(log_ns) < 0)):
        raise ValueError("MCAP log times must be non-negative and non-decreasing")
    ids = list(range(1, len(channels) + 1))
    rows = _Rows(streams, ids, log_ns)
    n, row_bytes = log_ns.size, rows.row.size
    valid = np.column_stack([np.ones(n, bool) if s.valid is None else np.asarray(s.valid, bool)
                             for s in streams]) if streams else np.ones((n, 0), bool)  # fmt: skip
    every = bool(valid.all())  # every tick has every message: the rows are the records as they are

    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    rb = RecordBuilder()
    stats_counts: dict[int, int] = dict.fromkeys(ids, 0)
    chunk_indexes: list[Any] = []
    with out.open("wb", buffering=0) as fh:  # a few large writes: no buffer to copy through
        fh.write(MAGIC)
        records.Header(profile="", library=library).write(rb)
        schema_ids: dict[tuple[str, bytes], int] = {}
        schema_recs, channel_recs = [], []
        for cid, ch in zip(ids, channels, strict=True):
            key = (ch.schema_name, ch.schema_data)
            if key not in schema_ids:
                schema_ids[key] = len(schema_ids) + 1
                schema_recs.append(records.Schema(id=schema_ids[key], name=ch.schema_name,
                                                  encoding=ch.schema_encoding, data=ch.schema_data))
            channel_recs.append(records.Channel(id=cid, topic=ch.topic, message_encoding=ch.message_encoding,
                                                schema_id=schema_ids[key], metadata=dict(ch.metadata)))
        for r in (*schema_recs, *channel_recs):
            r.write(rb)
        pos = len(MAGIC) + rb.count
        metadata_index = []
        if metadata is not None:
            meta = records.Metadata(name=metadata[0], metadata=dict(metadata[1]))
            start = rb.count
            meta.write(rb)
            metadata_index.append(records.MetadataIndex(offset=pos, length=rb.count - start, name=meta.name))
        head = rb.end()
        fh.write(head)
        pos = len(MAGIC) + len(head)

        def chunk(recs: Any, index: Mapping[int, tuple[IntArray, IntArray]]) -> None:
            nonlocal pos
            times = [t for t, _ in index.values() if t.size]
            t0, t1 = (int(min(t[0] for t in times)), int(max(t[-1] for t in times))) if times else (0, 0)
            size = len(recs)
            head = struct.pack("<BQQQQII", OP_CHUNK, 8 + 8 + 8 + 4 + 4 + 8 + size, t0, t1, size, 0, 0)
            fh.write(head + struct.pack("<Q", size))
            fh.write(recs)  # unbuffered file: straight from the rows
            chunk_start, chunk_len = pos, len(head) + 8 + size
            pos += chunk_len
            offsets: dict[int, int] = {}
            index_start = pos
            parts: list[bytes] = []
            for cid, (t, off) in index.items():
                if not t.size:
                    continue
                entries = np.empty(t.size, dtype=_INDEX_ENTRY)
                entries["log_time"], entries["offset"] = t, off
                body = 16 * t.size
                parts += [struct.pack("<BQHI", OP_MESSAGE_INDEX, 2 + 4 + body, cid, body), entries.tobytes()]
                offsets[cid] = pos
                pos += 15 + body
                stats_counts[cid] += t.size
            fh.write(b"".join(parts))  # one write for the chunk's indexes
            chunk_indexes.append(records.ChunkIndex(
                message_start_time=t0, message_end_time=t1, chunk_start_offset=chunk_start,
                chunk_length=chunk_len, message_index_offsets=offsets, message_index_length=pos - index_start,
                compression="", compressed_size=size, uncompressed_size=size))  # fmt: skip

        if once and n:
            t = int(log_ns[0])
            first, index, at = bytearray(), {}, 0
            for ci, payload in once:
                rec = _MSG_HEADER.pack(0x05, 22 + len(payload), ids[ci], 0, t, t) + payload
                index[ids[ci]] = (np.array([t], np.int64), np.array([at], np.int64))
                first += rec
                at += len(rec)
            chunk(bytes(first), index)
        # chunk by chunk in one buffer of about a chunk: built, written and reused while in cache
        ticks_per_chunk = max(1, chunk_bytes // max(1, row_bytes))
        buf = np.empty((min(n, ticks_per_chunk), row_bytes), dtype=np.uint8)
        for a in range(0, n, ticks_per_chunk):
            b = min(n, a + ticks_per_chunk)
            block = rows.fill(buf, a, b)
            ok = valid[a:b]
            if every:
                starts = np.arange(b - a, dtype=np.int64)[:, None] * row_bytes + rows.rec_at[None, :]
                recs: Any = block.reshape(-1)
            else:  # drop the missing messages' bytes (a lost flight's last ticks, a log without a reference)
                keep = np.repeat(ok.reshape(-1), np.tile(rows.rec_bytes, b - a))
                recs = block.reshape(-1)[keep]
                sizes = (ok * rows.rec_bytes[None, :]).reshape(-1)
                starts = (np.cumsum(sizes) - sizes).reshape(b - a, len(streams))
            index = {ids[s.channel]: (log_ns[a:b][ok[:, i]], starts[:, i][ok[:, i]])
                     for i, s in enumerate(streams)}  # fmt: skip
            chunk(recs, index)

        rb = RecordBuilder()
        records.DataEnd(data_section_crc=0).write(rb)
        fh.write(rb.end())
        pos += 9 + 4
        summary_start = pos
        groups: list[tuple[int, list[Any]]] = [
            (Opcode.SCHEMA, schema_recs), (Opcode.CHANNEL, channel_recs),
            (Opcode.STATISTICS, [records.Statistics(
                message_count=sum(stats_counts.values()), schema_count=len(schema_recs),
                channel_count=len(channel_recs), attachment_count=0, metadata_count=len(metadata_index),
                chunk_count=len(chunk_indexes), message_start_time=int(log_ns[0]) if n else 0,
                message_end_time=int(log_ns[-1]) if n else 0, channel_message_counts=stats_counts)]),
            (Opcode.CHUNK_INDEX, chunk_indexes), (Opcode.METADATA_INDEX, metadata_index),
        ]  # fmt: skip
        offsets_recs = []
        for opcode, recs_ in groups:
            if not recs_:
                continue
            start = rb.count
            for r in recs_:
                r.write(rb)
            offsets_recs.append(records.SummaryOffset(group_opcode=opcode, group_start=summary_start + start,
                                                      group_length=rb.count - start))
        summary_offset_start = summary_start + rb.count
        for r in offsets_recs:
            r.write(rb)
        summary = rb.end()
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start),
                         zlib.crc32(summary))  # fmt: skip
        fh.write(summary)
        records.Footer(summary_start=summary_start, summary_offset_start=summary_offset_start,
                       summary_crc=crc).write(rb)
        fh.write(rb.end())
        fh.write(MAGIC)
    return out

