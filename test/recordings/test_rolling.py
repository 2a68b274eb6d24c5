"""Recordings split by size or duration (recordings/rolling.py): every file whole and readable on its
own by both MCAP readers, together the one unsplit recording; names from the template, never an
existing file overwritten."""

from __future__ import annotations

import datetime
import signal
import subprocess
import sys

import numpy as np
import pytest

from rollergear_ros.base.interface import MessageType
from rollergear_ros.recordings.bagwriter import BagWriter
from rollergear_ros.recordings.messages import encode_float64
from rollergear_ros.recordings.baginfo import read_metadata
from rollergear_ros.recordings.rolling import RollingRecorder, file_name, free_name, template_problem

from bagtools import read_mcap_ros2, read_rosbags

START_NS = 1_790_000_000 * 10**9  # 2026-09-21T...Z
TOPICS = ("/rollergear/motor/torque", "/rollergear/loss/torque")
LATCHED = "/rollergear/loss/map"


class Clock:
    def __init__(self) -> None:
        self.ns = START_NS

    def __call__(self) -> int:
        return self.ns


def _stream(writer, clock: Clock, seconds: int, roll=None) -> list[tuple[str, int, float]]:
    """A node's worth of messages: two topics at 100 Hz, a latched one now and then; ``roll`` called
    once a second, as the node's timer."""
    written = []
    values = iter(np.linspace(-5.0, 5.0, seconds * 200 + 10))
    for k in range(seconds * 100):
        clock.ns = START_NS + k * 10_000_000
        for topic in TOPICS:
            v = float(next(values))
            writer.write_raw(topic, MessageType.FLOAT64, clock.ns, encode_float64(np.array([v]))[0])
            written.append((topic, clock.ns, v))
        if k % 250 == 0:
            writer.write_raw(LATCHED, MessageType.FLOAT64, clock.ns, encode_float64(np.array([float(k)]))[0])
            written.append((LATCHED, clock.ns, float(k)))
        if roll is not None and k % 100 == 99:
            roll()
    return written


def _open(path):
    return BagWriter(path, chunk_size=4096, time_ordered=False, replace_atomically=False, durable=True)


@pytest.mark.parametrize("limit", ["duration", "size"])
def test_split_files_are_each_whole_and_together_the_unsplit_recording(tmp_path, limit):
    clock = Clock()
    kwargs = {"max_s": 3.0} if limit == "duration" else {"max_bytes": 20_000}
    rolling = RollingRecorder(str(tmp_path / "rig_{start}.mcap"), _open, clock, latched=(LATCHED,), **kwargs)
    rolling.add_metadata("rollergear_provenance", {"parameters": "gearbox: ...", "package": "rollergear_ros"})
    written = _stream(rolling, clock, 10, rolling.roll_if_due)
    rolling.close()
    unsplit = BagWriter(tmp_path / "whole.mcap", time_ordered=False, replace_atomically=False)
    _stream(unsplit, Clock(), 10)
    unsplit.close()

    files = rolling.files
    assert len(files) >= 3 and len(set(files)) == len(files)
    for path in files:  # named by their start time
        assert path.name.startswith("rig_2026") and path.name.endswith("Z.mcap") and path.exists()
    joined = {topic: [] for topic in (*TOPICS, LATCHED)}
    repeats = []  # (the file's first log time, its first latched value), for the files after the first
    for index, path in enumerate(files):
        by_mcap, by_rosbags = read_mcap_ros2(path), read_rosbags(path)  # each file on its own, both readers
        assert by_mcap.keys() == by_rosbags.keys()
        assert read_metadata(path, "rollergear_provenance")["parameters"] == "gearbox: ..."
        assert LATCHED in by_mcap, "each file starts with the latched topic's last message"
        for topic, (t, msgs) in by_mcap.items():
            np.testing.assert_array_equal(t, by_rosbags[topic][0])
            joined[topic].append((t, [m.data for m in msgs]))
        if index:
            repeats.append((by_mcap[LATCHED][0][0], by_mcap[LATCHED][1][0].data))
    whole = read_mcap_ros2(tmp_path / "whole.mcap")
    for topic in TOPICS:  # the split files together are the unsplit recording
        t = np.concatenate([p[0] for p in joined[topic]])
        v = np.concatenate([p[1] for p in joined[topic]])
        np.testing.assert_array_equal(t, whole[topic][0])
        np.testing.assert_array_equal(v, [m.data for m in whole[topic][1]])
    # the latched topic: each later file starts with the last message written before it opened
    latched_written = [(t, v) for topic, t, v in written if topic == LATCHED]
    for opened, value in repeats:
        assert value == [v for t, v in latched_written if t <= opened][-1]
    if limit == "size":
        assert all(p.stat().st_size < 40_000 for p in files[:-1])


def test_names_come_from_the_template_and_an_existing_file_is_never_overwritten(tmp_path):
    stamp = datetime.datetime.fromtimestamp(START_NS / 1e9, datetime.UTC).strftime("%Y%m%dT%H%M%SZ")
    assert file_name(str(tmp_path / "rig_{start}.mcap"), START_NS, 3, True).name == f"rig_{stamp}.mcap"
    assert file_name(str(tmp_path / "rig_{index}.mcap"), START_NS, 3, False).name == "rig_3.mcap"
    assert file_name(str(tmp_path / "rig.mcap"), START_NS, 2, True).name == "rig_2.mcap"  # as rosbag2
    assert file_name(str(tmp_path / "rig.mcap"), START_NS, 0, False).name == "rig.mcap"
    old = tmp_path / f"rig_{stamp}.mcap"
    old.write_bytes(b"yesterday's recording")
    clock = Clock()
    rolling = RollingRecorder(str(tmp_path / "rig_{start}.mcap"), _open, clock)  # a restart in the same second
    rolling.close()
    assert old.read_bytes() == b"yesterday's recording"
    assert rolling.files == [tmp_path / f"rig_{stamp}_1.mcap"] and free_name(old) == tmp_path / f"rig_{stamp}_2.mcap"


