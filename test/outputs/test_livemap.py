"""The live loss map's pure parts: layout round trip, the adapted parameters, when a map is due."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rollergear_ros.core.estimator import Estimator
from rollergear_ros.outputs.livemap import (adapted_config, coefficients_moved, from_multiarray, live_map, map_grid,
                                            to_multiarray)
from rollergear_ros.outputs.lossmap import build_map
from rollergear_ros.core.params import load_config, validate
from rollergear_ros.calibration.simulate import DeclaredEffect, SimulationOptions, simulate


def _drag_config(c: float):
    return validate(load_config().to_flat() | {"effects.drag_speed.enabled": True, "effects.drag_speed.c": c,
                                               "effects.drag_speed.p": 1.4})


def test_the_message_layout_round_trips_and_a_wrong_one_is_refused():
    config = _drag_config(3e-4)
    adapted, loss_map = live_map(config, {"drag_speed": 3e-4}, None)
    arr = to_multiarray(loss_map)
    ns, nt = arr.sizes
    assert arr.labels == ("speed_rpm", "torque_nm") and arr.strides == (ns * nt, nt) and arr.data_offset == ns + nt
    speeds, torques, loss = from_multiarray(arr.labels, arr.sizes, arr.data_offset, arr.data)
    np.testing.assert_array_equal(speeds, loss_map.speeds_rpm)
    np.testing.assert_array_equal(torques, loss_map.torques_nm)
    np.testing.assert_array_equal(loss, loss_map.loss_nm)
    # data[offset + i*Nt + j] is the loss at speed i, torque j
    assert arr.data[arr.data_offset + 3 * nt + 5] == loss_map.loss_nm[3, 5]
    with pytest.raises(ValueError, match="not a loss map"):
        from_multiarray(("x", "y"), arr.sizes, arr.data_offset, arr.data)
    with pytest.raises(ValueError, match="needs"):
        from_multiarray(arr.labels, arr.sizes, arr.data_offset, arr.data[:-1])


def test_the_map_of_adapted_coefficients_is_the_map_of_a_parameter_file_with_them():
    config = _drag_config(1.5e-4)
    adapted, loss_map = live_map(config, {"drag_speed": 2.7e-4}, None)
    assert adapted.effects.params("drag_speed")["c"] == 2.7e-4
    speeds, torques = map_grid(config)
    expect = build_map(_drag_config(2.7e-4), speeds, torques)
    np.testing.assert_array_equal(loss_map.loss_nm, expect.loss_nm)
    with pytest.raises(Exception, match="drag_speed"):
        adapted_config(config, {"drag_speed": math.inf})  # validated in the one place


def test_a_map_is_due_when_a_coefficient_left_its_interval():
    assert coefficients_moved({}, {"drag_speed": 1.0}, {}) == ["drag_speed"]  # never published
    assert coefficients_moved({"drag_speed": 1.0}, {"drag_speed": 1.1}, {"drag_speed": (0.9, 1.3)}) == []
    assert coefficients_moved({"drag_speed": 1.0}, {"drag_speed": 1.5}, {"drag_speed": (1.2, 1.8)}) == ["drag_speed"]
    assert coefficients_moved({"drag_speed": 1.0}, {"drag_speed": 5.0}, {}) == []  # no interval yet


def test_the_adapted_coefficients_interval_holds_the_recordings_drag():
    """Estimator.coefficient_intervals: after a recording with a speed drag of 3e-4 (white sensor
    noise, the model otherwise exact), started from 1.5e-4, the 95 % interval holds 3e-4 and is
    narrower than the distance it came."""
    config = _drag_config(1.5e-4)
    opts = SimulationOptions(profile="rig_map", rate_hz=200.0, seed=4,
                             effects=[DeclaredEffect.parse("drag_speed:c=3e-4,p=1.4")])
    rig = simulate(config, opts)
    est = Estimator(config)
    assert est.coefficient_intervals()["drag_speed"] == (-math.inf, math.inf)  # no residual yet
    est.process_batch(rig.t_ns, rig.torque_meas_nm, rig.speed_rad_s, rig.out_torque_meas_nm, rig.out_speed_meas_rad_s)
    lo, hi = est.coefficient_intervals()["drag_speed"]
    assert lo < 3e-4 < hi and hi - lo < 1.5e-4
