"""Damage found while reading is reported by every command; a recording of which nothing can be
read replaces no output (exit 2), one that lost more than 1 % exits 3 with what was readable."""

from __future__ import annotations

import json

import pytest

from helpers import BAGS, damaged_copy, run_cli

SRC = BAGS / "rig_map.mcap"


def _damaged(tmp_path, every: int):
    return damaged_copy(SRC, tmp_path / f"damaged_{every}.mcap", every)


def test_a_recording_nothing_of_which_is_readable_replaces_no_output(tmp_path):
    """It was replayed to 0 estimates, exit 0, and replaced an existing CSV with an empty one."""
    bag, _ = _damaged(tmp_path, 1)
    keep = tmp_path / "keep.csv"
    keep.write_text("the previous table")
    proc = run_cli("replay", str(bag), "--csv", str(keep), "--out", str(tmp_path / "o.mcap"), check=False)
    assert proc.returncode == 2 and "nothing readable" in proc.stderr.splitlines()[-1], proc.stderr
    assert keep.read_text() == "the previous table" and not (tmp_path / "o.mcap").exists()
    info = run_cli("info", str(bag), "--json", check=False)
    assert info.returncode == 2 and "nothing readable" in info.stderr, info.stderr
    damaged = json.loads(info.stdout)["damaged"]
    assert damaged[-1] == "100.0 % of the recording unreadable" and "zstd decompression failed" in damaged[0]


@pytest.mark.parametrize("command", ["replay", "calibrate"])
def test_a_recording_that_lost_a_chunk_is_said_and_exits_3_with_what_was_readable(tmp_path, command):
    bag, n_chunks = _damaged(tmp_path, 2)
    assert n_chunks >= 2
    out = tmp_path / ("o.mcap" if command == "replay" else "c.yaml")
    proc = run_cli(command, str(bag), "--out", str(out), check=False, timeout=300)
    assert proc.returncode == 3 and "Traceback" not in proc.stderr, proc.stderr
    assert "messages lost" in proc.stderr and "% of the recording unreadable (more than 1 %)" in proc.stderr
    assert out.exists()


def test_predict_of_a_damaged_recording_says_it_and_exits_3_with_what_was_readable(tmp_path):
    """`predict` gave its figures of half a recording with exit 0 and no word of the damage."""
    bag, _ = _damaged(tmp_path, 2)
    proc = run_cli("predict", str(bag), "--json", check=False, timeout=300)
    assert proc.returncode == 3 and "Traceback" not in proc.stderr, proc.stderr
    assert "% of the recording unreadable (more than 1 %): predicted from what was readable" in proc.stderr
    result = json.loads(proc.stdout)
    whole = json.loads(run_cli("predict", str(SRC), "--json").stdout)
    assert 0.01 < result["lost_share"] < 1 and whole["lost_share"] == 0
    assert 0 < result["samples"] < whole["samples"]
    nothing, _ = _damaged(tmp_path, 1)
    proc = run_cli("predict", str(nothing), check=False)
    assert proc.returncode == 2 and "nothing readable" in proc.stderr.splitlines()[-1], proc.stderr


def test_info_reads_every_chunk_and_says_what_is_damaged(tmp_path):
    """Info said "damaged: nothing found" for a file replay could not read: it read only the summary."""
    bag, _ = _damaged(tmp_path, 2)
    proc = run_cli("info", str(bag), check=False)
    assert proc.returncode == 3, proc.stderr  # more than 1 % lost: described, and said (the exit statuses' table)
    damaged = [ln for ln in proc.stdout.splitlines() if ln.startswith("damaged:")][0]
    assert "zstd decompression failed" in damaged and "% of the recording unreadable" in damaged
    assert "damaged:   nothing found" in run_cli("info", str(SRC)).stdout


def test_padded_float64_inputs_are_copied_as_every_reader_reads_them(tmp_path):
    """20-byte Float64 payloads (CDR padding after the value) were copied as they were into replay's
    output MCAP, which rosbags then could not read."""
    import numpy as np

    from rollergear_ros.base.interface import MessageType
    from rollergear_ros.recordings.bagwriter import BagWriter
    from rollergear_ros.recordings.messages import TopicMap, encode_float64

    from bagtools import read_mcap_ros2, read_rosbags

    tm, n = TopicMap(), 200
    t = 1_700_000_000 * 10**9 + np.arange(n, dtype=np.int64) * 10_000_000
    values = {tm.motor_torque: np.linspace(1, 5, n), tm.motor_speed: np.linspace(10, 50, n)}
    bag = tmp_path / "padded.mcap"
    with BagWriter(bag) as w:
        for k in range(n):
            for topic, v in values.items():
                w.write_raw(topic, MessageType.FLOAT64, int(t[k]), encode_float64(v[k:k + 1])[0] + bytes(8))
    run_cli("replay", str(bag), "--out", str(tmp_path / "o.mcap"), "--no-png")
    for read in (read_rosbags, read_mcap_ros2):
        got = read(tmp_path / "o.mcap")
        for topic, v in values.items():
            np.testing.assert_array_equal(np.array([m if isinstance(m, float) else m.data for m in got[topic][1]]), v)


