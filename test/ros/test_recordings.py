"""The node's live recordings over real DDS: split by duration into whole files named by their start,
together what one unsplit recording of the same inputs holds, with /diagnostics and the loss map in them."""

from __future__ import annotations

import numpy as np
import pytest

from rollergear_ros.recordings.messages import TopicMap
from rollergear_ros.recordings.baginfo import inspect_bag, read_metadata

from bagtools import float_series, read_mcap_ros2, read_rosbags
from helpers import BAGS
from rostools import LOSSLESS, FloatProbe, NodeProcess, play, ros_context, wait_for
from test_layouts import check_node_topics

pytestmark = [pytest.mark.ros, pytest.mark.slow]

T = TopicMap()


def test_a_split_recording_is_whole_files_that_together_are_the_unsplit_one(tmp_path):
    bag = BAGS / "rig_map_drag.mcap"
    n = inspect_bag(bag).counts[T.motor_torque]
    common = (*LOSSLESS, "node.trace_period_s:=3.0")
    split = NodeProcess(f"node.record_mcap:={tmp_path / 'split' / 'rig_{start}.mcap'}", "node.record_max_s:=2.0",
                        *common)
    whole = NodeProcess(f"node.record_mcap:={tmp_path / 'whole.mcap'}", *common)
    with ros_context() as probe_node:  # both nodes take the same played inputs
        probe = FloatProbe(probe_node, T.loss_torque)
        inputs = (T.motor_torque, T.motor_speed, T.output_torque, T.output_speed, T.oil_temperature)
        # both nodes in the graph with their inputs, both outputs matched: the player then waits until
        # every subscriber the graph shows has matched it (its default), so both get the first message
        assert wait_for(lambda: all(probe_node.count_subscribers(t) >= 2 for t in inputs)
                        and probe.subscription.get_publisher_count() >= 2, 120)
        play(bag, "--rate", "10", "--min-subscribers", "2")  # the player sees both nodes before it starts
        assert wait_for(lambda: len(probe) >= 2 * n, 600), f"{len(probe)} of {2 * n}"
        # a trace of the whole node's buffer (every 3 s) recorded before it stops: the layouts' trace
        # panel has something to show (a slow machine's worker takes longer than the play)
        assert wait_for(lambda: inspect_bag(tmp_path / "whole.mcap").counts.get("/rollergear/loss/traced", 0) > 0,
                        600, step=1.0)
        assert wait_for(lambda: (tmp_path / "whole.mcap").exists(), 10)
    assert split.stop() == 0 and whole.stop() == 0, split.stderr + whole.stderr
    files = sorted((tmp_path / "split").glob("rig_*.mcap"))
    assert len(files) >= 3, files
    assert f"wrote: {', '.join(str(f) for f in files)}" in split.stderr
    joined: dict[str, list] = {}
    for path in files:  # each file on its own: both readers, the provenance with the parameters
        by_mcap, by_rosbags = read_mcap_ros2(path), read_rosbags(path)
        assert by_mcap.keys() == by_rosbags.keys()
        assert "gearbox" in read_metadata(path, "rollergear_provenance")["parameters"]
        assert read_metadata(path, "rollergear_recording")["pairing"]
        assert "/rollergear/loss/map" in by_mcap  # the live map, repeated at the start of each file
        for topic in (T.motor_torque, T.output_torque, T.loss_torque, "/rollergear/efficiency/measured"):
            if topic in by_mcap:
                joined.setdefault(topic, []).append(float_series(by_mcap, topic)[1])
        assert "/diagnostics" in by_mcap or path == files[-1]
    one = read_mcap_ros2(tmp_path / "whole.mcap")
    for topic in (T.motor_torque, T.output_torque, T.loss_torque):  # the same inputs, the same estimates
        np.testing.assert_array_equal(np.concatenate(joined[topic]), float_series(one, topic)[1])
    assert len(np.concatenate(joined[T.motor_torque])) == n
    statuses = [s for m in one["/diagnostics"][1] for s in m.status]
    assert any(s.name.endswith("roller gearbox losses") for s in statuses)
    check_node_topics(one)  # what the layouts show of the node's status and traces is in its recording


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_a_signal_to_the_nodes_process_group_prints_no_traceback(sig, tmp_path):
    """Ctrl-C in a terminal signals the whole process group -- the node and its tracing worker: the
    node stops cleanly, the worker quietly, nothing prints a traceback."""
    import os
    import signal
    import subprocess
    import sys

    from helpers import CONFIG, ROOT

    rec = tmp_path / "rec.mcap"
    proc = subprocess.Popen([sys.executable, "-m", "rollergear_ros.ros.node",
                             "--ros-args", "--params-file", str(CONFIG), "-p", "node.trace:=true",
                             "-p", f"node.record_mcap:={rec}"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT, start_new_session=True)
    try:
        with ros_context() as probe_node:  # the node is up, its worker process spawned
            assert wait_for(lambda: probe_node.count_publishers(T.loss_torque) >= 1, 120)
            workers = lambda: subprocess.run(["pgrep", "-g", str(proc.pid)], capture_output=True,  # noqa: E731
                                             text=True).stdout.split()
            assert wait_for(lambda: len(workers()) >= 2, 60), "the tracing worker runs in the node's group"
        os.killpg(proc.pid, getattr(signal, sig))
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    assert proc.returncode == 0, err
    assert "Traceback" not in out + err and "KeyboardInterrupt" not in out + err, err
    assert "stopped:" in err and rec.exists()
