"""Writing ROS 2 MCAP files from whole numpy arrays of equal-sized messages (no rclpy).

Message records laid out by :mod:`.layout` (the package's one layout of a message record), a chunk
compressed at a time.  Records other than messages are the ``mcap`` library's, except a chunk's head
and its message indexes, packed here from arrays; re-encoded by ``mcap``, a written file is the same
bytes (tested).
"""

from __future__ import annotations

import os
import zlib
from pathlib import Path

import numpy as np
from mcap.opcode import Opcode
from mcap.well_known import Profile

from ..base import atomic
from .layout import lay_out_records
from .records import MAGIC, MESSAGE_FIXED, chunk_head, footer_head, message_index_head

#: records laid out per pass (a few chunks: whole arrays amortise the per-call cost, and a whole
#: recording added at once still costs no more than this beside it)
_PIECE_BYTES = 8 * 1024 * 1024
_MAX_PENDING = 16  #: chunks waiting for the background thread before the caller waits too
#: zstd level of the chunks: a replay's output (Float64 streams, stamped estimates, copied inputs)
#: compresses faster than at level 1 for a file hardly larger (docs/benchmarks.md)
ZSTD_LEVEL = -1
#: a background writer's file is synced to disk every this many bytes, while the caller goes on
_SYNC_BYTES = 32 * 1024 * 1024
_INT64_MIN, _INT64_MAX = -(2**63), 2**63 - 1


