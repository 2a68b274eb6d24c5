"""The numpy MCAP reader's log-time ordering against the ``mcap`` library's own reader."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from rollergear_ros.recordings.fastmcap import ReadState, iter_message_arrays
from rollergear_ros.recordings.logorder import iter_log_time_order, release_count


def _lagging_recording(path, n: int = 3000, chunk_size: int = 4096) -> None:
    """Two topics at 1 kHz where the speed messages reach the file in blocks up to 40 ms late
    (a recorder with per-topic buffers), written in small chunks so that the disorder crosses
    many chunk boundaries; a slow temperature topic at 10 Hz."""
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=chunk_size)
        w.start(profile="ros2", library="test")
        sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
        torque = w.register_channel("/torque", "cdr", sid)
        speed = w.register_channel("/speed", "cdr", sid)
        temp = w.register_channel("/temperature", "cdr", sid)
        pending: list[tuple[int, int]] = []
        for k in range(n):
            t = 1_000_000_000 + k * 1_000_000
            w.add_message(torque, t, struct.pack("<4xd", float(k)), t)
            pending.append((t + 1000, k))
            if k % 100 == 0:
                w.add_message(temp, t + 2000, struct.pack("<4xd", 40.0 + k), t)
            if len(pending) == 40 or k == n - 1:  # the speed buffer is flushed every 40 messages
                for ts, kk in pending:
                    w.add_message(speed, ts, struct.pack("<4xd", -float(kk)), ts)
                pending = []
        w.finish()


def test_log_time_order_equals_the_mcap_reader(tmp_path):
    bag = tmp_path / "lagging.mcap"
    _lagging_recording(bag)
    with bag.open("rb") as fh:
        ref = [(m.log_time, c.topic, m.data) for _, c, m in make_reader(fh).iter_messages(log_time_order=True)]
    state = ReadState()
    got = []
    batches = 0
    for t, cid, payloads in iter_log_time_order(bag, state):
        batches += 1
        got += [(tt, state.channels[c][0], p) for tt, c, p in zip(t.tolist(), cid.tolist(), payloads)]
    assert batches > 10, "the disorder crosses chunk boundaries"
    assert len(got) == len(ref) == 3000 * 2 + 30
    assert [g[0] for g in got] == sorted(g[0] for g in got)
    assert got == ref


def test_a_log_time_range_reads_only_the_chunks_that_may_hold_it(tmp_path):
    """A time slice of a long recording: chunks wholly outside the range are skipped unread (their
    header says their log times), every message inside it is still read."""
    path = tmp_path / "lagging.mcap"
    _lagging_recording(path)
    every = [(int(t), int(c)) for a in iter_message_arrays(path) for t, c in zip(a.log_time, a.channel)]
    lo, hi = 2_000_000_000, 2_500_000_000
    state = ReadState(log_time_range=(lo, hi))
    got = [(int(t), int(c)) for a in iter_message_arrays(path, state) for t, c in zip(a.log_time, a.channel)]
    assert state.chunks_skipped > 0 and len(got) < len(every) / 2
    assert sorted(m for m in got if lo <= m[0] <= hi) == sorted(m for m in every if lo <= m[0] <= hi)
    assert not state.damaged


def test_release_count_holds_back_what_the_next_batch_may_precede():
    t = np.array([1, 2, 3, 4, 5, 6], dtype=np.int64)
    keys = np.array([0, 1, 0, 0, 2, 0])
    # channel 1 was last seen at t=2: everything after it may still be preceded by channel 1
    assert release_count(t, keys) == 2
    # unless channel 1 is the slow one that must not hold the others back; then channel 2 (t=5) rules
    assert release_count(t, keys, ignore_key=1) == 5
    assert release_count(t[:0], keys[:0]) == 0


def test_writer_stores_the_crcs_that_mcap_validates_and_the_reader_checks_them(tmp_path):
    """The chunk and summary CRCs are written (the ``mcap`` reader validates them), and a byte
    flipped inside a chunk's compressed data is found: the read stops there, flagged, instead of
    yielding garbage."""
    from rollergear_ros.recordings.bagwriter import BagWriter

    path = tmp_path / "crc.mcap"
    n = 20_000
    with BagWriter(path, chunk_size=64 * 1024) as bw:
        for k in range(0, n, 1000):  # one call per 1000 messages: several chunks
            t = 10**9 + np.arange(k, k + 1000, dtype=np.int64) * 10**6
            bw.write_float64_series("/x", t, np.arange(k, k + 1000, dtype=float))
    with path.open("rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        summary = reader.get_summary()
        assert summary.chunk_indexes
        chunk_crcs = []
        for ci in summary.chunk_indexes:
            fh.seek(ci.chunk_start_offset + 1 + 8)
            chunk_crcs.append(struct.unpack("<QQQI", fh.read(28))[3])
        assert all(chunk_crcs)
        assert sum(1 for _ in reader.iter_messages()) == n  # validates every chunk's CRC
    footer_crc = struct.unpack("<QQI", path.read_bytes()[-8 - 20:-8])[2]
    assert footer_crc != 0
    # a byte flipped near the end of the second chunk's compressed data: zstd may decode it to other
    # values without noticing; the chunk CRC does.  That chunk is skipped and reported, the rest read
    raw = bytearray(path.read_bytes())
    ci = summary.chunk_indexes[1]
    raw[ci.chunk_start_offset + ci.chunk_length - 200] ^= 0x40
    bad = tmp_path / "flipped.mcap"
    bad.write_bytes(bytes(raw))
    state = ReadState()
    got = sum(len(b[0]) for b in iter_log_time_order(bad, state))
    lost = sum(summary.statistics.channel_message_counts.values()) - got
    assert not state.truncated and len(state.damaged) == 1
    span = state.damaged[0]
    assert "CRC" in span.reason or "decompression failed" in span.reason, span.reason
    assert (span.start_byte, span.end_byte) == (ci.chunk_start_offset, ci.chunk_start_offset + ci.chunk_length)
    assert (span.start_ns, span.end_ns) == (ci.message_start_time, ci.message_end_time)
    assert span.messages_lost == lost > 0
    with bad.open("rb") as fh, pytest.raises(Exception):  # noqa: B017 - the reference reader refuses it too
        sum(1 for _ in make_reader(fh, validate_crcs=True).iter_messages())


def _f64(v: float) -> bytes:
    """A little-endian CDR Float64 payload."""
    return b"\x00\x01\x00\x00" + struct.pack("<d", float(v))


def _twenty_chunks(path, n: int = 20_000) -> list:
    """A Float64 recording of ``n`` messages in 20 chunks written by the ``mcap`` library; its chunk indexes."""
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=10**9)
        w.start(profile="ros2", library="test")
        sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
        cid = w.register_channel("/x", "cdr", sid)
        per = n // 20
        for k in range(n):
            w.add_message(cid, 10**9 + k * 10**6, _f64(k), 10**9 + k * 10**6)
            if (k + 1) % per == 0:
                w._Writer__finalize_chunk()  # noqa: SLF001 - 20 equal chunks
        w.finish()
    with open(path, "rb") as fh:
        return make_reader(fh).get_summary().chunk_indexes


def _values(path, state) -> np.ndarray:
    from rollergear_ros.recordings.messages import decode_float64

    return np.concatenate([np.empty(0)] + [decode_float64(p) for _t, _c, p in iter_log_time_order(path, state)])


@pytest.mark.parametrize("where", ["compressed data", "chunk length", "crc"])
def test_one_damaged_chunk_is_skipped_and_reported_and_the_rest_read(tmp_path, where):
    """A flipped byte in chunk 2 of 20 costs that chunk only (it used to end the read): the read
    resynchronises on the next chunk and reports the span's bytes, log times and messages lost."""
    path = tmp_path / "ok.mcap"
    chunks = _twenty_chunks(path)
    raw = bytearray(path.read_bytes())
    ci = chunks[1]
    at = {"compressed data": ci.chunk_start_offset + ci.chunk_length // 2,
          "chunk length": ci.chunk_start_offset + 3,  # the record's length field: the next record misaligns
          "crc": ci.chunk_start_offset + 9 + 24}[where]
    raw[at] ^= 0x10
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(raw))
    state = ReadState()
    values = _values(bad, state)
    expected = np.delete(np.arange(20_000, dtype=float), np.arange(1000, 2000))
    np.testing.assert_array_equal(values, expected)
    assert len(state.damaged) == 1 and not state.truncated
    span = state.damaged[0]
    assert span.start_byte == ci.chunk_start_offset
    assert span.end_byte >= ci.chunk_start_offset + ci.chunk_length
    assert span.end_byte <= chunks[2].chunk_start_offset
    # the log times of what was lost: the chunk's own (or its neighbours' when its header is hit)
    assert span.start_ns <= ci.message_start_time and span.end_ns >= ci.message_end_time
    assert span.end_ns <= chunks[2].message_start_time
    if where != "chunk length":  # the chunk's message index follows it: the count is known
        assert span.messages_lost == 1000
    assert "unreadable" in span.text() and "bytes" in span.text()


