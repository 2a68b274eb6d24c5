"""The record layout and the chunk scan in C against their numpy twins and the ``mcap`` library's
encoder of each record: the same bytes, the same messages, the same refusals."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from mcap.writer import Writer

from rollergear_ros.recordings import fastmcap, layout
from rollergear_ros.recordings.fastmcap import ReadState, parse_records
from rollergear_ros.recordings.layout import lay_out_records

native = pytest.mark.skipif(layout._native_records is None, reason="the C part was not built (no compiler)")


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


def _reference(group, row, channel, log_time, payloads, counters, publish_time=None) -> bytes:
    """Each record as the ``mcap`` library's writer encodes it (``publish_time`` None: the log time)."""
    from mcap.data_stream import RecordBuilder
    from mcap.records import Message

    counters = counters.copy()
    builder = RecordBuilder()
    published = log_time if publish_time is None else publish_time
    for g, r, c, t, p in zip(group.tolist(), row.tolist(), channel.tolist(), log_time.tolist(), published.tolist()):
        counters[c] += 1
        Message(channel_id=c, sequence=int(counters[c]) & 0xFFFFFFFF, log_time=t, publish_time=p,
                data=payloads[g][r].tobytes()).write(builder)
    return builder.end()


@pytest.mark.parametrize("way", [pytest.param(True, marks=native, id="C"), pytest.param(False, id="numpy")])
@pytest.mark.parametrize("seed", range(6))
def test_both_layouts_give_the_records_mcap_encodes(seed, way):
    group, row, channel, log_time, payloads, counters = _random_records(seed)
    widths = np.array([31 + p.shape[1] for p in payloads])[group]
    starts = np.cumsum(widths) - widths
    published = log_time - np.random.default_rng(seed).integers(0, 10**9, size=len(log_time))
    for publish_time in (None, published):
        expected = _reference(group, row, channel, log_time, payloads, counters, publish_time)
        counted = counters.copy()
        out = lay_out_records(starts, int(widths.sum()), channel, log_time, group, row, payloads, counted,
                              native=way, publish_time=publish_time)
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
        layout._native_records(out, starts, channel, log_time, log_time, group, row, payloads, counted)
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


#: a chunk of 3.5 M 9-byte records of an opcode the spec says to skip, between two messages, parsed in
#: a process of its own: how much its peak memory grew, and what was found
SKIPPED_RECORDS = r"""
import resource, struct, sys
from rollergear_ros.recordings.fastmcap import ReadState, parse_records
schema = struct.pack("<BQ", 3, 14) + struct.pack("<H", 1) + struct.pack("<III", 0, 0, 0)
message = struct.pack("<BQHIqq", 5, 22 + 12, 1, 1, 5, 5) + bytes(12)
data = schema + message + struct.pack("<BQ", 0x7F, 0) * 3_500_000 + message
state = ReadState()
rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
arrays = parse_records(data, state, native=sys.argv[1] == "c")
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - rss0, len(data), len(arrays), len(state.schemas))
"""


@pytest.mark.parametrize("way", [pytest.param("c", marks=native), "numpy"])
def test_records_other_than_messages_cost_no_memory_per_record_and_the_two_scans_agree(way):
    """A 864 KB file held 250 MiB of 9-byte records and took 3.3 GB, one Python tuple each: records of
    an opcode the spec says to skip are skipped in runs (a few bytes of index per record at most), the
    messages around them found; opcode 0 and schema or channel records too short for their fields are
    damage, refused alike by both scans."""
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", SKIPPED_RECORDS, way], capture_output=True, text=True, timeout=300)
    grown, size, messages, schemas = map(int, proc.stdout.split())
    assert messages == 2 and schemas == 1, proc.stdout
    assert grown < 2 * size, (grown, size)  # the scan's index arrays, not a tuple per record
    message = struct.pack("<BQHIqq", 5, 22 + 12, 1, 1, 5, 5) + bytes(12)
    for bad, why in ((struct.pack("<BQ", 0, 0), "opcode 0"), (struct.pack("<BQ", 3, 2) + bytes(2), "shorter than")):
        with pytest.raises(ValueError, match=why):
            parse_records(message + bad + message, ReadState(), native=way == "c")


@pytest.mark.parametrize("bad", ["group", "row", "channel", "channel 65537", "start", "short", "counters int32",
                                 "short publish times"])
def test_both_layouts_refuse_a_bad_index_alike_and_change_nothing(bad):
    """One behaviour for both: the same refusal, counters untouched (numpy stored a channel's counts
    before it found the bad group; it wrapped a channel id of 65 537 to 1)."""
    group, row, channel, log_time, payloads, counters = _random_records(2)
    counters = np.zeros(65_538, dtype=np.int64)
    widths = np.array([31 + p.shape[1] for p in payloads])[group]
    starts = np.cumsum(widths) - widths
    size = int(widths.sum())
    k = len(group) - 1
    if bad == "group":
        group[k] = 3
    elif bad == "row":
        row[k] = len(payloads[group[k]])
    elif bad == "channel":
        channel[k] = -1
    elif bad == "channel 65537":
        channel[k] = 65_537
    elif bad == "start":
        starts[k] = size - widths[k] + 1
    elif bad == "short":
        channel = channel[:-1]
    elif bad == "counters int32":
        counters = counters.astype(np.int32)
    publish_time = log_time[:-1] if bad == "short publish times" else log_time
    errors = []
    for way in ([True] if layout._native_records is not None else []) + [False]:
        counted = counters.copy()
        with pytest.raises(ValueError) as err:
            lay_out_records(starts, size, channel, log_time, group, row, payloads, counted, native=way,
                            publish_time=publish_time)
        assert np.array_equal(counted, counters)
        errors.append(str(err.value))
    assert len(set(errors)) == 1, errors


