"""Every file the node writes goes through the CLI's output check, and none replaces a file that is there."""

from __future__ import annotations

import os

import numpy as np
import pytest

from rollergear_ros.base.errors import RollergearError
from rollergear_ros.core.estimator import Estimate

from bagtools import float_series, read_mcap_ros2, read_rosbags
from rostools import FloatProbe, ros_context, wait_for

pytestmark = [pytest.mark.ros]


def _start(probe, **values):
    from rclpy.parameter import Parameter

    from rollergear_ros.ros.node import LossEstimatorNode

    return LossEstimatorNode(context=probe.context,
                             parameter_overrides=[Parameter(k, value=str(v)) for k, v in values.items()])


@pytest.mark.parametrize("clash", ["same", "suffix", "proc"])
def test_a_traced_parameter_file_that_would_replace_a_recording_or_cannot_be_one_is_refused(tmp_path, clash):
    """``node.traced_params_file`` equal to ``node.record_mcap``, named like a recording, or where no
    file can be made: the node refuses to start with one line naming it, and writes nothing."""
    rec = tmp_path / "rec.mcap"
    traced = {"same": rec, "suffix": tmp_path / "cand.mcap", "proc": "/proc/cand.yaml"}[clash]
    with ros_context() as probe:
        with pytest.raises(RollergearError) as err:
            _start(probe, **{"node.record_mcap": rec, "node.traced_params_file": traced})
    assert "node.traced_params_file" in str(err.value) and "\n" not in str(err.value)
    assert not list(tmp_path.iterdir())


def test_files_the_node_rewrites_never_replace_one_that_is_there(tmp_path):
    """An existing map file and candidate parameter file are left as they are: the node takes the
    next free names, says so, and its shutdown line names the files it wrote."""
    map_file, traced = tmp_path / "live.vtlm", tmp_path / "cand.yaml"
    map_file.write_text("someone's map")
    traced.write_text("someone's parameters")
    with ros_context() as probe:
        node = _start(probe, **{"node.map_file": map_file, "node.traced_params_file": traced})
        try:
            assert node.live_map.path == tmp_path / "live_1.vtlm"
            assert node.traced_params_path == tmp_path / "cand_1.yaml"
            assert (tmp_path / "live_1.vtlm").is_file() and node.maps_published == 1
            assert str(tmp_path / "live_1.vtlm") in node.summary_line()
        finally:
            node.destroy_node()
    assert map_file.read_text() == "someone's map" and traced.read_text() == "someone's parameters"


def test_a_fifo_as_the_map_file_is_never_opened(tmp_path):
    """A FIFO where the map file would go: the node writes beside it (opening it would block)."""
    fifo = tmp_path / "live.vtlm"
    os.mkfifo(fifo)
    with ros_context() as probe:
        node = _start(probe, **{"node.map_file": fifo})
        try:
            assert node.live_map.path == tmp_path / "live_1.vtlm" and node.live_map.path.is_file()
        finally:
            node.destroy_node()


@pytest.mark.slow
def test_the_node_publishes_and_records_a_toy_channel(toy_channel, tmp_path):
    """A node made with the toy channel registered offers it, publishes it for an estimate with
    measured output (not for one without) and records it."""
    from rclpy.parameter import Parameter

    from rollergear_ros.ros.node import LossEstimatorNode

    rec = tmp_path / "live.mcap"
    with ros_context() as probe_node:
        node = LossEstimatorNode(context=probe_node.context,
                                 parameter_overrides=[Parameter("node.record_mcap", value=str(rec))])
        try:
            topic = node.out_topics[toy_channel.name]
            assert topic == "/rollergear/loss/measured"
            probe = FloatProbe(probe_node, topic)
            probe.wait_matched()
            unmeasured = Estimate(1_000, 10.0, 50.0, 0.1, 5.0, 0.99, float("nan"), float("nan"))
            measured = Estimate(2_000, 10.0, 50.0, 0.1, 5.0, 0.99, 0.123, 0.023)
            node.publish_estimate(unmeasured)
            node.publish_estimate(measured)
            assert wait_for(lambda: len(probe) >= 1, 60)
            np.testing.assert_array_equal(probe.values(), [0.123])
            node.close()
        finally:
            node.destroy_node()
    for got in (read_mcap_ros2(rec), read_rosbags(rec)):
        np.testing.assert_array_equal(float_series(got, topic)[1], [0.123])
        np.testing.assert_array_equal(float_series(got, "/rollergear/loss/torque")[1], [0.1, 0.1])
