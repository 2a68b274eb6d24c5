"""``play`` of an MCAP whose topics are no valid ROS 2 names: those are named and left out, and a
bag with none valid is one line and exit 2 (it was an InvalidTopicNameException traceback)."""

from __future__ import annotations

import numpy as np
import pytest

from rollergear_ros.recordings.bagwriter import BagWriter
from rollergear_ros.recordings.baginfo import inspect_bag
from rollergear_ros.ros.player import _playable

from helpers import BAGS, damaged_copy, run_cli


def _bag(path, topics):
    with BagWriter(path) as w:
        for topic in topics:
            w.write_float64_series(topic, np.arange(1, 4, dtype=np.int64), np.ones(3))
    return path


def test_a_bag_without_a_valid_topic_name_is_one_line_and_exit_2(tmp_path):
    bag = _bag(tmp_path / "bad.mcap", ["/spam/0", "/x\x1b[2J\rfake line"])
    proc = run_cli("play", str(bag), check=False, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.count("\n") == 1 and "no topic of the bag is a valid ROS 2 topic name" in proc.stderr
    assert "\x1b" not in proc.stderr and "\r" not in proc.stderr  # shown escaped, never as terminal codes


def test_the_valid_topics_are_played_and_the_others_named(tmp_path, capsys):
    bag = _bag(tmp_path / "mixed.mcap", ["/spam/0", "/rollergear/motor/torque"])
    assert list(_playable(inspect_bag(bag), None)) == ["/rollergear/motor/torque"]
    assert "not played (not valid ROS 2 topic names): '/spam/0'" in capsys.readouterr().err


@pytest.mark.ros
def test_play_of_a_damaged_recording_says_what_it_lost_and_exits_3(tmp_path):
    """It played 24 199 of 40 824 messages of a damaged file without a word."""
    bag, _ = damaged_copy(BAGS / "rig_map.mcap", tmp_path / "damaged.mcap", 2)
    proc = run_cli("play", str(bag), "--no-wait", "--rate", "50", check=False, timeout=300)
    assert proc.returncode == 3 and "Traceback" not in proc.stderr, proc.stderr
    assert "messages lost" in proc.stderr and "played what was readable" in proc.stderr
