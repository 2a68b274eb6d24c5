"""Outputs are replaced atomically: a failure, a full disk or a kill never leaves a truncated file
where a good one was (atomic.py, and every writer of the package through it)."""

from __future__ import annotations

import os

import numpy as np
import pytest

from rollergear_ros.base import atomic
from rollergear_ros.recordings.bagwriter import BagWriter

from bagtools import read_rosbags
from helpers import BAGS, partial_files, run_cli

BAG = str(BAGS / "rig_map_drag.mcap")


def test_replacing_puts_the_new_file_in_place_only_when_whole(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("good")
    with pytest.raises(RuntimeError), atomic.replacing(target) as partial:
        partial.write_text("half")
        assert target.read_text() == "good"  # not in place while written
        raise RuntimeError("the command failed")
    assert target.read_text() == "good" and not partial_files(target)
    with atomic.replacing(target) as partial:
        partial.write_text("new")
    assert target.read_text() == "new" and not partial_files(target)


def test_a_new_file_gets_the_permissions_of_a_plain_open_and_a_symlink_keeps_pointing(tmp_path):
    old = os.umask(0o022)
    try:
        atomic.write_text(tmp_path / "f.txt", "x")
    finally:
        os.umask(old)
    assert (tmp_path / "f.txt").stat().st_mode & 0o777 == 0o644  # not mkstemp's 0600
    real = tmp_path / "real.txt"
    real.write_text("old")
    link = tmp_path / "link.txt"
    link.symlink_to(real)
    atomic.write_text(link, "new")
    assert link.is_symlink() and real.read_text() == "new"


def test_a_bag_writer_that_fails_leaves_the_previous_file(tmp_path):
    """``import neg.csv --out prev.mcap`` truncated prev.mcap when it opened it, and the crash left 582 bytes."""
    prev = tmp_path / "prev.mcap"
    with BagWriter(prev) as w:
        w.write_float64_series("/a", np.arange(10, dtype=np.int64), np.arange(10.0))
    before = prev.read_bytes()
    with pytest.raises(ValueError), BagWriter(prev) as w:
        w.write_float64_series("/a", np.arange(5, dtype=np.int64), np.ones(5))
        raise ValueError("the import failed half way")
    assert prev.read_bytes() == before and not partial_files(prev)
    assert len(read_rosbags(prev)["/a"][0]) == 10


@pytest.mark.parametrize(("args", "victim"), [
    (["replay", BAG, "--out", "{d}/o.mcap", "--no-png"], "o.mcap"),
    (["replay", BAG, "--rrd", "{d}/o.rrd", "--no-png"], "o.rrd"),
    (["calibrate", BAG, "--report", "{d}/report"], "report/residual_over_time.png"),
    (["figures", "--out", "{d}/figs"], "figs/fig06.png"),
    (["map", "--out", "{d}/m.vtlm"], "m.png"),
])
def test_a_full_disk_is_one_line_and_leaves_the_previous_output_whole(tmp_path, args, victim):
    """--rrd, calibrate --report and figures ended in tracebacks on a full disk (here: a file size
    limit, EFBIG, as a full disk gives ENOSPC); and a half-written file replaced the old one."""
    path = tmp_path / victim
    path.parent.mkdir(parents=True, exist_ok=True)
    old = b"the previous output " * 8192  # 160 KB: already past the limit below
    path.write_bytes(old)
    proc = run_cli(*[a.format(d=tmp_path) for a in args], check=False, timeout=300, max_file_bytes=8_000)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    errors = [ln for ln in proc.stderr.splitlines() if "error" in ln.lower()]  # beside the progress lines
    assert len(errors) == 1 and errors[0].startswith("rollergear: error: ") and str(tmp_path) in errors[0], errors
    assert path.read_bytes() == old
    assert not list(tmp_path.rglob("*.partial"))


def test_the_files_of_one_block_are_put_in_place_together_or_none(tmp_path):
    """:func:`atomic.together`: a failure after one output was complete leaves that one's old file
    too; when the block ends normally every file is new, and no temporary file stays."""
    a, b = tmp_path / "a.csv", tmp_path / "b.parquet"
    a.write_text("old a")
    b.write_text("old b")
    with pytest.raises(OSError), atomic.together():
        atomic.write_text(a, "new a")
        assert a.read_text() == "old a"  # complete, not yet in place
        with atomic.replacing(b) as partial:
            partial.write_text("half")
            raise OSError(27, "File too large")
    assert a.read_text() == "old a" and b.read_text() == "old b" and sorted(tmp_path.iterdir()) == [a, b]
    with atomic.together():
        atomic.write_text(a, "new a")
        atomic.write_text(b, "new b")
    assert a.read_text() == "new a" and b.read_text() == "new b" and sorted(tmp_path.iterdir()) == [a, b]


def test_replay_whose_one_output_fails_leaves_every_output_as_it_was_and_no_temporary_file(tmp_path):
    """``ulimit -f 800`` and five outputs: replay exited 2 and left four ``*.partial`` files; on a
    full disk an MF4 stayed as ``keep.mf4.<random>.mf4`` after ``keep.parquet`` had been replaced."""
    names = ["keep.mcap", "keep.rrd", "keep.csv", "keep.parquet", "keep.mf4"]
    for name in names:
        (tmp_path / name).write_text(f"the previous {name}")
    proc = run_cli("replay", BAG, "--out", str(tmp_path / "keep.mcap"), "--rrd", str(tmp_path / "keep.rrd"),
                   "--csv", str(tmp_path / "keep.csv"), "--parquet", str(tmp_path / "keep.parquet"),
                   "--mf4", str(tmp_path / "keep.mf4"), "--no-png", check=False, timeout=300,
                   max_file_bytes=800 * 1024)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(names)
    for name in names:
        assert (tmp_path / name).read_text() == f"the previous {name}", name