#: a recorder as the node runs it (durable files, rolled by a timer), killed by SIGKILL at the
#: ``kill_at``-th write of a file's records (1: a file opened, its header not written; 2: its header
#: written, its first metadata not; ...) or just after a file was linked to its name ("link")
KILLED_RECORDER = r"""
import os, signal, sys
import numpy as np
from rollergear_ros.base.interface import MessageType
from rollergear_ros.recordings import mcapwriter
from rollergear_ros.recordings.bagwriter import BagWriter
from rollergear_ros.recordings.messages import encode_float64
from rollergear_ros.recordings.rolling import RollingRecorder

template, kill_at, max_s, max_bytes = sys.argv[1], sys.argv[2], float(sys.argv[3]), int(sys.argv[4])
writes = 0
append = mcapwriter.ChunkedMcapWriter._append
def killing(self, parts):
    global writes
    writes += 1
    if str(writes) == kill_at:
        os.kill(os.getpid(), signal.SIGKILL)
    return append(self, parts)
mcapwriter.ChunkedMcapWriter._append = killing
if kill_at == "link":
    unlink = os.unlink
    def killed_unlink(path, *a, **k):
        if str(path).endswith(".partial"):
            os.kill(os.getpid(), signal.SIGKILL)
        return unlink(path, *a, **k)
    os.unlink = killed_unlink
clock = [1_790_000_000 * 10**9]
rec = RollingRecorder(template, lambda p: BagWriter(p, chunk_size=2048, time_ordered=False,
                                                    replace_atomically=False, durable=True),
                      lambda: clock[0], max_bytes, max_s, (),
                      (("rollergear_provenance", {"parameters": "gearbox: ..."}),))
for k in range(3000):
    clock[0] += 10_000_000
    rec.write_raw("/rollergear/motor/torque", MessageType.FLOAT64, clock[0], encode_float64(np.array([float(k)]))[0])
    if k % 50 == 49:
        rec.roll_if_due()
rec.close()
print("not killed")
"""


@pytest.mark.parametrize("template", ["rig.mcap", "rig_{index}.mcap", "r_{start}_{index}.mcap", "rig_{start}.mcap"])
def test_a_recorder_killed_at_any_write_leaves_every_named_file_readable_by_both_readers(tmp_path, template):
    """SIGKILL at each of a recording's first writes (a file opened before its header, after it, after
    its metadata, after each chunk), just after a file took its name, split by duration and by size,
    restarted in the same folder: every file that has a name is read by ``mcap`` and ``rosbags`` alike,
    holds the provenance, and every message it holds is one that was written, in order."""
    runs = 0
    for max_s, max_bytes in ((1.0, 0), (0.0, 6000)):
        for kill_at in ("1", "2", "3", "5", "10", "link"):
            folder = tmp_path / f"{max_s}_{max_bytes}"
            folder.mkdir(exist_ok=True)
            proc = subprocess.run([sys.executable, "-c", KILLED_RECORDER, str(folder / template), kill_at,
                                   str(max_s), str(max_bytes)], capture_output=True, text=True, timeout=120)
            assert proc.returncode == -signal.SIGKILL, (kill_at, proc.returncode, proc.stdout, proc.stderr)
            runs += 1
            for path in sorted(folder.glob("*.mcap")):  # the named files of every run so far (restarts)
                by_mcap, by_rosbags = read_mcap_ros2(path), read_rosbags(path)
                assert by_mcap.keys() == by_rosbags.keys(), path
                assert read_metadata(path, "rollergear_provenance")["parameters"] == "gearbox: ...", path
                for topic, (t, msgs) in by_mcap.items():
                    np.testing.assert_array_equal(t, by_rosbags[topic][0])
                    values = np.array([m.data for m in msgs])
                    assert np.all(np.diff(values) == 1.0) and values[0] == np.round(values[0]), path
    assert runs == 12


@pytest.mark.parametrize(("template", "problem"), [
    ("{start}", "ending in .mcap"), (".mcap", "ending in .mcap"), ("rig.rrd", "ending in .mcap"),
    ("r" * 300 + ".mcap", "bytes with its fields filled in"), ("r" * 236 + "_{start}.mcap", "bytes"),
    ("rig_{start}.mcap", None), ("rig.mcap", None), ("runs/r_{start}_{index}.mcap", None), ("r" * 200 + ".mcap", None)])
def test_a_name_that_makes_no_recording_is_refused_with_the_reason(template, problem):
    """The node's record name: no suffix ('{start}' alone), nothing before it ('.mcap', which split made
    hidden '.mcap_0' files), or a name the file system refuses once its fields are filled in."""
    found = template_problem(template, ".mcap")
    assert (found is None) if problem is None else (problem in found), found
    if problem is None:  # the longest file it makes, hidden while it is opened, can be created
        longest = file_name(template, 4_102_444_799 * 10**9, 9999, True).name
        assert len(f".{longest}.000000.partial".encode()) <= 255