def _message_indexes(index: list[tuple[np.ndarray, np.ndarray, np.ndarray]]):
    """A chunk's message index entries from its appended parts ``(channel ids, log times, offsets)``:
    ``(channel id, entries)`` per channel by id, ``entries`` the n × 2 little-endian uint64 (log
    time, offset) of the record format, by log time (the order written among equal times)."""
    if not index:  # a chunk of schema and channel records only
        return
    ids, times, offs = (np.concatenate(column) for column in zip(*index))
    order = np.argsort(ids.astype(np.uint16), kind="stable")  # channel ids are 16-bit: a radix sort
    ids = ids[order]
    entries = np.empty((len(ids), 2), dtype="<u8")
    entries[:, 0] = times[order]
    entries[:, 1] = offs[order]
    cuts = np.flatnonzero(ids[1:] != ids[:-1]) + 1
    starts, stops = [0, *cuts.tolist()], [*cuts.tolist(), len(ids)]
    t = entries[:, 0].view("<i8")
    backwards = set(np.searchsorted(cuts, np.flatnonzero(t[1:] < t[:-1]), side="right").tolist())
    for k, (a, b) in enumerate(zip(starts, stops)):
        part = entries[a:b]
        if k in backwards and (np.diff(t[a:b]) < 0).any():  # not across a cut between channels
            part = part[np.argsort(t[a:b], kind="stable")]
        yield int(ids[a]), part


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
    zstd at :data:`ZSTD_LEVEL`.
    """

    def __init__(self, path: str | Path, chunk_size: int = 1024 * 1024, background: bool = False,
                 replace_atomically: bool = False, durable: bool = False) -> None:
        """``replace_atomically``: written beside ``path`` and renamed onto it by :meth:`close`
        (:mod:`~base.atomic`), so an existing file stays whole until the new one is.  ``durable``: a
        live recording, which a kill may end at any moment -- written under a hidden name until
        :meth:`publish` gives it its own (its header and what was added before on disk), and after
        its header, each metadata record and each chunk the file ends with a provisional summary
        and footer (:meth:`_tail`), overwritten in the same write by what comes next: a
        killed recording is whole up to its last chunk for any MCAP reader."""
        import zstandard
        from mcap.data_stream import RecordBuilder
        from mcap.records import Header

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if durable and (background or replace_atomically):
            raise ValueError("a durable (live) recording is written in the foreground, in place")
        self._partial = atomic.partial_path(self.path) if replace_atomically else None
        self.durable = durable
        #: a durable recording's name until it is published (None: it has its name)
        self._hidden = atomic.partial_path(self.path) if durable else None
        self._fh = (self._partial or self._hidden or self.path).open("wb")
        self._data_end = 0  # a durable recording: where its data section ends (its provisional tail starts)
        self._zstd = zstandard.ZstdCompressor(level=ZSTD_LEVEL)
        # background: one thread compresses and writes finished chunks (zstd, crc32 and file writes
        # release the GIL) while the caller builds the next; for bulk writers (import), not the
        # node's recorder, whose chunks must reach the file as soon as they are full
        self._pool = None
        if background:
            from concurrent.futures import ThreadPoolExecutor

            self._pool = ThreadPoolExecutor(1, thread_name_prefix="mcap-chunks")
        self._pending: list = []
        self._synced = 0  # bytes of the file on disk (a background writer syncs every _SYNC_BYTES)
        self.chunk_size = chunk_size
        self._schemas: dict[int, object] = {}
        self._channels: dict[int, object] = {}
        self._chunk_indexes: list = []
        self._metadata_indexes: list = []
        self._chunk = bytearray()  # record bytes of the open chunk
        # the open chunk's messages: (channel ids, log times, offsets) per part appended
        self._index: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        #: messages added one by one whose records are not laid out yet: (channel id, log time,
        #: publish time, payload); laid out together before anything else enters the chunk
        self._one_by_one: list[tuple[int, int, int, bytes]] = []
        self._one_by_one_bytes = 0  # the size of their records
        self._size = 0
        self._start = self._end = None
        self._seq: dict[int, int] = {}  # messages laid out so far, by channel id (the last sequence number)
        self._period_hint = [0]  # the pattern of payload widths last seen by add_mixed (see layout.interleave)
        self._message_count = 0
        self._t_min: int | None = None
        self._t_max: int | None = None
        self.closed = False
        rb = RecordBuilder()
        Header(profile=Profile.ROS2, library="rollergear_ros").write(rb)
        self._append([MAGIC, rb.end()])

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
        self._seq[cid] = 0
        return cid

    def _write_record(self, record) -> None:
        """Schema/channel records go into the open chunk (as the mcap writer does)."""
        from mcap.data_stream import RecordBuilder

        rb = RecordBuilder()
        record.write(rb)
        data = rb.end()
        self._lay_out_one_by_one()
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
        self.add_mixed(np.broadcast_to(np.asarray(channel_id, dtype=np.int64), (n,)), log_time,
                       np.zeros(n, dtype=np.int64), np.arange(n, dtype=np.int64), [payload])

    def add_mixed(self, channel_id: np.ndarray, log_time: np.ndarray, group: np.ndarray, row: np.ndarray,
                  payloads: list[np.ndarray]) -> None:
        """Add ``n`` messages of several payload widths, in this order: message ``i`` is row
        ``row[i]`` of ``payloads[group[i]]`` (each an m × L uint8 array), on channel
        ``channel_id[i]`` at ``log_time[i]``.  The records are laid out in one pass whatever the
        interleaving (a time-ordered output alternates widths sample by sample), a few MB at a
        time (:func:`lay_out_records`); chunks close at ``chunk_size`` as in :meth:`add_messages`.
        Messages added one by one before come first, laid out in the same pass."""
        if len(log_time) == 0:
            return
        arrays = (np.asarray(channel_id, dtype=np.int64), np.asarray(log_time, dtype=np.int64),
                  np.asarray(group, dtype=np.int64), np.asarray(row, dtype=np.int64), list(payloads), None)
        pending = self._take_one_by_one()
        if pending is not None:  # (a temperature between runs of Float64 arrays: no call of its own)
            ids, times, p_group, p_row, p_payloads, published = pending
            arrays = (np.concatenate([ids, arrays[0]]), np.concatenate([times, arrays[1]]),
                      np.concatenate([p_group, arrays[2] + len(p_payloads)]), np.concatenate([p_row, arrays[3]]),
                      p_payloads + arrays[4], np.concatenate([published, arrays[1]]))
        self._lay_out(*arrays)

    def _lay_out(self, ids: np.ndarray, log_time: np.ndarray, group: np.ndarray, row: np.ndarray,
                 payloads: list[np.ndarray], publish_time: np.ndarray | None) -> None:
        """:meth:`add_mixed` of int64 arrays (``publish_time`` None: the log times)."""
        n = len(log_time)
        rec_of_group = np.array([9 + MESSAGE_FIXED + p.shape[1] for p in payloads], dtype=np.int64)
        ends = np.cumsum(rec_of_group[group])
        start = 0
        while start < n:
            base = int(ends[start - 1]) if start else 0
            stop = min(n, max(start + 1, int(ends.searchsorted(np.int64(base + _PIECE_BYTES), side="right"))))
            sl = slice(start, stop)
            g_sl, ids_sl, t_sl = group[sl], ids[sl], log_time[sl]
            piece_ends = ends[sl] - base
            counters = self._counters()
            records = lay_out_records(piece_ends - rec_of_group[g_sl], int(piece_ends[-1]), ids_sl, t_sl, g_sl,
                                      row[sl], payloads, counters, self._period_hint,
                                      publish_time=None if publish_time is None else publish_time[sl])
            self._seq.update(zip(self._seq, counters[list(self._seq)].tolist()))
            self._append_records(ids_sl, t_sl, records, piece_ends)
            start = stop

    def _append_records(self, ids: np.ndarray, log_time: np.ndarray, records: np.ndarray, ends: np.ndarray) -> None:
        """Append message records (the bytes ``records``; record ``i`` ends at ``ends[i]``) to the
        open chunk, closing it whenever it reaches ``chunk_size``; each chunk is indexed by channel
        when it is written."""
        n = len(ends)
        start, base = 0, 0
        while start < n:
            room = max(1, self.chunk_size - self._size)
            stop = min(n, int(ends.searchsorted(np.int64(base + room))) + 1)  # the record that fills the chunk
            top = int(ends[stop - 1])
            sl = slice(start, stop)
            starts = np.empty(stop - start, dtype=np.int64)
            starts[0] = base
            starts[1:] = ends[start:stop - 1]
            self._index.append((ids[sl], log_time[sl], starts + (self._size - base)))
            if self._size == 0 and top - base >= self.chunk_size:  # a whole chunk: the records are its bytes
                self._chunk = records[base:top]  # (flushed below, before anything else is appended)
            else:
                self._chunk += records[base:top].data
            self._size += top - base
            self._count(stop - start, int(log_time[sl].min()), int(log_time[sl].max()))
            if self._size >= self.chunk_size:
                self.flush_chunk()
            start, base = stop, top

    def _count(self, n: int, lo: int, hi: int) -> None:
        """``n`` messages laid out in the open chunk, their log times from ``lo`` to ``hi``."""
        self._message_count += n
        self._start = lo if self._start is None else min(self._start, lo)
        self._end = hi if self._end is None else max(self._end, hi)
        self._t_min = lo if self._t_min is None else min(self._t_min, lo)
        self._t_max = hi if self._t_max is None else max(self._t_max, hi)

    def _counters(self) -> np.ndarray:
        """The last sequence number of each channel, indexed by channel id (for :func:`lay_out_records`)."""
        counters = np.zeros(max(self._seq, default=0) + 1, dtype=np.int64)
        counters[list(self._seq)] = list(self._seq.values())
        return counters

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int | None = None) -> None:
        """Add one message (for recorders that get messages one by one: a list append here, the
        records laid out together by :func:`lay_out_records` before anything else enters the chunk);
        ``publish_time``: when its publisher sent it (None: ``log_time``)."""
        if channel_id not in self._seq:
            raise ValueError(f"channel {channel_id} is not registered")
        if publish_time is None:
            publish_time = log_time
        # refused here, not when the chunk is laid out: one bad message never costs the others
        if not (_INT64_MIN <= log_time <= _INT64_MAX and _INT64_MIN <= publish_time <= _INT64_MAX):
            raise ValueError(f"log time {log_time} or publish time {publish_time}: not a 64-bit time in ns")
        if type(data) is not bytes:  # a copy of a buffer its owner may change before the layout
            data = bytes(data)
        self._one_by_one.append((channel_id, log_time, publish_time, data))
        self._one_by_one_bytes += 9 + MESSAGE_FIXED + len(data)
        if self._size + self._one_by_one_bytes >= self.chunk_size:
            self.flush_chunk()

    def _lay_out_one_by_one(self) -> None:
        """Append the records of the messages added one by one since the last call to the open chunk."""
        pending = self._take_one_by_one()
        if pending is not None:
            self._lay_out(*pending)

    def _take_one_by_one(self) -> tuple | None:
        """The messages added one by one since the last call as :meth:`_lay_out`'s arrays (one payload
        group per payload width), or None; they are no longer pending."""
        pending, self._one_by_one, self._one_by_one_bytes = self._one_by_one, [], 0
        if not pending:
            return None
        ids, log_times, publish_times, datas = zip(*pending)
        widths = np.fromiter(map(len, datas), dtype=np.int64, count=len(datas))
        unique, group = np.unique(widths, return_inverse=True)
        row = np.empty(len(datas), dtype=np.int64)
        payloads = []
        for g, width in enumerate(unique.tolist()):
            where = np.flatnonzero(group == g)
            payloads.append(np.frombuffer(b"".join([datas[i] for i in where.tolist()]), dtype=np.uint8)
                            .reshape(len(where), width))
            row[where] = np.arange(len(where))
        return (np.array(ids, dtype=np.int64), np.array(log_times, dtype=np.int64), group.astype(np.int64), row,
                payloads, np.array(publish_times, dtype=np.int64))

    @property
    def bytes_written(self) -> int:
        """The file's size so far, with the open chunk (uncompressed) and the chunks being written."""
        return self._position() + self._size + self._one_by_one_bytes

    def _position(self) -> int:
        """Where the next record goes: the end of the data section written so far."""
        return self._data_end if self.durable else self._fh.tell()

    def _append(self, parts: list) -> None:
        """Write records at the end of the data section; a durable recording's with its provisional
        tail after them, in one write (what a kill leaves is the file before it or after it)."""
        if not self.durable:
            for part in parts:
                self._fh.write(part)
            return
        body = sum(memoryview(p).nbytes for p in parts)
        tail = self._tail(self._data_end + body, chunk_indexes=False)
        self._fh.seek(self._data_end)
        self._fh.write(b"".join([*parts, tail]))
        self._fh.truncate()
        self._fh.flush()
        self._data_end += body

    def _tail(self, data_end: int, chunk_indexes: bool = True) -> bytes:
        """The data-end record, the summary section, the footer and the closing magic after a data
        section that ends at byte ``data_end`` (:meth:`_summary`); without ``chunk_indexes`` the
        provisional one of a durable recording (what is on disk: a reader then reads the chunks front
        to back)."""
        from mcap.data_stream import RecordBuilder
        from mcap.records import DataEnd, Footer

        rb = RecordBuilder()
        DataEnd(data_section_crc=0).write(rb)
        head = rb.end()
        summary_start = data_end + len(head)
        summary, summary_offset_start = self._summary(summary_start, chunk_indexes)
        # the summary CRC covers the summary section and the footer's fields before it (MCAP spec)
        summary_crc = zlib.crc32(footer_head(summary_start, summary_offset_start), zlib.crc32(summary))
        fb = RecordBuilder()
        Footer(summary_start=summary_start, summary_offset_start=summary_offset_start,
               summary_crc=summary_crc).write(fb)
        return head + summary + fb.end() + MAGIC

    def publish(self, path: str | Path | None = None) -> Path:
        """A durable recording takes its name (``path``, else the one it was opened for) once what was
        added so far is on disk: never a file by that name without its header and metadata.  A name
        that exists meanwhile raises ``FileExistsError`` (nothing is overwritten); returns the name."""
        if self._hidden is None:
            return self.path
        target = Path(path) if path is not None else self.path
        with atomic.named(target):
            if not self._fh.closed:  # (closed: close synced it, and publishes it now)
                self.flush_chunk()
                self._fh.flush()
                os.fsync(self._fh.fileno())
            try:
                os.link(self._hidden, target)  # fails where the name exists: never overwrites
            except FileExistsError:
                raise
            except OSError:  # a file system without hard links: the name checked, then renamed
                if target.exists() or target.is_symlink():
                    raise FileExistsError(17, "File exists", str(target)) from None
                os.replace(self._hidden, target)
            else:
                os.unlink(self._hidden)
        self.path, self._hidden = target, None
        return target

    @property
    def channel_counts(self) -> dict[int, int]:
        """Messages added so far, by channel id (the Statistics record's)."""
        counts = dict(self._seq)
        for cid, *_ in self._one_by_one:
            counts[cid] += 1
        return counts

    @property
    def log_time_range(self) -> tuple[int, int] | None:
        """First and last log time added so far (None before the first message)."""
        times = [t for _, t, _, _ in self._one_by_one] + ([] if self._t_min is None else [self._t_min, self._t_max])
        return (min(times), max(times)) if times else None

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        from mcap.data_stream import RecordBuilder
        from mcap.records import Metadata, MetadataIndex

        self.flush_chunk()
        self._drain()
        rb = RecordBuilder()
        Metadata(name=name, metadata=dict(data)).write(rb)
        blob = rb.end()
        self._metadata_indexes.append(MetadataIndex(offset=self._position(), length=len(blob), name=name))
        self._append([blob])

    def flush_chunk(self) -> None:
        """Compress and write the open chunk with its message indexes (in the background with
        ``background=True``: the next chunk is built while this one is compressed and written)."""
        self._lay_out_one_by_one()  # (which closes the chunk itself where they fill it)
        if not self._size:
            return
        job = (self._chunk, self._index, self._start if self._start is not None else 0,
               self._end if self._end is not None else 0)
        self._chunk, self._index, self._size = bytearray(), [], 0
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

    def _emit(self, data: bytearray | np.ndarray, index: list, start: int, end: int) -> None:
        """Compress one chunk and write it and its message indexes (the only writer of the file while
        chunks are pending); a write that fails is an OSError naming the file."""
        with atomic.named(self.path):
            self._emit_chunk(data, index, start, end)
            if self._pool is not None and self._fh.tell() - self._synced >= _SYNC_BYTES:
                self._fh.flush()  # on disk as it goes: close's fsync has only the last few MB to wait for
                os.fdatasync(self._fh.fileno())
                self._synced = self._fh.tell()

    def _emit_chunk(self, data: bytearray | np.ndarray, index: list, start: int, end: int) -> None:
        """The chunk record (fields as ``mcap.records.Chunk`` writes them) and one message index record
        per channel, each written as its head and its body, without joining them first."""
        from mcap.records import ChunkIndex

        compressed = self._zstd.compress(data)
        chunk_offset = at = self._position()
        parts = [chunk_head(start, end, len(data), zlib.crc32(data), len(compressed)), compressed]
        at += len(parts[0]) + len(compressed)
        chunk_length = at - chunk_offset
        index_offsets: dict[int, int] = {}
        for cid, entries in _message_indexes(index):
            index_offsets[cid] = at
            parts += [message_index_head(cid, entries.nbytes), entries]
            at += len(parts[-2]) + entries.nbytes
        self._append(parts)
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=start, message_end_time=end, chunk_start_offset=chunk_offset,
            chunk_length=chunk_length, message_index_offsets=index_offsets,
            message_index_length=at - chunk_offset - chunk_length, compression="zstd",
            compressed_size=len(compressed), uncompressed_size=len(data)))

    def close(self, commit: bool = True) -> None:
        """Write the last chunk, the summary and the footer (idempotent); with
        ``replace_atomically``, put the file in place -- or, ``commit=False`` (the command failed),
        remove it and leave an existing file as it was."""
        if self.closed:
            return
        self.closed = True
        try:
            with atomic.named(self.path):
                self._close()
        except BaseException:
            if self._partial is not None:
                atomic.discard(self._partial)
            raise
        if self._partial is not None:
            if commit:
                atomic.commit(self._partial, self.path)
            else:
                atomic.discard(self._partial)

    def _close(self) -> None:
        try:
            self.flush_chunk()
            self._drain()  # on an error, the pool's shutdown below still waits for the other chunks
            end = self._position()
            self._fh.seek(end)  # a durable recording: its full tail over the provisional one, in one write
            self._fh.write(self._tail(end))
            self._fh.truncate()
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True)
            self._fh.flush()
            os.fsync(self._fh.fileno())
            self._fh.close()
        if self._hidden is not None:  # closed before it was published: it takes its name now
            self.publish()

    def _summary(self, summary_start: int, chunk_indexes: bool = True) -> tuple[bytes, int]:
        """The summary section (schemas, channels, statistics, chunk and metadata indexes, and the
        summary offsets of each group) for a summary that starts at byte ``summary_start``;
        returns it and where its summary offsets start."""
        from mcap.data_stream import RecordBuilder
        from mcap.records import Statistics, SummaryOffset

        sb = RecordBuilder()
        offsets = []
        statistics = Statistics(
            attachment_count=0,
            channel_count=len(self._channels),
            channel_message_counts=dict(self._seq),
            chunk_count=len(self._chunk_indexes),
            message_count=self._message_count,
            message_end_time=self._t_max or 0,
            message_start_time=self._t_min or 0,
            metadata_count=len(self._metadata_indexes),
            schema_count=len(self._schemas),
        )
        groups = (
            (Opcode.SCHEMA, list(self._schemas.values())),
            (Opcode.CHANNEL, list(self._channels.values())),
            (Opcode.STATISTICS, [statistics]),
            (Opcode.CHUNK_INDEX, self._chunk_indexes if chunk_indexes else []),
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
        return sb.end(), summary_offset_start
