"""Operating points, dwells and folds of the blocks, on samples laid out by hand."""

from __future__ import annotations

import numpy as np

from rollergear_ros.calibration.grouping import DWELL_MAX_S, dwells, places
from rollergear_ros.calibration.samples import SampleData


def _samples(speed, torque, bag, t_s, out_torque=None) -> SampleData:
    n = len(speed)
    z = np.zeros(n)
    t_ns = np.asarray(np.round(np.asarray(t_s) * 1e9), dtype=np.int64)
    return SampleData(t_ns, np.asarray(bag), np.asarray(torque, float), np.asarray(speed, float), np.full(n, np.nan),
                      z, z, z,
                      out_torque=None if out_torque is None else np.asarray(out_torque, float))


def test_places_are_the_same_operating_point_in_any_recording_and_none_at_standstill():
    speed = [10.0, 10.5, -10.0, 20.0, 10.2, 0.0]
    d = _samples(speed, [1.0] * 6, [0, 0, 0, 0, 1, 1], np.arange(6) * 0.25, out_torque=[5.0, 5.0, 5.0, 5.0, 5.04, 5.0])
    label = places(d, np.arange(6), np.ones(6, dtype=np.int64))
    assert label[0] == label[1] == label[4]  # in one 10 % bin, across recordings
    assert len({label[0], label[2], label[3]}) == 3  # the other direction, another speed
    assert label[5] == -1
    heavier = _samples(speed, [1.0] * 6, [0] * 6, np.arange(6) * 0.25, out_torque=[5.0, 9.0, 5, 5, 5, 5])
    split = places(heavier, np.arange(6), np.ones(6, dtype=np.int64))
    assert split[0] != split[1]  # another load


def test_a_dwell_is_one_operating_point_within_one_recording_and_at_most_its_length():
    n = int(2 * DWELL_MAX_S / 0.25) + 4
    speed = np.r_[np.full(n, 10.0), np.full(4, 30.0)]
    bag = np.r_[np.zeros(n, dtype=np.int64), np.ones(4, dtype=np.int64)]
    t = np.r_[np.arange(n) * 0.25, np.arange(4) * 0.25]
    d = _samples(speed, np.ones(len(speed)), bag, t)
    dwell, fold = dwells(d, speed, np.ones(len(speed)), np.arange(len(speed)), 0.25, 5, t)
    first = dwell[:n]
    assert first[0] == 0 and len(np.unique(first)) == 3  # 10 s at one point: three dwells of at most 5 s
    assert np.all(np.bincount(first) <= DWELL_MAX_S / 0.25)
    assert set(dwell[n:]) == {first.max() + 1}  # the other recording: a dwell of its own
    assert len(fold) == len(dwell) and all(len(set(fold[dwell == k])) == 1 for k in np.unique(dwell))
