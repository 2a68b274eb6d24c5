"""Fast MCAP reading: whole chunks parsed with numpy instead of one Python object per message.

The ``mcap`` reader builds a record object per message (~5 µs each).  Here a chunk's message
records are found in one pass of C (or, in a build without a compiler, run by run with numpy:
recorders write long runs of equal-sized records), and the channel ids, log times and payload
offsets come out as arrays.  Reads linearly (no index needed), so a truncated recording yields
every complete chunk before the damage.  No rclpy.
"""

from __future__ import annotations

import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Iterator

import numpy as np
from mcap.opcode import Opcode
from mcap.writer import MCAP0_MAGIC as MAGIC

from ..base.errors import BagError

try:  # the chunk's records found in C (built by setup.py where a compiler is found)
    from ._records import scan as _native_scan
except ImportError:  # pragma: no cover - a build without a compiler: numpy finds them
    _native_scan = None

# record opcodes as plain ints (compared per record in the numpy fast path)
OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_MESSAGE_INDEX, OP_DATA_END, OP_FOOTER = (
    int(Opcode.SCHEMA), int(Opcode.CHANNEL), int(Opcode.MESSAGE), int(Opcode.CHUNK), int(Opcode.MESSAGE_INDEX),
    int(Opcode.DATA_END), int(Opcode.FOOTER))
_MSG_FIXED = 2 + 4 + 8 + 8  # channel id, sequence, log time, publish time


def byte_rows(buf: np.ndarray, width: int, writeable: bool = False) -> np.ndarray:
    """Every ``width`` bytes of ``buf`` from each offset, as the rows of a view (no copy):
    ``byte_rows(buf, w)[offsets]`` gathers the w bytes at each offset in one numpy call, without the
    offset × width index array a fancy index would build (``writeable``: assign to them likewise)."""
    from numpy.lib.stride_tricks import as_strided

    return as_strided(buf, shape=(max(0, len(buf) - width + 1), width), strides=(buf.strides[0], buf.strides[0]),
                      writeable=writeable)


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


#: bounds on what a record may declare, so that a damaged or hostile length costs neither memory nor time
MAX_CHUNK_BYTES = 256 << 20  # a decompressed chunk (recorders write 1–4 MB)
MAX_COMPRESSION_RATIO = 1000  # declared uncompressed / compressed size; real messages stay far below
CHUNK_COMPRESSIONS = ("", "zstd", "lz4")
_LOOSE_BLOCK = 1 << 20  # messages outside chunks are parsed this many bytes at a time
_SCAN_WINDOW = 1 << 22  # resynchronisation scans the file in windows of this size
_DATA_END_RECORD = bytes([int(Opcode.DATA_END)]) + (4).to_bytes(8, "little")


@dataclass
class DamagedSpan:
    """A stretch of a file that could not be read; reading went on after it (or the file ended)."""

    start_byte: int
    end_byte: int
    reason: str
    start_ns: int | None = None  #: the lost messages' log times (the chunk's own, else the neighbours')
    end_ns: int | None = None
    messages_lost: int | None = None  #: from the damaged chunk's message index; None: not known

    def text(self) -> str:
        if self.start_ns is not None and self.end_ns is not None:
            when = f"log time {_time_text(self.start_ns)} to {_time_text(self.end_ns)}"
        else:
            when = "log time unknown"
        lost = "an unknown number of messages" if self.messages_lost is None else f"{self.messages_lost:,} messages"
        return (f"bytes {self.start_byte:,}–{self.end_byte:,} ({self.end_byte - self.start_byte:,} bytes, {when}) "
                f"unreadable: {self.reason}; {lost} lost")


def _time_text(t_ns: int) -> str:
    """A log time for people: UTC date and time for wall-clock stamps, seconds for others."""
    if t_ns >= 10**17:  # after 1973: a wall-clock stamp
        import datetime as dt

        return dt.datetime.fromtimestamp(t_ns * 1e-9, dt.UTC).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3] + " UTC"
    return f"{t_ns * 1e-9:.3f} s"


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
    arrays = MessageArrays(byte_rows(buf, 2)[starts + 9].view("<u2").ravel(),
                           byte_rows(buf, 8)[starts + 15].view("<i8").ravel(),
                           starts + 9 + _MSG_FIXED, rec - 9 - _MSG_FIXED,
                           buf, byte_rows(buf, 8)[starts + 23].view("<i8").ravel())
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
        _schema(body, state)
    elif op == OP_CHANNEL:
        _channel(body, state)


