"""Fast MCAP reading: whole chunks parsed with numpy instead of one Python object per message.

The ``mcap`` reader builds a record object per message (~5 µs each).  Here a chunk's message
records are found in one pass of C (or, in a build without a compiler, run by run with numpy:
recorders write long runs of equal-sized records), and the channel ids, log times and payload
offsets come out as arrays.  Reads linearly (no index needed), so a truncated recording yields
every complete chunk before the damage; what it had to skip is said (:mod:`.damage`).  The records'
fields are read as :mod:`.records` frames them.  No rclpy.
"""

from __future__ import annotations

import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Iterator

import numpy as np

from ..base.errors import BagError
from .damage import DamagedSpan, close_gap, find_next_chunk, record_damage
from .records import (CHANNEL_FIXED, MAGIC, MESSAGE_FIXED, MIN_OTHER_RECORD, OP_CHANNEL, OP_CHUNK, OP_DATA_END,
                      OP_FOOTER, OP_MESSAGE, OP_MESSAGE_INDEX, OP_SCHEMA, SCHEMA_FIXED, byte_rows, message_fields,
                      message_index_count, read_channel, read_chunk_head, read_schema)

try:  # the chunk's records found in C (built by setup.py where a compiler is found)
    from ._records import scan as _native_scan
except ImportError:  # pragma: no cover - a build without a compiler: numpy finds them
    _native_scan = None


@dataclass
class MessageArrays:
    """Messages of one chunk, in file order: payload ``i`` is ``buf[offset[i]:offset[i]+length[i]]``."""

    channel: np.ndarray  # uint16
    log_time: np.ndarray  # int64
    offset: np.ndarray  # int64
    length: np.ndarray  # int64
    buf: np.ndarray  # uint8 view of the decompressed chunk
    #: int64, when each message's publisher sent it (recorders that know no better write the log time)
    publish_time: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.channel)

    def payload(self, i: int) -> bytes:
        o = int(self.offset[i])
        return self.buf[o:o + int(self.length[i])].tobytes()

    def float64(self, rows: np.ndarray) -> np.ndarray:
        """Decode the given rows as little-endian CDR Float64 payloads (12 bytes), vectorised."""
        off = self.offset[rows]
        if not (np.all(self.length[rows] >= 12) and np.all(self.buf[off + 1] == 1) and not self.buf[off].any()):
            raise ValueError("not little-endian Float64 CDR payloads")
        return byte_rows(self.buf, 8)[off + 4].view("<f8").ravel()


_LOOSE_BLOCK = 1 << 20  # messages outside chunks are parsed this many bytes at a time
_SCAN_WINDOW = 1 << 22  # resynchronisation scans the file in windows of this size


@dataclass
class ReadState:
    """What a linear read has seen so far: schemas, channels, and every damaged span it skipped."""

    schemas: dict[int, tuple[str, str, bytes]] = field(default_factory=dict)  # id -> (name, encoding, data)
    channels: dict[int, tuple[str, int, str]] = field(default_factory=dict)  # id -> (topic, schema id, encoding)
    bytes_read: int = 0
    truncated: bool = False  #: the read did not reach the data-end record
    problem: str = ""  #: why it did not
    damaged: list[DamagedSpan] = field(default_factory=list)
    bad_log_times: int = 0  #: messages skipped because their log time is beyond 2⁶³ − 1 ns
    last_log_time: int | None = None  #: of the last message yielded
    #: read only the chunks whose messages may lie in this ``(first, last)`` log-time range (each
    #: chunk's header says its range; the others are skipped unread: a time slice of a long recording)
    log_time_range: tuple[int, int] | None = None
    chunks_skipped: int = 0  #: chunks outside ``log_time_range``, not read

    def damage_report(self) -> list[str]:
        """One line per damaged span, and one for skipped log times."""
        lines = [s.text() for s in self.damaged]
        if self.bad_log_times:
            lines.append(f"{self.bad_log_times:,} messages with a log time beyond 2^63 - 1 ns skipped")
        return lines


