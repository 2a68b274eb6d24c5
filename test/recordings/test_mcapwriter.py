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
    from rollergear_ros.recordings.mcapwriter import interleave

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
