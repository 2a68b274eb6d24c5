"""rosbag2 folders that are not what they say: a FIFO as a storage file (every reader blocked for
ever, deaf to Ctrl-C), a "zstd-compressed" storage file that is not zstd, a metadata.yaml with
anchors: one line and exit 2 from every command that reads them."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from helpers import run_cli

METADATA = """rosbag2_bagfile_information:
  version: 5
  storage_identifier: mcap
  relative_file_paths: [{name}]
  duration: {{nanoseconds: 1}}
  starting_time: {{nanoseconds_since_epoch: 0}}
  message_count: 0
  topics_with_message_count: []
  compression_format: "{compression}"
  compression_mode: "{mode}"
"""


def _bag(folder: Path, kind: str) -> Path:
    folder.mkdir()
    if kind == "fifo":
        os.mkfifo(folder / "bag_0.mcap")
        (folder / "metadata.yaml").write_text(METADATA.format(name="bag_0.mcap", compression="", mode=""))
    elif kind == "not_zstd":
        (folder / "bag_0.mcap.zstd").write_bytes(bytes(range(256)) * 20)
        (folder / "metadata.yaml").write_text(METADATA.format(name="bag_0.mcap.zstd", compression="zstd",
                                                              mode="file"))
    else:  # anchors: what ROS 2's parser refuses and a YAML bomb is made of
        (folder / "bag_0.mcap").write_bytes(b"")
        (folder / "metadata.yaml").write_text(METADATA.format(name="bag_0.mcap", compression="", mode="")
                                              + "  a: &x [1]\n  b: *x\n")
    return folder


@pytest.mark.parametrize("kind", ["fifo", "not_zstd", "anchors"])
@pytest.mark.parametrize("command", [["info"], ["replay", "--no-png"], ["import", "--out", "{d}/o.mcap"],
                                     ["calibrate"], ["play"]])
def test_a_hostile_rosbag2_folder_is_one_line_and_exit_2(tmp_path, kind, command):
    bag = _bag(tmp_path / "bag", kind)
    args = [command[0], str(bag), *(a.format(d=tmp_path) for a in command[1:])]
    proc = run_cli(*args, check=False, timeout=120)
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("rollergear: error: ")]
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and len(errors) == 1, proc.stderr[-2000:]
    assert str(bag) in errors[0]
    assert not (tmp_path / "o.mcap").exists()
