"""Fast MCAP reading: whole chunks parsed with numpy instead of one Python object per message.

The ``mcap`` reader builds a record object per message (~5 µs each).  Recorders write long runs of
equal-sized records (a Float64 message record is always 43 bytes), so a chunk is parsed run by
run: the run's rows are checked in one numpy comparison and the channel ids, log times and payload
offsets come out as arrays.  Reads linearly (no index needed), so a truncated recording yields
every complete chunk before the damage.  No rclpy.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Iterator

import numpy as np
from mcap.opcode import Opcode
from mcap.well_known import Profile
from mcap.writer import MCAP0_MAGIC as MAGIC

# record opcodes as plain ints (compared per record in the numpy fast path)
OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_DATA_END, OP_FOOTER = (
    int(Opcode.SCHEMA), int(Opcode.CHANNEL), int(Opcode.MESSAGE), int(Opcode.CHUNK), int(Opcode.DATA_END),
    int(Opcode.FOOTER))
_MSG_FIXED = 2 + 4 + 8 + 8  # channel id, sequence, log time, publish time
_MSG_HEAD = struct.Struct("<BQHIqq")


@dataclass
class MessageArrays:
    """Messages of one chunk, in file order: payload ``i`` is ``buf[offset[i]:offset[i]+length[i]]``."""

    channel: np.ndarray  # uint16
    log_time: np.ndarray  # int64
    offset: np.ndarray  # int64
    length: np.ndarray  # int64
    buf: np.ndarray  # uint8 view of the decompressed chunk

    def __len__(self) -> int:
        return len(self.channel)

    def payload(self, i: int) -> bytes:
        o = int(self.offset[i])
        return self.buf[o:o + int(self.length[i])].tobytes()

    def float64(self, rows: np.ndarray) -> np.ndarray:
        """Decode the given rows as little-endian CDR Float64 payloads (12 bytes), vectorised."""
        off = self.offset[rows]
        if not (np.all(self.length[rows] >= 12) and np.all(self.buf[off + 1] == 1)):
            raise ValueError("not little-endian Float64 CDR payloads")
        return self.buf[off[:, None] + np.arange(4, 12)].copy().view("<f8").ravel()


@dataclass
class ReadState:
    """What a linear read has seen so far."""

    schemas: dict[int, tuple[str, str, bytes]] = field(default_factory=dict)  # id -> (name, encoding, data)
    channels: dict[int, tuple[str, int, str]] = field(default_factory=dict)  # id -> (topic, schema id, encoding)
    bytes_read: int = 0
    truncated: bool = False
    problem: str = ""


def _string(b: bytes, pos: int) -> tuple[str, int]:
    n = struct.unpack_from("<I", b, pos)[0]
    return b[pos + 4:pos + 4 + n].decode(), pos + 4 + n


def _schema(body: bytes, state: ReadState) -> None:
    sid = struct.unpack_from("<H", body, 0)[0]
    name, p = _string(body, 2)
    enc, p = _string(body, p)
    n = struct.unpack_from("<I", body, p)[0]
    state.schemas[sid] = (name, enc, body[p + 4:p + 4 + n])


def _channel(body: bytes, state: ReadState) -> None:
    cid, sid = struct.unpack_from("<HH", body, 0)
    topic, p = _string(body, 4)
    enc, p = _string(body, p)
    state.channels[cid] = (topic, sid, enc)


def parse_records(data: bytes, state: ReadState) -> MessageArrays:
    """Parse a chunk's records; schema and channel records update ``state``."""
    buf = np.frombuffer(data, dtype=np.uint8)
    n = len(data)
    pos = 0
    chans, times, offs, lens = [], [], [], []
    while pos + 9 <= n:
        op = data[pos]
        ln = int.from_bytes(data[pos + 1:pos + 9], "little")
        rec = 9 + ln
        if pos + rec > n:
            raise ValueError("record runs past the end of its chunk")
        if op == OP_MESSAGE:
            avail = (n - pos) // rec
            head = buf[pos:pos + 9]
            m, step = 1, 64
            while m < avail:  # a run of records with the same opcode and length, checked in growing windows
                k = min(step, avail - m)
                rows = buf[pos + m * rec:pos + (m + k) * rec].reshape(k, rec)
                bad = np.flatnonzero(~(rows[:, :9] == head).all(axis=1))
                if len(bad):
                    m += int(bad[0])
                    break
                m += k
                step *= 2
            rows = buf[pos:pos + m * rec].reshape(m, rec)
            chans.append(rows[:, 9:11].copy().view("<u2").ravel())
            times.append(rows[:, 15:23].copy().view("<i8").ravel())
            offs.append(pos + 9 + _MSG_FIXED + rec * np.arange(m, dtype=np.int64))
            lens.append(np.full(m, ln - _MSG_FIXED, dtype=np.int64))
            pos += m * rec
            continue
        if op == OP_SCHEMA:
            _schema(data[pos + 9:pos + rec], state)
        elif op == OP_CHANNEL:
            _channel(data[pos + 9:pos + rec], state)
        pos += rec
    if not chans:
        e = np.empty(0, dtype=np.int64)
        return MessageArrays(np.empty(0, dtype=np.uint16), e, e, e, buf)
    return MessageArrays(np.concatenate(chans), np.concatenate(times), np.concatenate(offs), np.concatenate(lens), buf)


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(data)
    raise ValueError(f"unsupported chunk compression {compression!r}")