@pytest.mark.parametrize("mutation", ["length", "huge chunk", "magic only", "random"])
def test_hostile_lengths_cost_neither_memory_nor_time(tmp_path, mutation):
    """Lengths are bounded by the file size and a chunk's declared size by the reader's bounds."""
    import resource
    import time

    from rollergear_ros.recordings.records import MAX_CHUNK_BYTES

    path = tmp_path / "ok.mcap"
    chunks = _twenty_chunks(path, 2000)
    raw = bytearray(path.read_bytes())
    if mutation == "length":  # a record declaring 2^63 bytes
        raw[chunks[0].chunk_start_offset + 1:chunks[0].chunk_start_offset + 9] = struct.pack("<Q", 2**63)
    elif mutation == "huge chunk":  # a chunk declaring 1 GiB of records
        raw[chunks[0].chunk_start_offset + 9 + 16:chunks[0].chunk_start_offset + 9 + 24] = struct.pack("<Q", 2**30)
    elif mutation == "magic only":
        raw = raw[:8] + bytes(20)
    else:
        raw = raw[:8] + bytearray(np.random.default_rng(7).integers(0, 256, 1 << 20, dtype=np.uint8).tobytes())
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(raw))
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    state = ReadState()
    t0 = time.process_time()
    _values(bad, state)
    assert time.process_time() - t0 < 30  # a scan of 1 MB, not a decompression of a GiB
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0 < MAX_CHUNK_BYTES // 1024 // 4
    assert state.damaged or state.truncated


