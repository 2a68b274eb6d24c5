"""The MCAP records this package frames by hand, each record's read and write side by side (as ``mcap``'s
``records.py`` keeps them): the message record, the chunk's head, the message index's head, the schema
and channel records (read here; the writer has ``mcap``'s builder frame them) and the footer's head.

Everything is little-endian as the MCAP specification lays it out: a record is its opcode (1 byte), its
length (uint64) and its fields.  The bounds a reader puts on what a record declares (a chunk's size, its
compression ratio) live here with the record.  No rclpy.
"""

from __future__ import annotations

import struct

import numpy as np
from mcap.opcode import Opcode
from mcap.writer import MCAP0_MAGIC as MAGIC

__all__ = [
    "CHANNEL_FIXED", "CHUNK_COMPRESSIONS", "DATA_END_RECORD", "MAGIC", "MAX_CHUNK_BYTES", "MAX_COMPRESSION_RATIO",
    "MESSAGE_FIXED", "MIN_OTHER_RECORD", "OP_CHANNEL", "OP_CHUNK", "OP_DATA_END", "OP_FOOTER", "OP_MESSAGE",
    "OP_MESSAGE_INDEX", "OP_SCHEMA", "RECORD_HEAD", "SCHEMA_FIXED", "byte_rows", "chunk_head", "footer_head",
    "message_fields", "message_index_count", "message_index_head", "message_rows", "read_channel", "read_chunk_head",
    "read_schema",
]

# record opcodes as plain ints (compared per record in the numpy fast path)
OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_MESSAGE_INDEX, OP_DATA_END, OP_FOOTER = (
    int(Opcode.SCHEMA), int(Opcode.CHANNEL), int(Opcode.MESSAGE), int(Opcode.CHUNK), int(Opcode.MESSAGE_INDEX),
    int(Opcode.DATA_END), int(Opcode.FOOTER))
RECORD_HEAD = 1 + 8  #: opcode and length, before every record's fields
#: the data-end record with a CRC of 0 ("not computed"): where a resynchronising read stops looking for chunks
DATA_END_RECORD = bytes([OP_DATA_END]) + (4).to_bytes(8, "little")


def byte_rows(buf: np.ndarray, width: int, writeable: bool = False) -> np.ndarray:
    """Every ``width`` bytes of ``buf`` from each offset, as the rows of a view (no copy):
    ``byte_rows(buf, w)[offsets]`` gathers the w bytes at each offset in one numpy call, without the
    offset × width index array a fancy index would build (``writeable``: assign to them likewise)."""
    from numpy.lib.stride_tricks import as_strided

    return as_strided(buf, shape=(max(0, len(buf) - width + 1), width), strides=(buf.strides[0], buf.strides[0]),
                      writeable=writeable)


# --------------------------------------------------------------------------------- message (0x05)
MESSAGE_FIXED = 2 + 4 + 8 + 8  #: channel id (uint16), sequence (uint32), log time, publish time (uint64)


def message_rows(channel_id: np.ndarray, log_time: np.ndarray, payload: np.ndarray,
                 sequence: np.ndarray | None = None, publish_time: np.ndarray | None = None) -> np.ndarray:
    """Write: message records (one row each) for payloads of equal length -- opcode 0x05, its length,
    channel id, sequence (None leaves 0), log time and publish time (``publish_time`` None: the log time),
    the payload.  The one layout of a message record in the package (``_records.c`` lays out exactly
    this, faster: :func:`.layout.lay_out_records`)."""
    n, plen = payload.shape
    rows = np.empty((n, RECORD_HEAD + MESSAGE_FIXED + plen), dtype=np.uint8)
    rows[:, 0] = OP_MESSAGE
    rows[:, 1:9] = np.frombuffer(struct.pack("<Q", MESSAGE_FIXED + plen), dtype=np.uint8)
    rows[:, 9:11] = np.ascontiguousarray(channel_id, dtype="<u2").view(np.uint8).reshape(n, 2)
    if sequence is None:
        rows[:, 11:15] = 0
    else:
        rows[:, 11:15] = (sequence & 0xFFFFFFFF).astype("<u4").view(np.uint8).reshape(n, 4)
    rows[:, 15:23] = np.ascontiguousarray(log_time, dtype="<i8").view(np.uint8).reshape(n, 8)
    if publish_time is None:
        rows[:, 23:31] = rows[:, 15:23]
    else:
        rows[:, 23:31] = np.ascontiguousarray(publish_time, dtype="<i8").view(np.uint8).reshape(n, 8)
    rows[:, 31:] = payload
    return rows


