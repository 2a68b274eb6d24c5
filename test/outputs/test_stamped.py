"""The stamped estimate (one JointState per estimate): its encoding read back by two independent
deserializers, and replay's output carrying it beside the Float64 topics."""

from __future__ import annotations

import numpy as np
import pytest

from rollergear_ros.recordings.messages import TopicMap
from rollergear_ros.base.errors import BagError
from rollergear_ros.base.errors import ParameterError
from rollergear_ros.core.params import load_config, validate
from rollergear_ros.replay.run import replay
from rollergear_ros.outputs.stamped import ESTIMATE_FIELDS, EstimateCodec, decode_estimates

from bagtools import float_series, read_mcap_ros2, read_rosbags
from helpers import BAGS

T = TopicMap()


def _stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def test_the_template_encoding_is_what_ros_and_rosbags_read():
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState

    codec = EstimateCodec()
    rng = np.random.default_rng(3)
    t_ns = np.array([0, 999_999_999, 1_700_000_000_123_456_789, (2**31 - 1) * 1_000_000_000 + 999_999_999],
                    dtype=np.int64)
    values = rng.normal(size=(len(t_ns), len(ESTIMATE_FIELDS))) * 100
    values[1, 3] = np.nan  # no residual
    rows = codec.payloads(t_ns, values)
    for k in range(len(t_ns)):
        raw = codec.encode(int(t_ns[k]), values[k])
        assert raw == rows[k].tobytes()
        msg = deserialize_message(raw, JointState)  # rclpy's own CDR
        assert _stamp_ns(msg) == t_ns[k] and tuple(msg.name) == ESTIMATE_FIELDS
        np.testing.assert_array_equal(np.asarray(msg.position), values[k])
        assert len(msg.velocity) == len(msg.effort) == 0
    stamps, got = decode_estimates([r.tobytes() for r in rows])  # the rosbags typestore
    np.testing.assert_array_equal(stamps, t_ns)
    for i, name in enumerate(ESTIMATE_FIELDS):
        np.testing.assert_array_equal(got[name], values[:, i])
    # after 2038 a header stamp cannot hold the time: refused, not wrapped around
    with pytest.raises(BagError, match="int32 seconds"):
        codec.payloads(np.array([2**31 * 1_000_000_000]), values[:1])


def test_replay_output_holds_one_stamped_estimate_per_sample_equal_to_the_float64_topics(tmp_path, config):
    out = tmp_path / "o.mcap"
    summary, _ = replay(BAGS / "rig_map_drag.mcap", config, out_mcap=out, show_progress=False)
    for reader in (read_rosbags, read_mcap_ros2):
        got = reader(out)
        t_log, msgs = got[T.loss_estimate]
        assert len(msgs) == summary.estimated
        stamps = np.array([_stamp_ns(m) for m in msgs])
        np.testing.assert_array_equal(stamps, t_log)  # stamped with the sample's time, logged at it
        position = np.array([list(m.position) for m in msgs])
        for topic, field in ((T.loss_torque, "loss_torque_nm"), (T.loss_power, "loss_power_w"),
                             (T.efficiency, "efficiency")):
            t, v = float_series(got, topic)
            np.testing.assert_array_equal(t, stamps)
            np.testing.assert_array_equal(position[:, ESTIMATE_FIELDS.index(field)], v)
        t_res, res = float_series(got, T.residual_torque)
        column = position[:, ESTIMATE_FIELDS.index("residual_nm")]
        np.testing.assert_array_equal(column[np.isin(stamps, t_res)], res)
        assert np.isnan(column[~np.isin(stamps, t_res)]).all()
        t_in, torque = float_series(got, T.motor_torque)
        np.testing.assert_array_equal(position[:, ESTIMATE_FIELDS.index("torque_nm")], torque[np.isin(t_in, stamps)])


def test_a_node_with_no_output_at_all_is_refused():
    flat = load_config().to_flat() | {"node.publish_float64": False, "node.publish_stamped": False}
    with pytest.raises(ParameterError, match="publish no estimate"):
        validate(flat)
    validate(flat | {"node.publish_stamped": True})  # one of them is enough
