"""The output-channel table: every channel documented, and a toy channel added by one entry reaches
replay's MCAP (both readers) and ``watch`` (the live node's publishers and recording:
test/ros/test_node_outputs.py)."""

from __future__ import annotations

import re

import numpy as np
import pytest
import yaml

from rollergear_ros.recordings.messages import TopicMap
from rollergear_ros.recordings.baginfo import inspect_bag, read_metadata
from rollergear_ros.base.interface import MessageType, Topic
from rollergear_ros.base.output_channels import (OUTPUT_CHANNELS, OutputChannel, float64_channels, map_channels,
                                                 register, sample_channels, trace_channels, window_channels)
from rollergear_ros.replay.run import replay
from rollergear_ros.ros.watch import WatchWindow

from bagtools import float_series, read_mcap_ros2, read_rosbags
from helpers import BAGS, ROOT


def test_every_output_channel_has_its_row_in_the_interface_document():
    text = (ROOT / "docs" / "interface.md").read_text()
    for channel in OUTPUT_CHANNELS.values():
        row = re.compile(rf"^\| `{re.escape(channel.topic)}` \| `{re.escape(channel.message_type)}` \|", re.M)
        assert row.search(text), f"docs/interface.md has no row for {channel.name} ({channel.topic})"


def test_every_per_sample_channel_is_a_topic_map_field_and_a_name_is_registered_once():
    topics = TopicMap()
    not_moved = map_channels() + trace_channels() + window_channels()
    assert {c.name for c in sample_channels()} | {c.name for c in not_moved} == set(OUTPUT_CHANNELS)
    for channel in sample_channels():
        assert getattr(topics, channel.name) == topics.output(channel.name) == channel.absolute_topic()
    for channel in not_moved:  # not per sample: no --topic-<name>, the table's topic
        assert not hasattr(topics, channel.name)
        assert topics.output(channel.name) == channel.absolute_topic()
    with pytest.raises(ValueError, match="already registered"):
        register(OUTPUT_CHANNELS["loss_torque"])
    with pytest.raises(ValueError, match="stamped"):
        register(OutputChannel("bad", "bad", MessageType.FLOAT64, "1", "no value and not a JointState"))
    with pytest.raises(ValueError, match="Float64MultiArray"):
        register(OutputChannel("bad", "bad", MessageType.FLOAT64, "1", "a map as a Float64", per="map"))
    with pytest.raises(ValueError, match="window channel"):
        register(OutputChannel("bad", "bad", MessageType.JOINT_STATE, "", "a window without a value", per="window"))
    with pytest.raises(ValueError, match="DiagnosticStatus"):
        register(OutputChannel("bad", "bad", MessageType.FLOAT64, "1", "a trace as a Float64", per="trace"))
    with pytest.raises(ValueError, match="per is"):
        register(OutputChannel("bad", "bad", MessageType.FLOAT64, "1", "neither", "loss_torque_nm", per="hour"))
    assert "bad" not in OUTPUT_CHANNELS


def test_the_loss_map_and_trace_channels_are_offered_latched_and_the_node_takes_their_qos_from_the_table():
    from rollergear_ros.ros.qos import output_qos
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

    (channel,) = map_channels()
    (traced,) = trace_channels()
    assert channel.topic == Topic.LOSS_MAP and traced.topic == Topic.LOSS_TRACED
    for qos in (output_qos(channel), output_qos(traced)):
        assert qos.depth == 1
        assert qos.durability == DurabilityPolicy.TRANSIENT_LOCAL and qos.reliability == ReliabilityPolicy.RELIABLE
    sample = output_qos(OUTPUT_CHANNELS["loss_torque"])
    assert sample.durability == DurabilityPolicy.VOLATILE and sample.depth == OUTPUT_CHANNELS["loss_torque"].depth
    # node.output_depth: the depth of every channel of samples or windows; the latched ones keep theirs
    for c in OUTPUT_CHANNELS.values():
        assert output_qos(c, 4321).depth == (1 if c.transient_local else 4321), c.name


def test_a_toy_channel_is_written_by_replay_and_read_back_by_both_readers(toy_channel, tmp_path, config):
    out = tmp_path / "o.mcap"
    bag = BAGS / "rig_map_drag.mcap"
    _, estimates = replay(bag, config, out_mcap=out, show_progress=False, collect=True)
    measured = np.concatenate([b.measured_loss_nm for b in estimates])
    t_ns = np.concatenate([b.t_ns for b in estimates])
    has = np.isfinite(measured)
    assert has.any()
    topic = TopicMap().output(toy_channel.name)
    assert topic == "/rollergear/loss/measured"
    for got in (read_mcap_ros2(out), read_rosbags(out)):
        t, v = float_series(got, topic)
        np.testing.assert_array_equal(t, t_ns[has])
        np.testing.assert_array_equal(v, measured[has])
    assert inspect_bag(out).topics[topic] == MessageType.FLOAT64
    meta = yaml.safe_load(read_metadata(out, "rosbag2")["serialized_metadata"])["rosbag2_bagfile_information"]
    offered = {t["topic_metadata"]["name"]: (t["message_count"], t["topic_metadata"]["offered_qos_profiles"])
               for t in meta["topics_with_message_count"]}
    count, qos = offered[topic]
    assert count == int(has.sum()) and yaml.safe_load(qos)[0]["depth"] == toy_channel.depth


def test_watch_shows_a_toy_channel_after_the_four(toy_channel):
    from rollergear_ros.recordings.messages import encode_float64

    window = WatchWindow()
    assert set(window.payloads) == {c.name for c in float64_channels() + window_channels()}
    assert toy_channel.name in window.payloads
    for name, values in (("loss_torque", [0.1, 0.3]), ("loss_power", [10.0, 30.0]), ("efficiency", [0.9, 0.9]),
                         ("measured_loss", [0.2, 0.4])):
        for raw in encode_float64(np.asarray(values)):
            window.add(name, raw)
    assert window.line(1.0, "/x").endswith("measured_loss 0.3 N*m")
    # the measured efficiency's latest window, with its uncertainty, in its own place
    for name, values in (("loss_torque", [0.1]), ("efficiency_measured", [0.97, 0.9812]),
                         ("efficiency_measured_uncertainty", [0.002, 0.0021])):
        for raw in encode_float64(np.asarray(values)):
            window.add(name, raw)
    assert "η measured 98.12 ± 0.21 %" in window.line(1.0, "/x")