def iter_message_arrays(path: str | Path, state: ReadState | None = None) -> Iterator[MessageArrays]:
    """Linear read of an MCAP file, one :class:`MessageArrays` per chunk (or per loose message run).

    Stops at the data-end record; on a truncated or damaged file it stops at the first bad record
    and sets ``state.truncated`` (everything before it has been yielded).
    """
    state = state if state is not None else ReadState()
    with Path(path).open("rb") as fh:
        if fh.read(8) != MAGIC:
            raise ValueError(f"{path} is not an MCAP file")
        pos = 8
        while True:
            head = fh.read(9)
            if len(head) < 9:
                state.truncated = True
                state.problem = "file ends without a data-end record"
                break
            op = head[0]
            ln = int.from_bytes(head[1:], "little")
            body = fh.read(ln)
            if len(body) < ln:
                state.truncated = True
                state.problem = f"record at byte {pos} is cut short"
                break
            try:
                if op == OP_CHUNK:
                    _st, _et, size, crc = struct.unpack_from("<QQQI", body, 0)
                    comp, p = _string(body, 28)
                    n = struct.unpack_from("<Q", body, p)[0]
                    data = _decompress(comp, body[p + 8:p + 8 + n], size)
                    if crc and zlib.crc32(data) != crc:  # 0: the writer computed none
                        raise ValueError(f"chunk CRC mismatch (stored {crc:#010x}, data {zlib.crc32(data):#010x})")
                    arrays = parse_records(data, state)
                    state.bytes_read = pos + 9 + ln
                    if len(arrays):
                        yield arrays
                elif op == OP_MESSAGE:
                    arrays = parse_records(head + body, state)
                    state.bytes_read = pos + 9 + ln
                    yield arrays
                elif op == OP_SCHEMA:
                    _schema(body, state)
                elif op == OP_CHANNEL:
                    _channel(body, state)
                elif op in (OP_DATA_END, OP_FOOTER):
                    state.bytes_read = pos + 9 + ln
                    break
            except Exception as exc:  # noqa: BLE001 - damaged data (bad lengths, decompression): stop there
                state.truncated = True
                state.problem = f"damaged record at byte {pos}: {exc}"
                break
            pos += 9 + ln


def release_count(t_sorted: np.ndarray, keys_sorted: np.ndarray, ignore_key: int | None = None) -> int:
    """How many messages of a log-time-sorted batch are safe to hand on before the next batch is read.

    Each channel is in log-time order within a file, but channels interleave loosely across chunk
    (and batch) boundaries, so a message newer than the oldest of the channels' latest messages may
    still be preceded by one in the next batch; those are held back.  ``ignore_key`` names a slow
    channel (e.g. a temperature) whose last message must not hold everything else back.
    """
    keep = keys_sorted != ignore_key if ignore_key is not None else slice(None)
    t, k = t_sorted[keep], keys_sorted[keep]
    if len(t) == 0:
        return len(t_sorted)
    uniq, inv = np.unique(k, return_inverse=True)
    lasts = np.full(len(uniq), np.iinfo(np.int64).min, dtype=np.int64)
    np.maximum.at(lasts, inv, t)
    return int(np.searchsorted(t_sorted, lasts.min(), side="right"))