def _uncompressed_copy(src, out):
    """``src`` rewritten by the mcap library's writer with uncompressed chunks of 64 KiB; its chunk
    indexes (where each chunk's records start and how long they are)."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    with open(src, "rb") as fh, open(out, "wb") as dst:
        reader = make_reader(fh)
        writer = Writer(dst, chunk_size=64 * 1024, compression=CompressionType.NONE)
        writer.start(profile="ros2", library="test")
        summary = reader.get_summary()
        for schema in summary.schemas.values():
            writer.register_schema(schema.name, schema.encoding, schema.data)
        ids = {c.id: writer.register_channel(c.topic, c.message_encoding, c.schema_id, c.metadata)
               for c in summary.channels.values()}
        for _schema, channel, message in reader.iter_messages(log_time_order=False):
            writer.add_message(ids[channel.id], message.log_time, message.data, message.publish_time,
                               message.sequence)
        writer.finish()
    with open(out, "rb") as fh:
        return sorted(make_reader(fh).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)


def _patched(path, chunk, records: bytes | None = None, crc: int | None = None, length_at: int | None = None):
    """Patch one uncompressed chunk in place: its records, its CRC, or the length field of the record
    at ``length_at`` (bytes into the records) set to reach the end of the records."""
    import struct
    import zlib

    data = bytearray(path.read_bytes())
    head = chunk.chunk_start_offset + 9
    size = struct.unpack_from("<Q", data, head + 16)[0]
    rec = head + 8 + 8 + 8 + 4 + 4 + 8  # start, end, uncompressed size, crc, compression "" , compressed size
    if records is not None:
        data[rec:rec + size] = records
    if length_at is not None:
        struct.pack_into("<Q", data, rec + length_at + 1, size - length_at - 9)
        crc = zlib.crc32(bytes(data[rec:rec + size]))  # a CRC-valid chunk: the damage was there when it was written
    if crc is not None:
        struct.pack_into("<I", data, head + 24, crc)
    path.write_bytes(bytes(data))
    return size


@pytest.mark.parametrize("damage", ["empty records, CRC 0", "a record's length swallows the chunk"])
def test_messages_a_chunks_index_lists_but_its_records_lost_are_reported_and_exit_3(tmp_path, damage):
    """A chunk whose records are gone (CRC 0: "not computed") or whose one record's length swallows the
    rest (CRC valid): its message index lists the messages.  info, replay, play and map --measured say
    how many were lost, and where; each exits 3 (more than 1 % lost)."""
    bag = tmp_path / "d.mcap"
    chunks = _uncompressed_copy(SRC, bag)
    assert len(chunks) >= 8
    target = chunks[len(chunks) // 2]
    import struct

    from mcap.reader import make_reader

    with open(bag, "rb") as fh:
        reader = make_reader(fh)
        listed = sum(1 for _s, _c, m in reader.iter_messages(log_time_order=False)
                     if target.message_start_time <= m.log_time <= target.message_end_time)
    if damage.startswith("empty"):
        size = struct.unpack_from("<Q", bag.read_bytes(), target.chunk_start_offset + 9 + 16)[0]
        _patched(bag, target, records=bytes([0x7F]) + struct.pack("<Q", size - 9) + bytes(size - 9), crc=0)
    else:
        _patched(bag, target, length_at=0)
    info = json.loads(run_cli("info", str(bag), "--json", check=False).stdout)
    said = " ".join(info["damaged"])
    assert "message index lists" in said and "messages lost" in said, said
    for command in (("replay", str(bag), "--out", str(tmp_path / "o.mcap")),
                    ("map", "--recording", str(bag), "--measured", "--out", str(tmp_path / "m.vtlm"))):
        proc = run_cli(*command, check=False, timeout=300)
        assert proc.returncode == 3 and "Traceback" not in proc.stderr, (command, proc.returncode, proc.stderr)
        assert "messages lost" in proc.stderr or "unreadable" in proc.stderr, proc.stderr
    assert listed > 100


#: the exit status each command gives (docs/interface.md, "Exit statuses"): a whole recording, one that
#: lost more than 1 %, one of which nothing is readable
EXIT_STATUSES = {"whole": 0, "damaged": 3, "nothing readable": 2}


@pytest.mark.parametrize("command", [("info", "{bag}"), ("replay", "{bag}", "--out", "{tmp}/o.mcap"),
                                     ("predict", "{bag}", "--json"),
                                     ("map", "--recording", "{bag}", "--out", "{tmp}/m.vtlm", "--no-plot")])
def test_every_command_gives_the_exit_status_of_the_table(tmp_path, command):
    """The table holds for each command (`info` exited 0 on a recording 7.2 % or 100 % unreadable)."""
    bags = {"whole": SRC, "damaged": _damaged(tmp_path, 2)[0], "nothing readable": _damaged(tmp_path, 1)[0]}
    for kind, status in EXIT_STATUSES.items():
        args = [a.format(bag=bags[kind], tmp=tmp_path) for a in command]
        proc = run_cli(*args, check=False, timeout=300)
        assert proc.returncode == status and "Traceback" not in proc.stderr, (kind, args, proc.returncode,
                                                                              proc.stderr[-500:])
        if status:
            assert proc.stderr.strip().splitlines()[-1].startswith("rollergear: error: "), proc.stderr
