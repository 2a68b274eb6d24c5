"""Replay applies a live recording's run-time parameter changes where the node applied them."""

from __future__ import annotations

import numpy as np

from rollergear_ros.base.interface import MessageType, Topic
from rollergear_ros.calibration.samples import load_samples
from rollergear_ros.recordings.bagwriter import BagWriter
from rollergear_ros.recordings.baginfo import inspect_bag, iter_raw_batches
from rollergear_ros.replay.run import replay
from rollergear_ros.replay.switches import recorded_switches, split_at
from rollergear_ros.ros.parameters import parameter_event

from helpers import BAGS

DRAG = {"effects.drag_constant.enabled": True, "effects.drag_constant.c_nm": 0.05}


def with_change(src, dst, boundary_ns: int, changes: dict, node: str = "/rollergear/loss_estimator") -> None:
    """``src`` with a ``/parameter_events`` message as the node records one: stamped with the sample
    boundary, logged when it came (here: just after the boundary)."""
    info = inspect_bag(src)
    with BagWriter(dst) as out:
        for batch in iter_raw_batches(info, None):
            for topic, t, data in zip(batch.topics, batch.log_time_ns, batch.data):
                out.write_raw(topic, info.topics[topic], t, data)
        out.write_message(Topic.PARAMETER_EVENTS, MessageType.PARAMETER_EVENT, boundary_ns + 1,
                          parameter_event(node, boundary_ns, changes))


def _series(batches, name):
    return np.concatenate([getattr(b, name) for b in batches])


def test_a_recorded_change_applies_from_its_sample_boundary_on(tmp_path, config):
    """Without adaptation an estimate depends on its sample alone: before the boundary replay's
    estimates are those of the parameters it started with, after it those of the changed ones,
    sample for sample and bit for bit, wherever the batches split."""
    config = config.with_values({"estimator.adapt": False})
    bag = BAGS / "rig_map.mcap"
    _, plain = replay(bag, config, collect=True, show_progress=False)
    t = _series(plain, "t_ns")
    boundary = int(t[len(t) // 2])
    rec = tmp_path / "changed.mcap"
    with_change(bag, rec, boundary, DRAG)
    assert [(s.at_ns, s.changes) for s in recorded_switches(inspect_bag(rec))] == [(boundary, DRAG)]

    summary, switched = replay(rec, config, collect=True, show_progress=False, batch_size=977)  # split anywhere
    assert summary.parameter_changes == [f"effects.drag_constant.enabled=True, effects.drag_constant.c_nm=0.05 "
                                         f"after {boundary} ns"]
    assert "parameter changes the node made, applied where it made them" in summary.text()
    _, dragged = replay(bag, config.with_values(DRAG), collect=True, show_progress=False)
    assert np.array_equal(_series(switched, "t_ns"), t)
    before = t <= boundary
    for name in ("loss_torque_nm", "efficiency", "residual_nm"):
        got = _series(switched, name)
        np.testing.assert_array_equal(got[before], _series(plain, name)[before])
        np.testing.assert_array_equal(got[~before], _series(dragged, name)[~before])
    assert not np.array_equal(_series(plain, "loss_torque_nm")[~before], _series(dragged, "loss_torque_nm")[~before])
    # asked not to, replay keeps the parameters it was given throughout (calibration's bare model)
    _, kept = replay(rec, config, collect=True, show_progress=False, parameter_changes=False)
    np.testing.assert_array_equal(_series(kept, "loss_torque_nm"), _series(plain, "loss_torque_nm"))
    np.testing.assert_array_equal(load_samples([rec], config).model_loss, load_samples([bag], config).model_loss)


def test_a_change_before_any_input_and_another_nodes_events(tmp_path, config):
    bag = BAGS / "rig_map.mcap"
    rec, other = tmp_path / "first.mcap", tmp_path / "other.mcap"
    with_change(bag, rec, 0, DRAG)
    with_change(bag, other, 0, DRAG, node="/some/other_node")
    _, switched = replay(rec, config, collect=True, show_progress=False)
    _, dragged = replay(bag, config.with_values(DRAG), collect=True, show_progress=False)
    np.testing.assert_array_equal(_series(switched, "loss_torque_nm"), _series(dragged, "loss_torque_nm"))
    assert recorded_switches(inspect_bag(other)) == []  # a parameter event of another node is not ours


def test_split_at_takes_the_inputs_up_to_the_first_one_logged_after_the_boundary():
    assert split_at(np.array([1, 2, 3, 5, 8]), 3) == 3
    assert split_at(np.array([1, 2, 3]), 9) == 3 and split_at(np.array([4, 5]), 0) == 0