@native
@pytest.mark.parametrize("hostile", ["counters is channel", "out is a view of starts", "float64 starts",
                                     "unaligned starts", "counters is a payload", "counters is the publish times"])
def test_the_c_layout_is_safe_for_any_caller(hostile):
    """Direct calls a well-behaved caller never makes wrote past an array (a sentinel changed, a
    segfault, heap bytes in the output): each is refused, nothing written."""
    group, row, channel, log_time, payloads, counters = _random_records(3)
    widths = np.array([31 + p.shape[1] for p in payloads])[group]
    starts = np.cumsum(widths) - widths
    size = int(widths.sum())
    out = np.zeros(size, dtype=np.uint8)
    counted = counters.copy()
    args = [out, starts, channel, log_time, log_time, group, row, payloads, counted]
    if hostile == "counters is channel":
        args[8] = args[2] = np.ascontiguousarray(channel, dtype=np.int64)
    elif hostile == "out is a view of starts":
        args[0] = starts.view(np.uint8)
    elif hostile == "float64 starts":
        args[1] = starts.astype(np.float64)
    elif hostile == "unaligned starts":
        raw = np.zeros(len(starts) * 8 + 1, dtype=np.uint8)
        unaligned = raw[1:].view(np.int64)
        unaligned[:] = starts
        args[1] = unaligned
    elif hostile == "counters is the publish times":
        args[8] = args[4] = log_time.copy()
    else:
        args[8] = payloads[0].reshape(-1)[:8 * 5].view(np.int64)
    before = [a.copy() if isinstance(a, np.ndarray) else a for a in args]
    with pytest.raises(ValueError):
        layout._native_records(*args)
    for a, b in zip(args, before):
        if isinstance(a, np.ndarray):
            assert np.array_equal(a, b)


@pytest.mark.parametrize("seed", range(40))
def test_differential_fuzz_of_the_two_scans_on_random_and_damaged_chunks(seed, tmp_path):
    """Random chunks (messages of random widths, schema and channel records, skipped opcodes) and the
    same chunks damaged (a byte flipped, cut short, a length changed): both scans give the same
    messages and state, or the same refusal."""
    if fastmcap._native_scan is None:
        pytest.skip("the C part was not built (no compiler)")
    rng = np.random.default_rng(seed)
    parts = []
    for _ in range(int(rng.integers(1, 60))):
        kind = rng.choice(["message", "schema", "channel", "other"], p=[0.7, 0.1, 0.1, 0.1])
        if kind == "message":
            body = struct.pack("<HIqq", int(rng.integers(0, 4)), 0, int(rng.integers(0, 2**62)), 0)
            parts.append(struct.pack("<BQ", 5, len(body) + int(rng.integers(0, 40))) + body)
            parts[-1] += bytes(int.from_bytes(parts[-1][1:9], "little") - len(body))
        elif kind == "schema":
            name = b"s" * int(rng.integers(0, 5))
            body = struct.pack("<HI", int(rng.integers(0, 4)), len(name)) + name + struct.pack("<II", 0, 0)
            parts.append(struct.pack("<BQ", 3, len(body)) + body)
        elif kind == "channel":
            topic = b"/t" * int(rng.integers(0, 3))
            body = struct.pack("<HHI", int(rng.integers(0, 4)), 1, len(topic)) + topic + struct.pack("<II", 0, 0)
            parts.append(struct.pack("<BQ", 4, len(body)) + body)
        else:
            n = int(rng.integers(0, 20))
            parts.append(struct.pack("<BQ", int(rng.integers(6, 256)), n) + bytes(n))
    data = bytearray(b"".join(parts))
    damage = seed % 4
    if damage == 1 and data:
        data[int(rng.integers(0, len(data)))] ^= 0xFF
    elif damage == 2 and data:
        data = data[:int(rng.integers(0, len(data)))]
    elif damage == 3 and len(data) > 9:
        at = int(rng.integers(0, len(data) - 9))
        data[at + 1:at + 9] = struct.pack("<Q", int(rng.integers(0, 2 * len(data))))
    data = bytes(data)
    results = []
    for way in (True, False):
        state = ReadState()
        try:
            arrays = parse_records(data, state, native=way)
            results.append(("ok", state.schemas, state.channels, arrays.channel.tolist(), arrays.log_time.tolist(),
                            arrays.offset.tolist(), arrays.length.tolist()))
        except (ValueError, UnicodeDecodeError, struct.error) as exc:
            results.append(("refused", type(exc).__name__))
    assert results[0] == results[1], results
