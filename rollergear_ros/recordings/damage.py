"""Damage in an MCAP file: the spans a linear read skipped (:class:`DamagedSpan`), where it resumes (the
next plausible chunk: :func:`find_next_chunk`), and what a span cost (its log times from the chunk's own
head or its neighbours, its messages from the chunk's message index).  No rclpy."""

from __future__ import annotations

import struct
from dataclasses import dataclass

from .records import DATA_END_RECORD, OP_CHUNK, read_chunk_head

_SCAN_WINDOW = 1 << 22  # resynchronisation scans the file in windows of this size


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
        start_ns, end_ns, _size, _crc, _comp, p, n = read_chunk_head(head[9:], ln)
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
        end_at = block.find(DATA_END_RECORD, 0, _SCAN_WINDOW)
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


def record_damage(state, start: int, end: int, reason: str, fh=None, record_length: int = 0) -> DamagedSpan:
    """Record a damaged span; a chunk's own header (a chunk record of ``record_length`` bytes at
    ``start``, read through ``fh``) gives its log-time range when it is intact."""
    span = DamagedSpan(start, end, reason)
    if fh is not None:
        fh.seek(start + 9)
        try:
            start_ns, end_ns, *_ = read_chunk_head(fh.read(64), record_length)
            if 0 <= start_ns <= end_ns < 2**63:
                span.start_ns, span.end_ns = start_ns, end_ns
        except (ValueError, struct.error):
            pass
    if span.start_ns is None:
        span.start_ns = state.last_log_time
    state.damaged.append(span)
    return span


def close_gap(state, next_log_time: int | None) -> None:
    """Spans known only by their neighbours end at the first message read after them."""
    for span in state.damaged:
        if span.end_ns is None:
            span.end_ns = next_log_time if next_log_time is not None else state.last_log_time
