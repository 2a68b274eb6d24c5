"""The numpy MCAP reader's log-time ordering against the ``mcap`` library's own reader."""

from __future__ import annotations

import struct

import numpy as np
from mcap.reader import make_reader
from mcap.writer import Writer

from rollergear_ros.fastmcap import ReadState, iter_log_time_order, release_count


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
    import pytest

    from rollergear_ros.bag import BagWriter

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
    # values without noticing; the chunk CRC does
    raw = bytearray(path.read_bytes())
    ci = summary.chunk_indexes[1]
    raw[ci.chunk_start_offset + ci.chunk_length - 200] ^= 0x40
    bad = tmp_path / "flipped.mcap"
    bad.write_bytes(bytes(raw))
    state = ReadState()
    got = sum(len(b[0]) for b in iter_log_time_order(bad, state))
    assert state.truncated and ("CRC" in state.problem or "damaged" in state.problem), state.problem
    assert got < n
    with bad.open("rb") as fh, pytest.raises(Exception):  # noqa: B017 - the reference reader refuses it too
        sum(1 for _ in make_reader(fh, validate_crcs=True).iter_messages())