def iter_log_time_order(path: str | Path, state: ReadState | None = None
                        ) -> Iterator[tuple[np.ndarray, np.ndarray, list[bytes]]]:
    """All messages of an MCAP file in log-time order (file order among equal times), chunk by chunk.

    Yields ``(log_time, channel_id, payloads)``; ``state.channels`` maps the ids to topics.  Reads
    linearly like :func:`iter_message_arrays` (so also unindexed or truncated files) and restores
    the order across chunk boundaries with :func:`release_count`.
    """
    state = state if state is not None else ReadState()
    carry_t = np.empty(0, dtype=np.int64)
    carry_c = np.empty(0, dtype=np.int64)
    carry_p: list[bytes] = []
    for arrays in iter_message_arrays(path, state):
        data = arrays.buf.tobytes()
        payloads = carry_p + [data[o:o + n] for o, n in zip(arrays.offset.tolist(), arrays.length.tolist())]
        t = np.concatenate([carry_t, arrays.log_time])
        c = np.concatenate([carry_c, arrays.channel.astype(np.int64)])
        order = np.argsort(t, kind="stable")
        t, c = t[order], c[order]
        payloads = [payloads[i] for i in order.tolist()]
        cut = release_count(t, c)
        yield t[:cut], c[:cut], payloads[:cut]
        carry_t, carry_c, carry_p = t[cut:], c[cut:], payloads[cut:]
    if len(carry_t):
        yield carry_t, carry_c, carry_p


# ------------------------------------------------------------------------------------ writing
def message_rows(channel_id: np.ndarray, log_time: np.ndarray, payload: np.ndarray) -> np.ndarray:
    """Message records (one row each, sequence numbers left 0) for payloads of equal length."""
    n, plen = payload.shape
    rows = np.empty((n, 9 + _MSG_FIXED + plen), dtype=np.uint8)
    rows[:, 0] = OP_MESSAGE
    rows[:, 1:9] = np.frombuffer(struct.pack("<Q", _MSG_FIXED + plen), dtype=np.uint8)
    rows[:, 9:11] = np.ascontiguousarray(channel_id, dtype="<u2").view(np.uint8).reshape(n, 2)
    rows[:, 11:15] = 0
    lt = np.ascontiguousarray(log_time, dtype="<i8").view(np.uint8).reshape(n, 8)
    rows[:, 15:23] = lt
    rows[:, 23:31] = lt
    rows[:, 31:] = payload
    return rows