def parse_records(data: bytes, state: ReadState, native: bool | None = None) -> MessageArrays:
    """Parse a chunk's records; schema and channel records update ``state``.

    The records are found by a C function where the package was built with one (``_records.c``),
    else with numpy (``native``: force one or the other; the same result either way); the fields of
    every message of the chunk are then gathered at once."""
    buf = np.frombuffer(data, dtype=np.uint8)
    if native is None:
        native = _native_scan is not None
    starts, rec = (_native_message_starts if native else _numpy_message_starts)(data, buf, state)
    if not len(starts):
        e = np.empty(0, dtype=np.int64)
        return MessageArrays(np.empty(0, dtype=np.uint16), e, e, e, buf, e)
    channel, log_time, offset, length, publish_time = message_fields(buf, starts, rec)
    arrays = MessageArrays(channel, log_time, offset, length, buf, publish_time)
    bad = arrays.log_time < 0  # unsigned log times beyond 2⁶³ − 1: no ROS time, and no int64 to compute with
    if bad.any():
        state.bad_log_times += int(bad.sum())
        keep = ~bad
        arrays = MessageArrays(arrays.channel[keep], arrays.log_time[keep], arrays.offset[keep],
                               arrays.length[keep], buf, arrays.publish_time[keep])
    return arrays


def _other_record(op: int, body: bytes, state: ReadState) -> None:
    """A chunk's record other than a message: schemas and channels update ``state``."""
    if op == OP_SCHEMA:
        sid, schema = read_schema(body)
        state.schemas[sid] = schema
    elif op == OP_CHANNEL:
        cid, channel = read_channel(body)
        state.channels[cid] = channel


