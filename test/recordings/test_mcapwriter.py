"""The array MCAP writer: background chunk writing gives the same file, and its errors surface."""

from __future__ import annotations

import errno
from pathlib import Path

import numpy as np
import pytest

from rollergear_ros.recordings.mcapwriter import ChunkedMcapWriter

from bagtools import read_mcap_ros2, read_rosbags


def write(path, background: bool, n: int = 60_000) -> None:
    """Interleaved topics over many chunks, messages added one by one, a metadata record between."""
    rng = np.random.default_rng(0)
    w = ChunkedMcapWriter(path, chunk_size=32 * 1024, background=background)
    sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
    a, b = w.register_channel("/a", "cdr", sid), w.register_channel("/b", "cdr", sid)
    t = 1_000_000_000 + np.repeat(np.arange(n // 2, dtype=np.int64), 2) * 1_000_000
    payload = np.zeros((n, 12), dtype=np.uint8)
    payload[:, 1] = 1
    payload[:, 4:] = rng.normal(size=n).view(np.uint8).reshape(n, 8)
    w.add_messages(np.tile([a, b], n // 2), t[: n], payload)
    w.add_metadata("m", {"k": "v"})
    for i in range(100):
        w.add_message(a, int(t[-1]) + 1000 * (i + 1), bytes(payload[i]))
    w.add_messages(b, t[-1] + 10**6 + np.arange(5000, dtype=np.int64), payload[:5000])
    w.close()


def test_chunks_written_in_the_background_make_the_same_file(tmp_path):
    write(tmp_path / "fg.mcap", background=False)
    write(tmp_path / "bg.mcap", background=True)
    assert (tmp_path / "bg.mcap").read_bytes() == (tmp_path / "fg.mcap").read_bytes()
    for messages in (read_mcap_ros2(tmp_path / "bg.mcap"), read_rosbags(tmp_path / "bg.mcap")):
        assert len(messages["/a"][0]) == 30_100 and len(messages["/b"][0]) == 35_000


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full")
def test_an_error_of_the_writing_thread_is_raised_in_the_caller():
    """A disk that is full (``/dev/full``: every write fails with ENOSPC) is an OSError of the call
    that adds or closes, never a file silently cut short."""
    for background in (True, False):
        with pytest.raises(OSError) as err:
            write(Path("/dev/full"), background=background)
        assert err.value.filename == "/dev/full" and err.value.errno == errno.ENOSPC


@pytest.mark.parametrize("seed", range(6))
def test_interleave_equals_a_byte_by_byte_layout(seed):
    """The strided copy of repeating patterns lays out the same bytes as placing each record alone,
    for periodic sequences broken by stray records and for sequences with no period at all."""
    from rollergear_ros.recordings.layout import interleave

    rng = np.random.default_rng(seed)
    widths = {0: 43, 1: 219, 2: 61}
    motif = rng.integers(0, 2, size=int(rng.integers(1, 12)))
    group = np.tile(motif, int(rng.integers(1, 400)))
    for _ in range(int(rng.integers(0, 30))):  # stray records (an oil temperature now and then)
        group = np.insert(group, int(rng.integers(0, len(group) + 1)), int(rng.integers(0, 3)))
    if seed == 5:
        group = rng.integers(0, 3, size=500)
    lens = np.array([widths[g] for g in group.tolist()], dtype=np.int64)
    offsets = np.cumsum(lens) - lens
    rows = {g: rng.integers(0, 256, size=(int(np.count_nonzero(group == g)), w), dtype=np.uint8)
            for g, w in widths.items() if np.any(group == g)}
    expected = bytearray()
    used = dict.fromkeys(rows, 0)
    for g in group.tolist():
        expected += rows[g][used[g]].tobytes()
        used[g] += 1
    assert interleave(group, rows, offsets, int(lens.sum())).tobytes() == bytes(expected)


def write_bag(path, background: bool, fail_at: int | None = None) -> None:
    """A time-ordered bag of two payload widths over many releases, as replay writes its output
    (``fail_at``: the release whose payloads cannot be made)."""
    from rollergear_ros.recordings.bagwriter import BagWriter

    rng = np.random.default_rng(1)
    with BagWriter(path, chunk_size=16 * 1024, background=background) as bw:
        for k in range(12):
            t = 10**9 + k * 10**8 + np.arange(1000, dtype=np.int64) * 100_000
            bw.write_float64_series("/a", t + 7, rng.normal(size=1000))
            wide = np.zeros((1000, 44), dtype=np.uint8)  # std_msgs/String of 35 letters (CDR)
            wide[:, 1], wide[:, 4] = 1, 36
            wide[:, 8:43] = rng.integers(ord("a"), ord("z") + 1, (1000, 35), dtype=np.uint8)

            def payloads(wide=wide, k=k):
                if k == fail_at:
                    raise ValueError("no payloads for this batch")
                return wide

            bw.write_fixed("/b", "std_msgs/msg/String", t, payloads, schema_text="string data")
            bw.write_raw("/c", "std_msgs/msg/Float64", int(t[500]), bytes(12), publish_time_ns=1)
            bw.release(int(t[-1]) - 10**7)


def test_a_bag_laid_out_in_the_background_is_the_same_file(tmp_path):
    """The builder thread of a background writer (channels, held messages and their layout, one job
    per release) writes the same messages in the same order as the caller's thread does."""
    write_bag(tmp_path / "fg.mcap", background=False)
    write_bag(tmp_path / "bg.mcap", background=True)
    fg, bg = read_mcap_ros2(tmp_path / "fg.mcap"), read_mcap_ros2(tmp_path / "bg.mcap")
    assert set(fg) == set(bg) == {"/a", "/b", "/c"}
    for topic in fg:
        assert np.array_equal(fg[topic][0], bg[topic][0])
        assert [m.data for m in fg[topic][1]] == [m.data for m in bg[topic][1]]
    assert len(bg["/a"][0]) == 12_000 and len(bg["/b"][0]) == 12_000 and len(bg["/c"][0]) == 12
    assert [m.data for m in read_rosbags(tmp_path / "bg.mcap")["/b"][1]] == [m.data for m in bg["/b"][1]]


def test_an_error_of_the_builder_thread_reaches_the_caller_and_no_file_is_put_in_place(tmp_path):
    out = tmp_path / "out.mcap"
    out.write_bytes(b"the old file")
    with pytest.raises(ValueError, match="no payloads"):
        write_bag(out, background=True, fail_at=5)
    assert out.read_bytes() == b"the old file"
    assert [p.name for p in tmp_path.iterdir()] == ["out.mcap"]  # no partial file left


def test_message_indexes_point_at_every_record_by_log_time(tmp_path):
    """Each chunk's message index (what rosbags counts a chunk's messages by, and seeking readers
    jump with) lists every message of its channel once, by log time, at the offset of its record
    -- also where a recorder wrote a channel's messages out of log-time order."""
    from mcap.records import Chunk, MessageIndex
    from mcap.stream_reader import StreamReader

    from rollergear_ros.recordings.fastmcap import ReadState, _decompress, parse_records

    rng = np.random.default_rng(4)
    w = ChunkedMcapWriter(tmp_path / "i.mcap", chunk_size=16 * 1024)
    sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
    ids = [w.register_channel(f"/{k}", "cdr", sid) for k in range(3)]
    n = 6000
    t = 10**9 + np.arange(n, dtype=np.int64) * 1000
    w.add_messages(np.array(ids)[rng.integers(0, 3, n)], t, rng.integers(0, 256, (n, 12), dtype=np.uint8))
    for k in range(2000):  # one by one, up to 5 µs late: log times go back within a channel
        w.add_message(ids[k % 3], int(t[-1]) + 1000 * k - int(rng.integers(0, 5000)), bytes(20))
    w.close()
    chunk, indexed, seen, k = None, {}, 0, -1
    with open(tmp_path / "i.mcap", "rb") as fh:
        for record in StreamReader(fh, emit_chunks=True).records:
            if isinstance(record, Chunk):
                chunk = parse_records(_decompress(record.compression, record.data, record.uncompressed_size),
                                      ReadState())
                at = {int(o) - 31: i for i, o in enumerate(chunk.offset)}  # record start -> message
                seen, k = seen + len(chunk), k + 1
            elif isinstance(record, MessageIndex):
                times = [time for time, _ in record.records]
                assert times == sorted(times)
                for time, offset in record.records:
                    i = at[offset]
                    assert chunk.channel[i] == record.channel_id and chunk.log_time[i] == time
                    indexed[(k, i)] = indexed.get((k, i), 0) + 1
    assert seen == n + 2000 and len(indexed) == seen and set(indexed.values()) == {1}


def _encoded_by_mcap(records) -> bytes:
    """The bytes the ``mcap`` library's encoder makes of ``records``."""
    from mcap.data_stream import RecordBuilder

    builder = RecordBuilder()
    for record in records:
        record.write(builder)
    return builder.end()


@pytest.mark.parametrize("durable", [False, True], ids=["file", "durable"])
@pytest.mark.parametrize("native", [True, False], ids=["C", "numpy"])
def test_every_record_written_is_the_one_mcap_encodes(tmp_path, monkeypatch, native, durable):
    """One encoder of each record: the file read by ``mcap``'s stream reader and every record of it
    encoded again by ``mcap`` gives the file byte for byte -- header, schemas and channels, chunk
    records, message indexes, metadata, summary and footer; inside each chunk the message records
    added one by one (publish times of their own, payload widths 0 to 300), as arrays and as
    interleaved widths, laid out by C and by numpy -- and every message carries what was added."""
    from mcap.records import Chunk, Message
    from mcap.stream_reader import StreamReader, breakup_chunk
    from mcap.writer import MCAP0_MAGIC

    from rollergear_ros.recordings import layout
    from rollergear_ros.recordings.fastmcap import _decompress

    if native and layout._native_records is None:
        pytest.skip("the C part was not built (no compiler)")
    if not native:
        monkeypatch.setattr(layout, "_native_records", None)
    rng = np.random.default_rng(4)
    path = tmp_path / "w.mcap"
    w = ChunkedMcapWriter(path, chunk_size=8 * 1024, durable=durable)
    sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
    channels = [w.register_channel("/a", "cdr", sid, {"offered_qos_profiles": ""})]
    added = []  # (channel, log time, publish time, payload) in the order added
    for k in range(3000):
        if k % 700 == 0:
            channels.append(w.register_channel(f"/late{k}", "cdr", sid))
        if k % 1000 == 500:
            w.add_metadata(f"m{k}", {"k": str(k)})
        t = 10**9 + 1000 * k
        if k % 10 == 3:  # arrays: one width, then two interleaved
            wide = rng.integers(0, 256, (4, 40), dtype=np.uint8)
            narrow = rng.integers(0, 256, (4, 12), dtype=np.uint8)
            w.add_messages(channels[0], t + np.arange(4), narrow)
            added += [(channels[0], t + i, t + i, narrow[i].tobytes()) for i in range(4)]
            w.add_mixed(np.array([channels[-1]] * 4), t + 5 + np.arange(4), np.array([0, 1, 0, 1]),
                        np.array([0, 0, 1, 1]), [narrow, wide])
            added += [(channels[-1], t + 5 + i, t + 5 + i, [narrow, wide][i % 2][i // 2].tobytes()) for i in range(4)]
            continue
        c = int(rng.choice(channels))
        data = rng.integers(0, 256, 12 if rng.random() < 0.8 else int(rng.integers(0, 300)), dtype=np.uint8).tobytes()
        published = None if rng.random() < 0.5 else t - int(rng.integers(0, 10**6))
        w.add_message(c, t, data, published)
        added.append((c, t, t if published is None else published, data))
    w.close()
    raw = path.read_bytes()
    with path.open("rb") as fh:
        records = list(StreamReader(fh, emit_chunks=True).records)
    assert MCAP0_MAGIC + _encoded_by_mcap(records) + MCAP0_MAGIC == raw
    messages = []
    chunks = [r for r in records if isinstance(r, Chunk)]
    assert len(chunks) > 10
    for chunk in chunks:
        inside = breakup_chunk(chunk, validate_crc=True)
        assert _encoded_by_mcap(inside) == _decompress(chunk.compression, chunk.data, chunk.uncompressed_size)
        messages += [m for m in inside if isinstance(m, Message)]
    assert [(m.channel_id, m.log_time, m.publish_time, m.data) for m in messages] == added
    for cid in channels:
        assert [m.sequence for m in messages if m.channel_id == cid] == list(
            range(1, sum(1 for m in messages if m.channel_id == cid) + 1))


def test_a_message_on_a_channel_never_registered_is_refused(tmp_path):
    w = ChunkedMcapWriter(tmp_path / "w.mcap")
    with pytest.raises(ValueError, match="channel 3 is not registered"):
        w.add_message(3, 1, b"")
    w.close()


def test_a_bad_message_added_one_by_one_is_refused_at_once_and_costs_no_other(tmp_path):
    """The records of messages added one by one are laid out later, together: a time beyond 64 bits
    is refused when added (the others stay), and a buffer changed after it was added is recorded as
    it was when added."""
    from bagtools import read_mcap_ros2

    w = ChunkedMcapWriter(tmp_path / "w.mcap")
    sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
    cid = w.register_channel("/a", "cdr", sid)
    w.add_message(cid, 10, bytes([0, 1, 0, 0]) + np.float64(1.5).tobytes())
    for bad in ({"log_time": 2**63}, {"log_time": 11, "publish_time": -(2**63) - 1}):
        with pytest.raises(ValueError, match="not a 64-bit time"):
            w.add_message(cid, bad["log_time"], bytes(12), bad.get("publish_time"))
    buffer = bytearray(bytes([0, 1, 0, 0]) + np.float64(2.5).tobytes())
    w.add_message(cid, 12, buffer)
    buffer[4:] = np.float64(-9.0).tobytes()
    w.close()
    t, messages = read_mcap_ros2(tmp_path / "w.mcap")["/a"]
    assert t.tolist() == [10, 12] and [m.data for m in messages] == [1.5, 2.5]