class ChunkedMcapWriter:
    """A ROS 2 MCAP writer that takes whole arrays of equal-sized messages at once.

    Produces the same file structure as the ``mcap`` library's writer (chunks with message
    indexes, summary with schemas, channels, statistics, chunk and metadata indexes, summary
    offsets, footer), which both ``mcap`` and ``rosbags`` read (tested).  :meth:`close` writes the
    summary, so an interrupted program that reaches it leaves a complete file; a killed one leaves
    every finished chunk readable.  CRCs as the ``mcap`` library writes them by default: each
    chunk's (of its uncompressed records) and the summary's; the data-section CRC is 0 ("not
    computed", as the spec allows and ``mcap``'s default ``enable_data_crcs=False`` does), since
    every chunk is covered already.  The reader here verifies the chunk CRCs it finds.  Chunks are
    zstd level 1: on streams of Float64 messages 3x faster to compress than level 3 and no larger.
    """

    def __init__(self, path: str | Path, chunk_size: int = 1024 * 1024, profile: str = Profile.ROS2,
                 library: str = "rollergear_ros", compression_level: int = 1) -> None:
        import zstandard
        from mcap.data_stream import RecordBuilder
        from mcap.records import Header

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = self.path.open("wb")
        self._zstd = zstandard.ZstdCompressor(level=compression_level)
        self.chunk_size = chunk_size
        self._schemas: dict[int, object] = {}
        self._channels: dict[int, object] = {}
        self._chunk_indexes: list = []
        self._metadata_indexes: list = []
        self._chunk = bytearray()  # record bytes of the open chunk
        self._index: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}  # channel -> [(log times, offsets)]
        self._single: dict[int, tuple[list[int], list[int]]] = {}  # the same for messages added one by one
        self._size = 0
        self._start = self._end = None
        self._counts: dict[int, int] = {}
        self._seq: dict[int, int] = {}
        self._message_count = 0
        self._t_min: int | None = None
        self._t_max: int | None = None
        self.closed = False
        self._fh.write(MAGIC)
        rb = RecordBuilder()
        Header(profile=profile, library=library).write(rb)
        self._fh.write(rb.end())

    # -------------------------------------------------------------- registration
    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        from mcap.records import Schema

        sid = len(self._schemas) + 1
        self._schemas[sid] = Schema(id=sid, name=name, encoding=encoding, data=data)
        self._write_record(self._schemas[sid])
        return sid

    def register_channel(self, topic: str, message_encoding: str, schema_id: int, metadata: dict | None = None) -> int:
        from mcap.records import Channel

        cid = len(self._channels) + 1
        self._channels[cid] = Channel(id=cid, topic=topic, message_encoding=message_encoding, schema_id=schema_id,
                                      metadata=dict(metadata or {}))
        self._write_record(self._channels[cid])
        self._counts[cid] = 0
        self._seq[cid] = 0
        return cid

    def _write_record(self, record) -> None:
        """Schema/channel records go into the open chunk (as the mcap writer does)."""
        from mcap.data_stream import RecordBuilder

        rb = RecordBuilder()
        record.write(rb)
        data = rb.end()
        self._chunk += data
        self._size += len(data)

    # -------------------------------------------------------------- messages
    def add_messages(self, channel_id: int | np.ndarray, log_time: np.ndarray, payload: np.ndarray) -> None:
        """Add ``n`` messages whose payloads are the rows of ``payload`` (n × L uint8), in this order.

        ``channel_id`` is one id for all rows, or an array with one id per row (interleaved topics).
        """
        n = len(log_time)
        if n == 0:
            return
        log_time = np.asarray(log_time, dtype=np.int64)
        ids = np.broadcast_to(np.asarray(channel_id, dtype=np.int64), (n,))
        rows = message_rows(ids, log_time, payload)
        rec = rows.shape[1]
        offsets = self._size + rec * np.arange(n, dtype=np.int64)
        for cid in np.unique(ids).tolist():
            sel = ids == cid
            k = int(sel.sum())
            seq = self._seq[cid] + np.arange(1, k + 1, dtype=np.int64)
            rows[sel, 11:15] = (seq & 0xFFFFFFFF).astype("<u4").view(np.uint8).reshape(k, 4)
            self._seq[cid] += k
            self._index.setdefault(cid, []).append((log_time[sel], offsets[sel]))
            self._counts[cid] += k
        self._chunk += rows.reshape(-1).data
        self._size += rows.size
        self._message_count += n
        lo, hi = int(np.min(log_time)), int(np.max(log_time))
        self._start = lo if self._start is None else min(self._start, lo)
        self._end = hi if self._end is None else max(self._end, hi)
        self._t_min = lo if self._t_min is None else min(self._t_min, lo)
        self._t_max = hi if self._t_max is None else max(self._t_max, hi)
        if self._size >= self.chunk_size:
            self.flush_chunk()

    def add_message(self, channel_id: int, log_time: int, data: bytes) -> None:
        """Add one message (plain Python: ~1 µs, for recorders that get messages one by one)."""
        seq = self._seq[channel_id] = self._seq[channel_id] + 1
        rec = _MSG_HEAD.pack(OP_MESSAGE, _MSG_FIXED + len(data), channel_id, seq & 0xFFFFFFFF, log_time, log_time)
        times, offs = self._single.setdefault(channel_id, ([], []))
        times.append(log_time)
        offs.append(self._size)
        self._chunk += rec
        self._chunk += data
        self._size += len(rec) + len(data)
        self._counts[channel_id] += 1
        self._message_count += 1
        if self._start is None or log_time < self._start:
            self._start = log_time
        if self._end is None or log_time > self._end:
            self._end = log_time
        if self._t_min is None or log_time < self._t_min:
            self._t_min = log_time
        if self._t_max is None or log_time > self._t_max:
            self._t_max = log_time
        if self._size >= self.chunk_size:
            self.flush_chunk()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        from mcap.data_stream import RecordBuilder
        from mcap.records import Metadata, MetadataIndex

        self.flush_chunk()
        rb = RecordBuilder()
        Metadata(name=name, metadata=dict(data)).write(rb)
        blob = rb.end()
        offset = self._fh.tell()
        self._fh.write(blob)
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=len(blob), name=name))

    def flush_chunk(self) -> None:
        """Compress and write the open chunk with its message indexes."""
        from mcap.data_stream import RecordBuilder
        from mcap.records import Chunk, ChunkIndex

        if not self._chunk:
            return
        data = self._chunk
        compressed = self._zstd.compress(data)
        start = self._start if self._start is not None else 0
        end = self._end if self._end is not None else 0
        rb = RecordBuilder()
        Chunk(compression="zstd", data=compressed, message_start_time=start, message_end_time=end,
              uncompressed_crc=zlib.crc32(data), uncompressed_size=len(data)).write(rb)
        chunk_blob = rb.end()
        chunk_offset = self._fh.tell()
        self._fh.write(chunk_blob)
        index_offsets: dict[int, int] = {}
        index_start = self._fh.tell()
        for cid, (times, offs) in self._single.items():
            self._index.setdefault(cid, []).append((np.array(times, dtype=np.int64), np.array(offs, dtype=np.int64)))
        for cid in sorted(self._index):
            times = np.concatenate([t for t, _ in self._index[cid]])
            offs = np.concatenate([o for _, o in self._index[cid]])
            order = np.argsort(times, kind="stable")
            entries = np.empty((len(times), 2), dtype="<u8")
            entries[:, 0] = times[order]
            entries[:, 1] = offs[order]
            body = struct.pack("<HI", cid, entries.nbytes) + entries.tobytes()
            index_offsets[cid] = self._fh.tell()
            self._fh.write(struct.pack("<BQ", Opcode.MESSAGE_INDEX, len(body)) + body)
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=start, message_end_time=end, chunk_start_offset=chunk_offset,
            chunk_length=len(chunk_blob), message_index_offsets=index_offsets,
            message_index_length=self._fh.tell() - index_start, compression="zstd",
            compressed_size=len(compressed), uncompressed_size=len(data)))
        self._chunk, self._index, self._single, self._size = bytearray(), {}, {}, 0
        self._start = self._end = None

    def close(self) -> None:
        """Write the last chunk, the summary and the footer (idempotent)."""
        from mcap.data_stream import RecordBuilder
        from mcap.records import DataEnd, Footer, Statistics, SummaryOffset

        if self.closed:
            return
        self.closed = True
        try:
            self.flush_chunk()
            rb = RecordBuilder()
            DataEnd(data_section_crc=0).write(rb)
            self._fh.write(rb.end())
            summary_start = self._fh.tell()
            sb = RecordBuilder()
            offsets = []
            groups = (
                (Opcode.SCHEMA, list(self._schemas.values())),
                (Opcode.CHANNEL, list(self._channels.values())),
                (
                    Opcode.STATISTICS,
                    [
                        Statistics(
                            attachment_count=0,
                            channel_count=len(self._channels),
                            channel_message_counts=dict(self._counts),
                            chunk_count=len(self._chunk_indexes),
                            message_count=self._message_count,
                            message_end_time=self._t_max or 0,
                            message_start_time=self._t_min or 0,
                            metadata_count=len(self._metadata_indexes),
                            schema_count=len(self._schemas),
                        )
                    ],
                ),
                (Opcode.CHUNK_INDEX, self._chunk_indexes),
                (Opcode.METADATA_INDEX, self._metadata_indexes),
            )
            for opcode, records in groups:
                if not records:
                    continue
                g0 = sb.count
                for r in records:
                    r.write(sb)
                offsets.append(
                    SummaryOffset(group_opcode=opcode, group_start=summary_start + g0, group_length=sb.count - g0)
                )
            summary_offset_start = summary_start + sb.count
            for o in offsets:
                o.write(sb)
            summary = sb.end()
            self._fh.write(summary)
            # the summary CRC covers the summary section and the footer's fields before it (MCAP spec)
            footer_head = struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, summary_start, summary_offset_start)
            summary_crc = zlib.crc32(footer_head, zlib.crc32(summary))
            fb = RecordBuilder()
            Footer(summary_start=summary_start, summary_offset_start=summary_offset_start,
                   summary_crc=summary_crc).write(fb)
            self._fh.write(fb.end())
            self._fh.write(MAGIC)
        finally:
            self._fh.flush()
            import os

            os.fsync(self._fh.fileno())
            self._fh.close()