def test_log_times_beyond_int64_are_skipped_and_counted(tmp_path):
    path = tmp_path / "t.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2", library="test")
        sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
        cid = w.register_channel("/x", "cdr", sid)
        for k, t in enumerate([10**9, 2**63 + 5, 2 * 10**9, 2**64 - 1, 3 * 10**9]):
            w.add_message(cid, t, _f64(k), 0)
        w.finish()
    state = ReadState()
    np.testing.assert_array_equal(_values(path, state), [0.0, 2.0, 4.0])
    assert state.bad_log_times == 2 and "2^63" in state.damage_report()[0]


def test_an_unchunked_file_reads_fast_and_complete(tmp_path):
    """Messages outside chunks (``use_chunking=False``) are parsed in runs, not one by one."""
    from mcap.writer import CompressionType

    from rollergear_ros.recordings.baginfo import inspect_bag

    path = tmp_path / "flat.mcap"
    n = 50_000
    with open(path, "wb") as fh:
        w = Writer(fh, use_chunking=False, compression=CompressionType.NONE)
        w.start(profile="ros2", library="test")
        sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
        cid = w.register_channel("/x", "cdr", sid)
        for k in range(n):
            w.add_message(cid, 10**9 + k, _f64(k), 0)
        w.finish()
    info = inspect_bag(path)
    assert info.indexed and info.counts == {"/x": n}  # its summary is used, no "has no index"
    state = ReadState()
    chunks = list(iter_message_arrays(path, state))
    assert len(chunks) < 10  # runs of ~1 MB, not 50 000 single messages
    np.testing.assert_array_equal(_values(path, ReadState()), np.arange(n, dtype=float))


def test_a_fifo_is_refused_not_waited_on(tmp_path):
    import os

    from rollergear_ros.base.errors import BagError

    fifo = tmp_path / "pipe.mcap"
    os.mkfifo(fifo)
    with pytest.raises(BagError, match="not a regular file"):
        list(iter_message_arrays(fifo))


