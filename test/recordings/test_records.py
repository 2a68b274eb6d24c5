"""The record layout and the chunk scan in C against their numpy twins and a record-by-record
reference: the same bytes, the same messages, the same refusals."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from mcap.writer import Writer

from rollergear_ros.recordings import fastmcap, mcapwriter
from rollergear_ros.recordings.fastmcap import ReadState, parse_records
from rollergear_ros.recordings.mcapwriter import lay_out_records

native = pytest.mark.skipif(mcapwriter._native_records is None, reason="the C part was not built (no compiler)")


def _random_records(seed: int):
    """Records of three payload widths on four channels, a repeating pattern broken by strays (or,
    for seed 5, no pattern at all), rows taken in any order, counters already counting."""
    rng = np.random.default_rng(seed)
    widths = (12, 219, 61)
    motif = rng.integers(0, 2, size=int(rng.integers(1, 12)))
    group = np.tile(motif, int(rng.integers(1, 400)))
    for _ in range(int(rng.integers(0, 30))):
        group = np.insert(group, int(rng.integers(0, len(group) + 1)), int(rng.integers(0, 3)))
    if seed == 5:
        group = rng.integers(0, 3, size=500)
    payloads = [rng.integers(0, 256, size=(int(rng.integers(1, 50)) + len(group), w), dtype=np.uint8) for w in widths]
    row = np.array([rng.integers(0, len(payloads[g])) for g in group.tolist()], dtype=np.int64)
    channel = rng.integers(1, 5, size=len(group))
    log_time = np.sort(rng.integers(0, 2**62, size=len(group)))
    counters = rng.integers(0, 2**33, size=5)  # beyond 32 bits: the record keeps the low 32
    return group, row, channel, log_time, payloads, counters


def _reference(group, row, channel, log_time, payloads, counters) -> bytes:
    """Each record packed by itself with struct, as the MCAP spec lays it out."""
    counters = counters.copy()
    out = bytearray()
    for g, r, c, t in zip(group.tolist(), row.tolist(), channel.tolist(), log_time.tolist()):
        counters[c] += 1
        data = payloads[g][r].tobytes()
        out += struct.pack("<BQHIQQ", 5, 22 + len(data), c, int(counters[c]) & 0xFFFFFFFF, t, t) + data
    return bytes(out)


@pytest.mark.parametrize("way", [pytest.param(True, marks=native, id="C"), pytest.param(False, id="numpy")])
@pytest.mark.parametrize("seed", range(6))
def test_both_layouts_give_the_records_packed_one_by_one(seed, way):
    group, row, channel, log_time, payloads, counters = _random_records(seed)
    widths = np.array([31 + p.shape[1] for p in payloads])[group]
    starts = np.cumsum(widths) - widths
    expected = _reference(group, row, channel, log_time, payloads, counters)
    counted = counters.copy()
    out = lay_out_records(starts, int(widths.sum()), channel, log_time, group, row, payloads, counted, native=way)
    assert out.tobytes() == expected
    np.testing.assert_array_equal(counted - counters, np.bincount(channel, minlength=5))


@pytest.mark.parametrize("way", [pytest.param(True, marks=native, id="C"), pytest.param(False, id="numpy")])
def test_one_group_per_payload_width_however_many(way):
    """An imported bag's messages may come in a hundred widths (strings, arrays): one group each."""
    rng = np.random.default_rng(9)
    payloads = [rng.integers(0, 256, size=(3, w), dtype=np.uint8) for w in range(150)]
    group = rng.permutation(np.repeat(np.arange(150), 2))
    row = rng.integers(0, 3, size=len(group))
    channel = rng.integers(1, 3, size=len(group))
    log_time = np.arange(len(group), dtype=np.int64)
    counters = np.zeros(3, dtype=np.int64)
    widths = 31 + group
    starts = np.cumsum(widths) - widths
    expected = _reference(group, row, channel, log_time, payloads, counters)
    out = lay_out_records(starts, int(widths.sum()), channel, log_time, group, row, payloads, counters, native=way)
    assert out.tobytes() == expected


@native
@pytest.mark.parametrize("bad", ["group", "row", "channel", "start", "short"])
def test_the_c_layout_refuses_a_bad_index_and_writes_nothing(bad):
    group, row, channel, log_time, payloads, counters = _random_records(1)
    widths = np.array([31 + p.shape[1] for p in payloads])[group]
    starts = np.cumsum(widths) - widths
    size = int(widths.sum())
    k = len(group) - 1  # the last record: every one before it would be valid
    if bad == "group":
        group[k] = 3
    elif bad == "row":
        row[k] = len(payloads[group[k]])
    elif bad == "channel":
        channel[k] = 5
    elif bad == "start":
        starts[k] = size - widths[k] + 1
    else:
        channel = channel[:-1]
    counted = counters.copy()
    out = np.zeros(size, dtype=np.uint8)
    with pytest.raises(ValueError):
        mcapwriter._native_records(out, starts, channel, log_time, group, row, payloads, counted)
    assert not out.any() and np.array_equal(counted, counters)


def _chunks(path) -> list[bytes]:
    """The decompressed records of every chunk of ``path``."""
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    with open(path, "rb") as fh:
        return [fastmcap._decompress(r.compression, r.data, r.uncompressed_size)
                for r in StreamReader(fh, emit_chunks=True).records if isinstance(r, Chunk)]


def _mixed_recording(path) -> None:
    """Float64 runs broken by wider and empty messages, with schema and channel records inside chunks."""
    rng = np.random.default_rng(3)
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=8192, compression=None)
        w.start(profile="ros2", library="test")
        sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
        channels = [w.register_channel("/a", "cdr", sid)]
        for k in range(6000):
            if k % 1500 == 0:
                channels.append(w.register_channel(f"/late{k}", "cdr", sid))
            size = 12 if rng.random() < 0.9 else int(rng.integers(0, 300))
            w.add_message(int(rng.choice(channels)), 10**9 + k, rng.integers(0, 256, size, dtype=np.uint8).tobytes(),
                          10**9 + k - int(rng.integers(0, 100)))
        w.finish()


@native
def test_both_scans_find_the_same_messages_schemas_and_channels(tmp_path):
    _mixed_recording(tmp_path / "m.mcap")
    chunks = _chunks(tmp_path / "m.mcap")
    found = {way: (ReadState(), []) for way in (True, False)}
    for data in chunks:
        for way, (state, arrays) in found.items():
            arrays.append(parse_records(data, state, native=way))
    (c_state, c_arrays), (np_state, np_arrays) = found[True], found[False]
    assert c_state.channels == np_state.channels and len(c_state.channels) == 5
    assert c_state.schemas == np_state.schemas
    for field in ("channel", "log_time", "offset", "length", "publish_time"):
        assert np.array_equal(np.concatenate([getattr(a, field) for a in c_arrays]),
                              np.concatenate([getattr(a, field) for a in np_arrays])), field
    assert sum(len(a) for a in c_arrays) == 6000
    short = struct.pack("<BQ", 5, 5) + bytes(5)  # a message record too short for a message's fields
    for way in (True, False):  # a chunk cut inside a record, or a damaged record: the same refusal
        with pytest.raises(ValueError, match="past the end of its chunk"):
            parse_records(chunks[0][:-5], ReadState(), native=way)
        with pytest.raises(ValueError, match="shorter than a message's fields"):
            parse_records(chunks[0] + short, ReadState(), native=way)