def message_fields(buf: np.ndarray, starts: np.ndarray, record_length: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Read: the fields of the message records starting at ``starts`` (each ``record_length`` bytes with
    its head) in ``buf``, gathered at once: channel id (uint16), log time (int64), the payload's offset
    and length, publish time (int64).  The sequence is not read (nothing here uses it)."""
    rows8 = byte_rows(buf, 8)
    return (byte_rows(buf, 2)[starts + 9].view("<u2").ravel(), rows8[starts + 15].view("<i8").ravel(),
            starts + RECORD_HEAD + MESSAGE_FIXED, record_length - RECORD_HEAD - MESSAGE_FIXED,
            rows8[starts + 23].view("<i8").ravel())


# ----------------------------------------------------------------------------- schema (0x03), channel (0x04)
#: a schema's and a channel's fields with empty strings (the shortest records of each), and the
#: shortest of them with its head: a bound on how many a chunk holds
SCHEMA_FIXED, CHANNEL_FIXED = 14, 16
MIN_OTHER_RECORD = RECORD_HEAD + SCHEMA_FIXED


def _string(b: bytes, pos: int) -> tuple[str, int]:
    n = struct.unpack_from("<I", b, pos)[0]
    return b[pos + 4:pos + 4 + n].decode(), pos + 4 + n


def read_schema(body: bytes) -> tuple[int, tuple[str, str, bytes]]:
    """Read: a schema record's fields -- its id, and (name, encoding, data); the writer has ``mcap``'s
    builder frame it (:class:`~.mcapwriter.ChunkedMcapWriter`)."""
    sid = struct.unpack_from("<H", body, 0)[0]
    name, p = _string(body, 2)
    enc, p = _string(body, p)
    n = struct.unpack_from("<I", body, p)[0]
    return sid, (name, enc, body[p + 4:p + 4 + n])


def read_channel(body: bytes) -> tuple[int, tuple[str, int, str]]:
    """Read: a channel record's fields -- its id, and (topic, schema id, message encoding); its metadata
    is not read, and the writer has ``mcap``'s builder frame it."""
    cid, sid = struct.unpack_from("<HH", body, 0)
    topic, p = _string(body, 4)
    enc, p = _string(body, p)
    return cid, (topic, sid, enc)


# --------------------------------------------------------------------------------- chunk (0x06)
#: bounds on what a chunk may declare, so that a damaged or hostile length costs neither memory nor time
MAX_CHUNK_BYTES = 256 << 20  # a decompressed chunk (recorders write 1–4 MB)
MAX_COMPRESSION_RATIO = 1000  # declared uncompressed / compressed size; real messages stay far below
CHUNK_COMPRESSIONS = ("", "zstd", "lz4")


def chunk_head(start_ns: int, end_ns: int, uncompressed_size: int, crc: int, compressed_size: int) -> bytes:
    """Write: a zstd chunk record's head and fields up to its records (``compressed_size`` bytes follow),
    the fields as ``mcap.records.Chunk`` writes them."""
    fields = struct.pack("<QQQII4sQ", start_ns, end_ns, uncompressed_size, crc, 4, b"zstd", compressed_size)
    return struct.pack("<BQ", OP_CHUNK, len(fields) + compressed_size) + fields


def read_chunk_head(body: bytes, record_length: int | None = None) -> tuple[int, int, int, int, str, int, int]:
    """Read: a chunk record's fields, each checked: (start, end, uncompressed size, CRC, compression,
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


# --------------------------------------------------------------------------------- message index (0x07)
def message_index_head(channel_id: int, entries_bytes: int) -> bytes:
    """Write: a message index record's head and fields up to its entries (``entries_bytes`` of (log time,
    offset) pairs, uint64 each, follow)."""
    return struct.pack("<BQHI", OP_MESSAGE_INDEX, 6 + entries_bytes, channel_id, entries_bytes)


def message_index_count(head: bytes, record_length: int) -> int | None:
    """Read: messages a message index record lists (16 bytes per entry), None if it is malformed: from the
    first 6 bytes of its fields (channel id, entries' byte length) and its ``record_length``."""
    if len(head) < 6:
        return None
    n = struct.unpack_from("<I", head, 2)[0]
    return n // 16 if n % 16 == 0 and 6 + n <= record_length else None


# --------------------------------------------------------------------------------- footer (0x02)
def footer_head(summary_start: int, summary_offset_start: int) -> bytes:
    """Write: the footer record up to its summary CRC -- what that CRC covers after the summary section
    (MCAP specification); the reader takes the summary through ``mcap`` (:func:`.fastmcap.preload_summary`)."""
    return struct.pack("<BQQQ", OP_FOOTER, 8 + 8 + 4, summary_start, summary_offset_start)
