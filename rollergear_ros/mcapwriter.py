"""Writing ROS 2 MCAP files from whole numpy arrays of equal-sized messages (no rclpy).

One message record per row of a uint8 array, a chunk compressed at a time; the file structure is
the ``mcap`` library writer's (tested against ``mcap`` and ``rosbags``).
"""

from __future__ import annotations

import struct
import zlib
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from mcap.opcode import Opcode
from mcap.well_known import Profile
from mcap.writer import MCAP0_MAGIC as MAGIC

from .fastmcap import _MSG_FIXED, _MSG_HEAD, OP_MESSAGE

_MAX_PENDING = 4  #: chunks waiting for the background thread before the caller waits too


@contextmanager
def _named(path: Path):
    """OSErrors of writes (a full disk: ENOSPC carries no file name) name the file written."""
    try:
        yield
    except OSError as exc:
        if exc.filename is not None:
            raise
        raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from exc


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
                 library: str = "rollergear_ros", compression_level: int = 1, background: bool = False) -> None:
        import zstandard
        from mcap.data_stream import RecordBuilder
        from mcap.records import Header

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = self.path.open("wb")
        self._zstd = zstandard.ZstdCompressor(level=compression_level)
        # background: one thread compresses and writes finished chunks (zstd, crc32 and file writes
        # release the GIL) while the caller builds the next; for bulk writers (import), not the
        # node's recorder, whose chunks must reach the file as soon as they are full
        self._pool = None
        if background:
            from concurrent.futures import ThreadPoolExecutor

            self._pool = ThreadPoolExecutor(1, thread_name_prefix="mcap-chunks")
        self._pending: list = []
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
        A chunk is closed whenever it reaches ``chunk_size``, also inside one call (so that no chunk
        spans a whole recording added at once).
        """
        n = len(log_time)
        if n == 0:
            return
        log_time = np.asarray(log_time, dtype=np.int64)
        ids = np.broadcast_to(np.asarray(channel_id, dtype=np.int64), (n,))
        rec = 9 + _MSG_FIXED + payload.shape[1]
        start = 0
        while start < n:
            stop = min(n, start + max(1, -(-(self.chunk_size - self._size) // rec)))
            self._add_rows(ids[start:stop], log_time[start:stop], payload[start:stop])
            start = stop

    def _add_rows(self, ids: np.ndarray, log_time: np.ndarray, payload: np.ndarray) -> None:
        n = len(log_time)
        rows = message_rows(ids, log_time, payload)
        rec = rows.shape[1]
        offsets = self._size + rec * np.arange(n, dtype=np.int64)
        if ids[0] == ids[-1] and (ids == ids[0]).all():  # one topic
            cid = int(ids[0])
            seq = self._seq[cid] + np.arange(1, n + 1, dtype=np.int64)
            self._seq[cid] += n
            self._counts[cid] += n
            self._index.setdefault(cid, []).append((log_time, offsets))
        else:  # interleaved topics: each one's sequence numbers count on, its messages indexed apart
            seq = np.empty(n, dtype=np.int64)
            per_channel = np.bincount(ids)
            for cid in np.flatnonzero(per_channel).tolist():
                where = np.flatnonzero(ids == cid)
                k = len(where)
                seq[where] = np.arange(self._seq[cid] + 1, self._seq[cid] + k + 1, dtype=np.int64)
                self._seq[cid] += k
                self._counts[cid] += k
                self._index.setdefault(cid, []).append((log_time[where], offsets[where]))
        rows[:, 11:15] = (seq & 0xFFFFFFFF).astype("<u4").view(np.uint8).reshape(n, 4)
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

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int | None = None) -> None:
        """Add one message (plain Python: ~1 µs, for recorders that get messages one by one);
        ``publish_time``: when its publisher sent it (None: ``log_time``)."""
        seq = self._seq[channel_id] = self._seq[channel_id] + 1
        rec = _MSG_HEAD.pack(OP_MESSAGE, _MSG_FIXED + len(data), channel_id, seq & 0xFFFFFFFF, log_time,
                             log_time if publish_time is None else publish_time)
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

    @property
    def channel_counts(self) -> dict[int, int]:
        """Messages written so far, by channel id (the Statistics record's)."""
        return dict(self._counts)

    @property
    def log_time_range(self) -> tuple[int, int] | None:
        """First and last log time written so far (None before the first message)."""
        return None if self._t_min is None else (self._t_min, self._t_max)

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        from mcap.data_stream import RecordBuilder
        from mcap.records import Metadata, MetadataIndex

        self.flush_chunk()
        self._drain()
        rb = RecordBuilder()
        Metadata(name=name, metadata=dict(data)).write(rb)
        blob = rb.end()
        offset = self._fh.tell()
        self._fh.write(blob)
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=len(blob), name=name))

    def flush_chunk(self) -> None:
        """Compress and write the open chunk with its message indexes (in the background with
        ``background=True``: the next chunk is built while this one is compressed and written)."""
        if not self._chunk:
            return
        for cid, (times, offs) in self._single.items():
            self._index.setdefault(cid, []).append((np.array(times, dtype=np.int64), np.array(offs, dtype=np.int64)))
        job = (self._chunk, self._index, self._start if self._start is not None else 0,
               self._end if self._end is not None else 0)
        self._chunk, self._index, self._single, self._size = bytearray(), {}, {}, 0
        self._start = self._end = None
        if self._pool is None:
            self._emit(*job)
            return
        self._pending.append(self._pool.submit(self._emit, *job))
        while len(self._pending) > _MAX_PENDING or (self._pending and self._pending[0].done()):
            self._pending.pop(0).result()  # an error of the writing thread is raised here

    def _drain(self) -> None:
        """Wait for the chunks being written in the background (their errors are raised here)."""
        while self._pending:
            self._pending.pop(0).result()

    def _emit(self, data: bytearray, index: dict, start: int, end: int) -> None:
        """Compress one chunk and write it and its message indexes (the only writer of the file while
        chunks are pending); a write that fails is an OSError naming the file."""
        with _named(self.path):
            self._emit_chunk(data, index, start, end)

    def _emit_chunk(self, data: bytearray, index: dict, start: int, end: int) -> None:
        from mcap.data_stream import RecordBuilder
        from mcap.records import Chunk, ChunkIndex

        compressed = self._zstd.compress(data)
        rb = RecordBuilder()
        Chunk(compression="zstd", data=compressed, message_start_time=start, message_end_time=end,
              uncompressed_crc=zlib.crc32(data), uncompressed_size=len(data)).write(rb)
        chunk_blob = rb.end()
        chunk_offset = self._fh.tell()
        self._fh.write(chunk_blob)
        index_offsets: dict[int, int] = {}
        index_start = self._fh.tell()
        for cid in sorted(index):
            parts = index[cid]
            times = np.concatenate([t for t, _ in parts]) if len(parts) > 1 else parts[0][0]
            offs = np.concatenate([o for _, o in parts]) if len(parts) > 1 else parts[0][1]
            entries = np.empty((len(times), 2), dtype="<u8")
            if len(times) > 1 and np.any(times[1:] < times[:-1]):  # the index is by log time
                order = np.argsort(times, kind="stable")
                times, offs = times[order], offs[order]
            entries[:, 0] = times
            entries[:, 1] = offs
            body = struct.pack("<HI", cid, entries.nbytes) + entries.tobytes()
            index_offsets[cid] = self._fh.tell()
            self._fh.write(struct.pack("<BQ", Opcode.MESSAGE_INDEX, len(body)) + body)
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=start, message_end_time=end, chunk_start_offset=chunk_offset,
            chunk_length=len(chunk_blob), message_index_offsets=index_offsets,
            message_index_length=self._fh.tell() - index_start, compression="zstd",
            compressed_size=len(compressed), uncompressed_size=len(data)))

    def close(self) -> None:
        """Write the last chunk, the summary and the footer (idempotent)."""
        if self.closed:
            return
        self.closed = True
        with _named(self.path):
            self._close()

    def _close(self) -> None:
        from mcap.data_stream import RecordBuilder
        from mcap.records import DataEnd, Footer, Statistics, SummaryOffset

        try:
            self.flush_chunk()
            self._drain()  # on an error, the pool's shutdown below still waits for the other chunks
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
            if self._pool is not None:
                self._pool.shutdown(wait=True)
            self._fh.flush()
            import os

            os.fsync(self._fh.fileno())
            self._fh.close()