def _native_message_starts(data: bytes, buf: np.ndarray, state: ReadState) -> tuple[np.ndarray, np.ndarray]:
    """(start, record length) of each message record of a chunk, found by the C scan (schema and
    channel records update ``state``; records of other opcodes are skipped, opcode 0 is damage)."""
    starts = np.empty(len(data) // (9 + MESSAGE_FIXED) + 1, dtype=np.int64)
    others = np.empty(len(data) // MIN_OTHER_RECORD + 1, dtype=np.int64)
    count, n_others = _native_scan(buf, starts, others)
    for pos in others[:n_others].tolist():
        length = int.from_bytes(data[pos + 1:pos + 9], "little")
        _other_record(data[pos], data[pos + 9:pos + 9 + length], state)
    starts = starts[:count]
    return starts, 9 + byte_rows(buf, 8)[starts + 1].view("<i8").ravel()


def _numpy_message_starts(data: bytes, buf: np.ndarray, state: ReadState) -> tuple[np.ndarray, np.ndarray]:
    """(start, record length) of each message record of a chunk, found with numpy: message records
    come in runs of one length (a recorder's Float64 topics, broken by the odd message of another
    type), each run found with a few vectorised checks of its records' heads."""
    n = len(data)
    pos = 0
    runs: list[tuple[int, int, int]] = []  # (first record's position, records, record length)
    step = 64  # the window of the first check: the last run's length (runs repeat)
    while pos + 9 <= n:
        op = data[pos]
        ln = int.from_bytes(data[pos + 1:pos + 9], "little")
        rec = 9 + ln
        if pos + rec > n:
            raise ValueError("record runs past the end of its chunk")
        if op == 0:
            raise ValueError("invalid record (opcode 0)")
        if op in (OP_SCHEMA, OP_CHANNEL):
            if ln < (SCHEMA_FIXED if op == OP_SCHEMA else CHANNEL_FIXED):
                raise ValueError("schema or channel record shorter than its fields")
            _other_record(op, data[pos + 9:pos + rec], state)
            pos += rec
            continue
        if op == OP_MESSAGE and ln < MESSAGE_FIXED:
            raise ValueError("message record shorter than a message's fields")
        # a run of records with the same opcode and length, checked in growing windows: a recorder's
        # messages of one type -- or records of an opcode the spec says to skip, skipped as a run
        avail = (n - pos) // rec
        head = buf[pos:pos + 9]
        m, window = 1, step
        while m < avail:
            k = min(window, avail - m)
            rows = buf[pos + m * rec:pos + (m + k) * rec].reshape(k, rec)
            bad = np.flatnonzero(~(rows[:, :9] == head).all(axis=1))
            if len(bad):
                m += int(bad[0])
                break
            m += k
            window *= 2
        if op == OP_MESSAGE:
            runs.append((pos, m, rec))
            step = max(64, m)
        pos += m * rec
    if not runs:
        e = np.empty(0, dtype=np.int64)
        return e, e
    run_pos, run_m, run_rec = (np.array(column, dtype=np.int64) for column in zip(*runs))
    first = np.cumsum(run_m) - run_m
    starts = np.repeat(run_pos, run_m) + (np.arange(int(run_m.sum()), dtype=np.int64)
                                          - np.repeat(first, run_m)) * np.repeat(run_rec, run_m)
    return starts, np.repeat(run_rec, run_m)


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    """Decompress a chunk's records into at most ``size`` bytes (more is damage, not memory spent)."""
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard

        declared = zstandard.frame_content_size(data)
        if declared not in (-1, size):
            raise ValueError(f"zstd frame holds {declared:,} bytes, the chunk declares {size:,}")
        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    import lz4.frame

    return lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1)


def chunk_records(body: bytes) -> bytes:
    """The records inside a chunk record's body: decompressed within bounds, size and CRC checked."""
    _s, _e, size, crc, compression, p, n = read_chunk_head(body)
    try:
        data = _decompress(compression, body[p:p + n], size)
    except Exception as exc:  # noqa: BLE001 - each codec raises its own error class
        raise ValueError(f"{compression} decompression failed ({exc})") from None
    if len(data) != size:
        raise ValueError(f"chunk decompresses to {len(data):,} bytes, declares {size:,}")
    if crc and zlib.crc32(data) != crc:  # 0: the writer computed none
        raise ValueError(f"chunk CRC mismatch (stored {crc:#010x}, data {zlib.crc32(data):#010x})")
    return data


def _loose_records(fh, pos: int, file_size: int) -> bytes:
    """A run of schema, channel and message records outside chunks starting at ``pos`` (whole
    records, up to about :data:`_LOOSE_BLOCK` bytes), so unchunked files parse in runs too."""
    fh.seek(pos)
    block = fh.read(min(_LOOSE_BLOCK, file_size - pos))
    p = 0
    while p + 9 <= len(block):
        ln = int.from_bytes(block[p + 1:p + 9], "little")
        if block[p] not in (OP_MESSAGE, OP_SCHEMA, OP_CHANNEL) or p + 9 + ln > len(block):
            break
        p += 9 + ln
    if p == 0:  # one record larger than the block (its length is within the file: checked by the caller)
        fh.seek(pos)
        return fh.read(9 + int.from_bytes(block[1:9], "little"))
    return block[:p]


def preload_summary(path: str | Path, state: ReadState) -> None:
    """Take the schemas and channels of the file's summary, when it has a readable one: a damaged
    chunk may have held the only schema or channel record of messages in later chunks."""
    from mcap.reader import make_reader

    try:
        with Path(path).open("rb") as fh:
            summary = make_reader(fh).get_summary()
    except Exception:  # noqa: BLE001 - no usable summary: the records in the data section will do
        return
    if summary is None:
        return
    for s in summary.schemas.values():
        state.schemas.setdefault(s.id, (s.name, s.encoding, s.data))
    for c in summary.channels.values():
        state.channels.setdefault(c.id, (c.topic, c.schema_id, c.message_encoding))


def iter_message_arrays(path: str | Path, state: ReadState | None = None) -> Iterator[MessageArrays]:
    """Linear read of an MCAP file, one :class:`MessageArrays` per chunk (or per run of loose messages).

    Every length a record declares is bounded by the file size (and a chunk's decompressed size by
    :data:`MAX_CHUNK_BYTES`) before anything is allocated; chunk CRCs are verified.  A damaged
    record is skipped: the read resumes at the next chunk (found by :func:`find_next_chunk`) and
    the skipped span — bytes, log times, messages lost when the chunk's message index tells — is
    added to ``state.damaged``.  A file that ends early sets ``state.truncated``.
    """
    state = state if state is not None else ReadState()
    path = Path(path)
    if not path.is_file():
        raise BagError(f"{path} is not a regular file")
    with path.open("rb") as fh:
        file_size = os.fstat(fh.fileno()).st_size
        if fh.read(8) != MAGIC:
            raise BagError(f"{path} is not an MCAP file")
        reader = _LinearRead(fh, file_size, state)
        while reader.pos is not None:
            arrays = reader.next_record()
            if arrays is not None and len(arrays):
                close_gap(state, int(arrays.log_time.min()))
                state.last_log_time = int(arrays.log_time.max())
                yield arrays
        close_gap(state, None)


class _LinearRead:
    """:func:`iter_message_arrays`' walk through the records: where it is (``pos``, None at the
    end) and the damaged span whose chunk's message-index records may still follow."""

    def __init__(self, fh, file_size: int, state: ReadState) -> None:
        self.fh, self.file_size, self.state = fh, file_size, state
        self.pos: int | None = 8
        self.after_damage: DamagedSpan | None = None  # message-index records right after it count its losses
        #: the chunk just read, its message-index records still to come: [start, end, messages read,
        #: first and last log time read, messages its index lists]
        self.after_chunk: list | None = None

    def _check_chunk(self) -> None:
        """The chunk just read against its message index: messages the index lists that the chunk's
        records did not hold (an empty record, a record whose length swallows the rest) are lost,
        a damaged span of their own (the chunk's CRC may be 0, "not computed", or hold the damage)."""
        chunk, self.after_chunk = self.after_chunk, None
        if chunk is None or chunk[5] <= chunk[2]:
            return
        start, end, read, first_ns, last_ns, listed = chunk
        span = record_damage(self.state, start, end, f"the chunk holds {read:,} readable messages, its message "
                             f"index lists {listed:,}", self.fh, end - start - 9)
        span.messages_lost = listed - read
        if span.start_ns is None:
            span.start_ns, span.end_ns = first_ns, last_ns

    def next_record(self) -> MessageArrays | None:
        """Read the record at ``pos`` and move past it: its messages (a chunk, a run of loose
        messages), or None (another record, a damaged one skipped, the end)."""
        fh, state, pos, file_size = self.fh, self.state, self.pos, self.file_size
        if pos + 9 > file_size:
            self._check_chunk()
            state.truncated = True
            state.problem = "file ends without a data-end record"
            if pos < file_size:
                record_damage(state, pos, file_size, "the file ends inside a record")
            self.pos = None
            return None
        fh.seek(pos)
        head = fh.read(9)
        op = head[0]
        if self.after_chunk is not None and op != OP_MESSAGE_INDEX:  # the chunk before has its index behind it
            self._check_chunk()
            fh.seek(pos + 9)  # (a damaged span's log times were read from the chunk's head)
        ln = int.from_bytes(head[1:], "little")
        end = pos + 9 + ln
        if op == 0 or end > file_size:
            self._skip_invalid(op, ln, end)
            return None
        try:
            arrays = None
            if op == OP_CHUNK:
                if state.log_time_range is not None and _outside(fh.read(64), ln, state.log_time_range):
                    state.chunks_skipped += 1
                    state.bytes_read = self.pos = end
                    return None
                fh.seek(pos + 9)
                skipped = state.bad_log_times  # messages found but skipped for their log time are no loss
                arrays = parse_records(chunk_records(fh.read(ln)), state)
                times = arrays.log_time
                first, last = (int(times.min()), int(times.max())) if len(times) else (None, None)
                self.after_chunk = [pos, end, len(arrays) + state.bad_log_times - skipped, first, last, 0]
            elif op == OP_MESSAGE_INDEX and self.after_chunk is not None:
                count = message_index_count(fh.read(6), ln)  # its head tells the entries: not read
                if count is not None:
                    self.after_chunk[5] += count
                state.bytes_read = self.pos = end
                return None
            elif op in (OP_MESSAGE, OP_SCHEMA, OP_CHANNEL):
                run = _loose_records(fh, pos, file_size)
                arrays = parse_records(run, state)
                end = pos + len(run)
            elif op == OP_MESSAGE_INDEX and self.after_damage is not None:
                count = message_index_count(fh.read(6), ln)
                if count is not None:
                    self.after_damage.messages_lost = (self.after_damage.messages_lost or 0) + count
                self.pos = end
                return None
            elif op in (OP_DATA_END, OP_FOOTER):
                state.bytes_read = end
                self.pos = None
                return None
        except Exception as exc:  # noqa: BLE001 - damaged data (bad fields, decompression, CRC): skip the record
            self.after_damage = record_damage(state, pos, end, str(exc) or type(exc).__name__,
                                              fh if op == OP_CHUNK else None, ln)
            self.pos = end
            return None
        self.after_damage = None
        state.bytes_read = self.pos = end
        return arrays

    def _skip_invalid(self, op: int, ln: int, end: int) -> None:
        """A record with opcode 0 or longer than the file: resume at the next chunk, or stop."""
        fh, state, pos, file_size = self.fh, self.state, self.pos, self.file_size
        nxt = find_next_chunk(fh, pos + 1, file_size)
        if op == 0:
            reason = "invalid record (opcode 0)"
        elif nxt is None:
            reason = "the file ends inside this record (cut short)"
        else:
            reason = f"a record declares {ln:,} bytes, beyond the end of the file"
        self.after_damage = record_damage(state, pos, nxt if nxt is not None else file_size, reason,
                                          fh if op == OP_CHUNK and end > file_size else None, ln)
        if nxt is None:
            state.truncated = True
            state.problem = f"{reason} (byte {pos:,}); nothing readable after it"
        self.pos = nxt


def _outside(head: bytes, record_length: int, log_time_range: tuple[int, int]) -> bool:
    """Whether a chunk (``head``: the start of its record) holds only messages outside the range;
    a header that cannot be read says nothing (the chunk is read, and its damage reported)."""
    try:
        start_ns, end_ns = read_chunk_head(head, record_length)[:2]
    except (ValueError, struct.error):
        return False
    return end_ns < log_time_range[0] or start_ns > log_time_range[1]


