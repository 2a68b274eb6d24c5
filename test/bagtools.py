"""Independent readers for tests: rosbags (AnyReader) and mcap + mcap-ros2-support."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np


def read_rosbags(path: Path, topics: Iterable[str] | None = None) -> dict[str, tuple[np.ndarray, list]]:
    """Topic -> (log times ns, messages) with the rosbags library (``topics``: only those)."""
    from rosbags.highlevel import AnyReader

    out: dict[str, tuple[list, list]] = {}
    with AnyReader([Path(path)]) as reader:
        connections = None if topics is None else [c for c in reader.connections if c.topic in set(topics)]
        for con, t, raw in reader.messages(connections=connections):
            msg = reader.deserialize(raw, con.msgtype)
            ts, ms = out.setdefault(con.topic, ([], []))
            ts.append(t)
            ms.append(msg)
    return {k: (np.array(v[0], dtype=np.int64), v[1]) for k, v in out.items()}


def read_mcap_ros2(path: Path, topics: Iterable[str] | None = None) -> dict[str, tuple[np.ndarray, list]]:
    """Topic -> (log times ns, decoded messages) with mcap + mcap-ros2-support, in log-time order
    (``topics``: only those)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out: dict[str, tuple[list, list]] = {}
    with Path(path).open("rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for _schema, channel, message, decoded in reader.iter_decoded_messages(
                topics=None if topics is None else list(topics)):
            ts, ms = out.setdefault(channel.topic, ([], []))
            ts.append(message.log_time)
            ms.append(decoded)
    return {k: (np.array(v[0], dtype=np.int64), v[1]) for k, v in out.items()}


def float_series(messages: dict, topic: str) -> tuple[np.ndarray, np.ndarray]:
    t, ms = messages[topic]
    v = np.array([m.data for m in ms], dtype=float)
    order = np.argsort(t, kind="stable")
    return t[order], v[order]


def shifted_copy(src: Path, dst: Path, shift_s: int) -> Path:
    """A copy of the MCAP ``src`` with every time ``shift_s`` whole seconds later (negative: earlier):
    log and publish times, and the header stamp of stamped messages (CDR: its seconds follow the
    4-byte encapsulation header)."""
    import struct

    shift_ns = shift_s * 10**9

    def shifted(schema, _channel, message):
        data = message.data
        if b"std_msgs/Header header" in schema.data:
            (sec,) = struct.unpack_from("<i", data, 4)
            data = data[:4] + struct.pack("<i", sec + shift_s) + data[8:]
        return message.log_time + shift_ns, data, message.publish_time + shift_ns

    return _copy(src, dst, shifted, log_time_order=False)


def scaled_copy(src: Path, dst: Path, topic: str, factor: float) -> Path:
    """A copy of the MCAP ``src`` with the Float64 readings of ``topic`` times ``factor`` (a sensor that reads
    high or low; CDR: the float64 follows the 4-byte encapsulation header)."""
    import struct

    def scaled(_schema, channel, message):
        data = message.data
        if channel.topic == topic:
            (value,) = struct.unpack_from("<d", data, 4)
            data = data[:4] + struct.pack("<d", value * factor) + data[12:]
        return message.log_time, data, message.publish_time

    return _copy(src, dst, scaled, log_time_order=False)


def filtered_copy(src: Path, dst: Path, keep) -> tuple[Path, int]:
    """A copy of the MCAP ``src`` in log-time order with only the messages ``keep(topic, log_time_ns)``
    holds for: the copy, and how many were left out."""
    left_out = 0

    def kept(_schema, channel, message):
        nonlocal left_out
        if keep(channel.topic, message.log_time):
            return message.log_time, message.data, message.publish_time
        left_out += 1
        return None

    return _copy(src, dst, kept, log_time_order=True), left_out


def _copy(src: Path, dst: Path, each, log_time_order: bool) -> Path:
    """``src`` copied to ``dst`` (schemas, channels, metadata), each message as ``each(schema, channel,
    message)`` gives its ``(log_time, data, publish_time)``, or None to leave it out."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(src, "rb") as fin, open(dst, "wb") as fout:
        reader = make_reader(fin)
        writer = Writer(fout)
        writer.start(profile="ros2", library="rollergear tests")
        schemas, channels = {}, {}
        for schema, channel, message in reader.iter_messages(log_time_order=log_time_order):
            written = each(schema, channel, message)
            if written is None:
                continue
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding,
                                                               schemas[schema.id], channel.metadata)
            log_time, data, publish_time = written
            writer.add_message(channels[channel.id], log_time, data, publish_time, message.sequence)
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, record.metadata)
        writer.finish()
    return dst


def swallowed_record_bag(path: Path, samples: int = 3000) -> Path:
    """An uncompressed MCAP of motor torque and speed whose middle chunk holds one message record with a
    length that swallows the rest of the chunk (its CRC zeroed: unchecked), written by the ``mcap``
    library and then patched: a record's bytes that are no Float64."""
    import struct

    from mcap.writer import CompressionType, Writer

    with open(path, "wb") as fh:
        writer = Writer(fh, compression=CompressionType.NONE, chunk_size=2000)
        writer.start(profile="ros2", library="rollergear tests")
        schema = writer.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
        channels = {t: writer.register_channel(t, "cdr", schema) for t in ("/rollergear/motor/torque",
                                                                           "/rollergear/motor/speed")}
        for k in range(samples):
            t = 10**18 + k * 1_000_000
            for topic, value in (("/rollergear/motor/torque", 10.0 + k * 1e-3), ("/rollergear/motor/speed", 100.0)):
                writer.add_message(channels[topic], t, b"\x00\x01\x00\x00" + struct.pack("<d", value), t)
        writer.finish()
    data = bytearray(Path(path).read_bytes())
    pos, chunks = 8, []
    while pos < len(data) - 8 and data[pos] != 0x0F:  # records up to the footer: the chunks
        length = struct.unpack_from("<Q", data, pos + 1)[0]
        if data[pos] == 0x06:
            chunks.append(pos)
        pos += 9 + length
    chunk = chunks[len(chunks) // 2]
    at = chunk + 9 + 24 + 4  # opcode, length; start, end, uncompressed size; crc
    at += 4 + struct.unpack_from("<I", data, at)[0]  # the compression's name
    records_end = at + 8 + struct.unpack_from("<Q", data, at)[0]
    at += 8
    while data[at] != 0x05:  # the chunk's first message record
        at += 9 + struct.unpack_from("<Q", data, at + 1)[0]
    struct.pack_into("<Q", data, at + 1, records_end - at - 9)
    struct.pack_into("<I", data, chunk + 9 + 24, 0)
    Path(path).write_bytes(bytes(data))
    return Path(path)