class TimeOrderBuffer:
    """Holds messages back and hands them to a :class:`ChunkedMcapWriter` in log-time order.

    Streaming readers (Foxglove, ``ros2 bag play``) read a file front to back and want its messages
    in log-time order across topics; a replay produces each batch's estimates topic by topic, and a
    sample completes a little after its inputs arrived.  :meth:`release` writes what is older than a
    watermark (nothing later can be older than that), :meth:`release` with none writes the rest.
    Equal-sized payloads stay numpy arrays throughout; messages of other sizes go one by one.
    """

    def __init__(self, writer: ChunkedMcapWriter) -> None:
        self._writer = writer
        self._fixed: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (channel ids, log times, payload rows)
        self._single: list[tuple[int, int, bytes, int | None]] = []  # (channel id, log time, payload, publish time)

    def __len__(self) -> int:
        return sum(len(t) for _, t, _ in self._fixed) + len(self._single)

    def add_messages(self, channel_id: int | np.ndarray, log_time: np.ndarray, payload: np.ndarray) -> None:
        log_time = np.asarray(log_time, dtype=np.int64)
        ids = np.broadcast_to(np.asarray(channel_id, dtype=np.int64), log_time.shape).copy()
        if len(log_time):
            self._fixed.append((ids, log_time, payload))

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int | None = None) -> None:
        self._single.append((channel_id, log_time, data, publish_time))

    def release(self, up_to_ns: int | None = None) -> None:
        """Write, in log-time order (the order added among equal times), every message whose log
        time is at most ``up_to_ns`` (all of them when None); keep the rest."""
        if not self._fixed and not self._single:
            return
        groups: dict[int, list] = {}
        for ids, t, pl in self._fixed:
            groups.setdefault(pl.shape[1], []).append((ids, t, pl))
        merged = [tuple(np.concatenate(parts) for parts in zip(*items)) for items in groups.values()]
        single = self._single
        times = [t for _, t, _ in merged] + [np.array([m[1] for m in single], dtype=np.int64)]
        source = np.concatenate([np.full(len(t), g, dtype=np.int64) for g, t in enumerate(times[:-1])]
                                + [np.full(len(single), -1, dtype=np.int64)])
        index = np.concatenate([np.arange(len(t), dtype=np.int64) for t in times])
        t_all = np.concatenate(times)
        order = np.argsort(t_all, kind="stable")
        n_out = len(order) if up_to_ns is None else int(np.searchsorted(t_all[order], up_to_ns, side="right"))
        out = order[:n_out]
        src, idx = source[out], index[out]
        starts = np.concatenate([[0], np.flatnonzero(np.diff(src)) + 1, [len(out)]]).tolist() if len(out) else [0]
        for a, b in zip(starts[:-1], starts[1:]):
            g = int(src[a])
            if g < 0:
                for j in idx[a:b].tolist():
                    self._writer.add_message(*single[j])
            else:
                ids, t, pl = merged[g]
                sel = idx[a:b]
                self._writer.add_messages(ids[sel], t[sel], pl[sel])
        rest = order[n_out:]
        self._fixed = []
        for g, (ids, t, pl) in enumerate(merged):
            sel = np.sort(index[rest][source[rest] == g])
            if len(sel):
                self._fixed.append((ids[sel], t[sel], pl[sel]))
        self._single = [single[j] for j in np.sort(index[rest][source[rest] == -1]).tolist()]