#: a schema's and a channel's fields with empty strings (the shortest records of each), and the
#: shortest of them with its head: a bound on how many a chunk holds
_SCHEMA_FIXED, _CHANNEL_FIXED = 14, 16
_MIN_OTHER_RECORD = 9 + _SCHEMA_FIXED


def _native_message_starts(data: bytes, buf: np.ndarray, state: ReadState) -> tuple[np.ndarray, np.ndarray]:
    """(start, record length) of each message record of a chunk, found by the C scan (schema and
    channel records update ``state``; records of other opcodes are skipped, opcode 0 is damage)."""
    starts = np.empty(len(data) // (9 + _MSG_FIXED) + 1, dtype=np.int64)
    others = np.empty(len(data) // _MIN_OTHER_RECORD + 1, dtype=np.int64)
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
            if ln < (_SCHEMA_FIXED if op == OP_SCHEMA else _CHANNEL_FIXED):
                raise ValueError("schema or channel record shorter than its fields")
            _other_record(op, data[pos + 9:pos + rec], state)
            pos += rec
            continue
        if op == OP_MESSAGE and ln < _MSG_FIXED:
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


def _chunk_header(body: bytes, record_length: int | None = None) -> tuple[int, int, int, int, str, int, int]:
    """A chunk record's fields, each checked: (start, end, uncompressed size, CRC, compression,
    offset of the compressed records, their length).  ``body`` may be only the record's start when
    ``record_length`` gives its whole length."""
    length = len(body) if record_length is None else record_length
    if len(body) < 40 or length < 40:
        raise ValueError("chunk record too short")
    start_ns, end_ns, size, crc = struct.unpack_from("<QQQI", body, 0)
    n_name = struct.unpack_from("<I", body, 28)[0]
    if n_name > 16:
        raise ValueError("chunk compression name too long")
    compression = body[32:32 + n_name].decode("ascii", errors="replace")
    if compression not in CHUNK_COMPRESSIONS:
        raise ValueError(f"unsupported chunk compression {compression!r}")
    p = 32 + n_name + 8
    if p > len(body):
        raise ValueError("chunk record too short")
    n = struct.unpack_from("<Q", body, p - 8)[0]
    if p + n > length:
        raise ValueError(f"chunk declares {n:,} compressed bytes, its record holds {length - p:,}")
    if size > MAX_CHUNK_BYTES or (compression and size > MAX_COMPRESSION_RATIO * n + 65536):
        raise ValueError(f"chunk declares {size:,} bytes uncompressed from {n:,} (beyond the reader's bounds)")
    return start_ns, end_ns, size, crc, compression, p, n


def chunk_records(body: bytes) -> bytes:
    """The records inside a chunk record's body: decompressed within bounds, size and CRC checked."""
    _s, _e, size, crc, compression, p, n = _chunk_header(body)
    try:
        data = _decompress(compression, body[p:p + n], size)
    except Exception as exc:  # noqa: BLE001 - each codec raises its own error class
        raise ValueError(f"{compression} decompression failed ({exc})") from None
    if len(data) != size:
        raise ValueError(f"chunk decompresses to {len(data):,} bytes, declares {size:,}")
    if crc and zlib.crc32(data) != crc:  # 0: the writer computed none
        raise ValueError(f"chunk CRC mismatch (stored {crc:#010x}, data {zlib.crc32(data):#010x})")
    return data


def _plausible_chunk(fh, offset: int, file_size: int) -> bool:
    """Whether a chunk record starts at ``offset``: every field of its header consistent (a
    byte pattern that random data matches with a probability of about 2⁻⁶⁰)."""
    fh.seek(offset)
    head = fh.read(9 + 32 + 16 + 8)
    if len(head) < 9 + 40 or head[0] != OP_CHUNK:
        return False
    ln = int.from_bytes(head[1:9], "little")
    if offset + 9 + ln > file_size:
        return False
    try:
        start_ns, end_ns, _size, _crc, _comp, p, n = _chunk_header(head[9:], ln)
    except (ValueError, struct.error):
        return False
    return start_ns <= end_ns and p + n == ln


def find_next_chunk(fh, start: int, file_size: int) -> int | None:
    """Offset of the first chunk (or data-end) record at or after ``start`` — where a read resumes
    after damage; None when there is none."""
    chunk_op = bytes([OP_CHUNK])
    pos = start
    while pos < file_size:
        fh.seek(pos)
        block = fh.read(min(_SCAN_WINDOW + 64, file_size - pos))
        end_at = block.find(_DATA_END_RECORD, 0, _SCAN_WINDOW)
        limit = end_at if end_at >= 0 else min(_SCAN_WINDOW, len(block))
        i = block.find(chunk_op, 0, limit)
        while i >= 0:
            if _plausible_chunk(fh, pos + i, file_size):
                return pos + i
            i = block.find(chunk_op, i + 1, limit)
        if end_at >= 0:
            return pos + end_at
        pos += _SCAN_WINDOW
    return None


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


def _message_index_count(head: bytes, record_length: int) -> int | None:
    """Messages a message-index record lists (16 bytes per entry), None if it is malformed: from the
    first 6 bytes of its content (channel id, entries' byte length) and its ``record_length``."""
    if len(head) < 6:
        return None
    n = struct.unpack_from("<I", head, 2)[0]
    return n // 16 if n % 16 == 0 and 6 + n <= record_length else None


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
                _close_gap(state, int(arrays.log_time.min()))
                state.last_log_time = int(arrays.log_time.max())
                yield arrays
        _close_gap(state, None)


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
        span = _damaged(self.state, start, end, f"the chunk holds {read:,} readable messages, its message index lists "
                        f"{listed:,}", self.fh, end - start - 9)
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
                _damaged(state, pos, file_size, "the file ends inside a record")
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
                count = _message_index_count(fh.read(6), ln)  # its head tells the entries: not read
                if count is not None:
                    self.after_chunk[5] += count
                state.bytes_read = self.pos = end
                return None
            elif op in (OP_MESSAGE, OP_SCHEMA, OP_CHANNEL):
                run = _loose_records(fh, pos, file_size)
                arrays = parse_records(run, state)
                end = pos + len(run)
            elif op == OP_MESSAGE_INDEX and self.after_damage is not None:
                count = _message_index_count(fh.read(6), ln)
                if count is not None:
                    self.after_damage.messages_lost = (self.after_damage.messages_lost or 0) + count
                self.pos = end
                return None
            elif op in (OP_DATA_END, OP_FOOTER):
                state.bytes_read = end
                self.pos = None
                return None
        except Exception as exc:  # noqa: BLE001 - damaged data (bad fields, decompression, CRC): skip the record
            self.after_damage = _damaged(state, pos, end, str(exc) or type(exc).__name__,
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
        self.after_damage = _damaged(state, pos, nxt if nxt is not None else file_size, reason,
                                     fh if op == OP_CHUNK and end > file_size else None, ln)
        if nxt is None:
            state.truncated = True
            state.problem = f"{reason} (byte {pos:,}); nothing readable after it"
        self.pos = nxt


def _outside(head: bytes, record_length: int, log_time_range: tuple[int, int]) -> bool:
    """Whether a chunk (``head``: the start of its record) holds only messages outside the range;
    a header that cannot be read says nothing (the chunk is read, and its damage reported)."""
    try:
        start_ns, end_ns = _chunk_header(head, record_length)[:2]
    except (ValueError, struct.error):
        return False
    return end_ns < log_time_range[0] or start_ns > log_time_range[1]


def _damaged(state: ReadState, start: int, end: int, reason: str, fh=None, record_length: int = 0) -> DamagedSpan:
    """Record a damaged span; a chunk's own header (a chunk record of ``record_length`` bytes at
    ``start``, read through ``fh``) gives its log-time range when it is intact."""
    span = DamagedSpan(start, end, reason)
    if fh is not None:
        fh.seek(start + 9)
        try:
            start_ns, end_ns, *_ = _chunk_header(fh.read(64), record_length)
            if 0 <= start_ns <= end_ns < 2**63:
                span.start_ns, span.end_ns = start_ns, end_ns
        except (ValueError, struct.error):
            pass
    if span.start_ns is None:
        span.start_ns = state.last_log_time
    state.damaged.append(span)
    return span


def _close_gap(state: ReadState, next_log_time: int | None) -> None:
    """Spans known only by their neighbours end at the first message read after them."""
    for span in state.damaged:
        if span.end_ns is None:
            span.end_ns = next_log_time if next_log_time is not None else state.last_log_time


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