def test_time_ordered_writer_puts_messages_of_every_size_in_log_time_order(tmp_path):
    """``BagWriter`` (time-ordered, as replay writes its outputs): series written topic by topic,
    and one-by-one messages of another size, reach the file in log-time order across topics,
    released in pieces behind a watermark; no chunk reaches into another's time range; both
    readers read back exactly what was written; rosbag2's metadata record counts it."""
    import yaml
    from rosbags.highlevel import AnyReader

    from rollergear_ros.recordings.bagwriter import BagWriter, offered_qos_yaml
    from rollergear_ros.recordings.messages import encoder_for, float64_payloads
    from rollergear_ros.base.interface import MessageType

    rng = np.random.default_rng(7)
    path = tmp_path / "ordered.mcap"
    written: list[tuple[str, int, bytes]] = []
    qos = offered_qos_yaml(reliable=True, depth=200)
    with BagWriter(path, chunk_size=4096, offered_qos={"/a": qos}) as bw:
        for part in range(3):  # three batches; each released up to 50 ms before its newest message
            t0 = 1_000_000_000 + part * 1_000_000_000
            for topic, phase in (("/a", 0), ("/b", 300_000)):
                t = t0 + phase + np.arange(1000, dtype=np.int64) * 1_000_000
                values = rng.normal(size=1000)
                bw.write_float64_series(topic, t, values)
                written += [(topic, int(ti), bytes(p)) for ti, p in zip(t, float64_payloads(values))]
            for t in np.sort(rng.integers(t0 - 40_000_000, t0 + 1_000_000_000, 20)).tolist():
                msg = {"header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": "oil" * (t % 5)},
                       "temperature": 40.0, "variance": 0.0}
                data = encoder_for(MessageType.TEMPERATURE)(msg)
                bw.write_raw("/t", MessageType.TEMPERATURE, t, data)
                written.append(("/t", t, data))
            bw.release(t0 + 950_000_000)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        read = [(ch.topic, m.log_time, m.data) for _, ch, m in reader.iter_messages(log_time_order=False)]
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        qos_of = {ch.topic: ch.metadata["offered_qos_profiles"] for ch in summary.channels.values()}
    times = np.array([t for _, t, _ in read])
    assert np.all(np.diff(times) >= 0), "not in log-time order"
    assert sorted(read) == sorted(written)
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert len(chunks) > 10
    assert all(b.message_start_time >= a.message_end_time for a, b in zip(chunks, chunks[1:]))
    with AnyReader([path]) as ar:
        assert sorted((c.topic, t, bytes(d)) for c, t, d in ar.messages()) == sorted(read)
    info = yaml.safe_load(meta["rosbag2"]["serialized_metadata"])["rosbag2_bagfile_information"]
    assert info["message_count"] == len(read) and info["storage_identifier"] == "mcap"
    assert {t["topic_metadata"]["name"]: t["message_count"] for t in info["topics_with_message_count"]} == {
        "/a": 3000, "/b": 3000, "/t": 60}
    profile = yaml.safe_load(qos_of["/a"])[0]
    assert profile["reliability"] == 1 and profile["depth"] == 200 and qos_of["/b"] == ""


def test_one_call_of_many_messages_is_cut_into_chunks(tmp_path):
    from rollergear_ros.recordings.mcapwriter import ChunkedMcapWriter

    path = tmp_path / "big.mcap"
    w = ChunkedMcapWriter(path, chunk_size=64 * 1024)
    sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
    cid = w.register_channel("/x", "cdr", sid)
    t = 1_000_000_000 + np.arange(100_000, dtype=np.int64) * 1000
    w.add_messages(cid, t, np.zeros((len(t), 12), dtype=np.uint8))
    w.close()
    with open(path, "rb") as f:
        reader = make_reader(f)
        chunks = reader.get_summary().chunk_indexes
        assert sum(1 for _ in reader.iter_messages()) == len(t)
    assert len(chunks) >= 100_000 * 43 // (64 * 1024)
    assert all(c.uncompressed_size <= 64 * 1024 + 43 for c in chunks)


def test_a_time_ordered_writer_with_nothing_or_nothing_old_enough_to_release(tmp_path):
    from rollergear_ros.recordings.bagwriter import BagWriter

    with BagWriter(tmp_path / "empty.mcap") as bw:
        bw.release(10**18)  # nothing held
    with BagWriter(tmp_path / "late.mcap") as bw:
        bw.write_float64_series("/a", np.array([5, 6], dtype=np.int64), np.array([1.0, 2.0]))
        bw.release(4)  # all newer than the watermark: kept for close
    for name, n in (("empty.mcap", 0), ("late.mcap", 2)):
        with open(tmp_path / name, "rb") as f:
            assert sum(1 for _ in make_reader(f).iter_messages()) == n


def test_publish_times_are_written_and_read_back_by_both_readers(tmp_path):
    """A message's publish time (when its publisher sent it) is stored beside its log time and read
    back by this reader and by the ``mcap`` library's; where none is given it is the log time."""
    from rollergear_ros.recordings.bagwriter import BagWriter
    from rollergear_ros.recordings.messages import encode_float64
    from rollergear_ros.base.interface import MessageType

    p = tmp_path / "sent.mcap"
    log = [1_000_000_000 + 7 * k for k in range(50)]
    sent = [t - 1000 - k if k % 3 else None for k, t in enumerate(log)]
    with BagWriter(p, chunk_size=256, time_ordered=False) as bw:
        for k, (t, s) in enumerate(zip(log, sent)):
            bw.write_raw("/x", MessageType.FLOAT64, t, encode_float64(np.array([float(k)]))[0], publish_time_ns=s)
    expect = [t if s is None else s for t, s in zip(log, sent)]
    ours = [a for a in iter_message_arrays(p)]
    assert np.concatenate([a.log_time for a in ours]).tolist() == log
    assert np.concatenate([a.publish_time for a in ours]).tolist() == expect
    with p.open("rb") as fh:
        theirs = [(m.log_time, m.publish_time) for _, _, m in make_reader(fh).iter_messages()]
    assert theirs == list(zip(log, expect))
