"""The live loss map's pure parts: layout round trip, the adapted parameters, when a map is due."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rollergear_ros.core.estimator import Estimator
from rollergear_ros.outputs.livemap import (adapted_config, coefficients_moved, from_multiarray, live_map, map_grid,
                                            oil_moved, to_multiarray)
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
    ns, nt, nk = arr.sizes
    assert arr.labels == ("speed_rpm", "torque_nm", "oil_temperature_c") and nk == 1
    assert arr.strides == (ns * nt, nt, 1) and arr.data_offset == ns + nt + 1
    back = from_multiarray(arr.labels, arr.sizes, arr.data_offset, arr.data)
    np.testing.assert_array_equal(back.speeds_rpm, loss_map.speeds_rpm)
    np.testing.assert_array_equal(back.torques_nm, loss_map.torques_nm)
    np.testing.assert_array_equal(back.loss_nm, loss_map.loss_nm)
    assert math.isnan(back.oil_temperature_c)  # a speed drag follows no oil
    # data[offset + i*Nt + j] is the loss at speed i, torque j
    assert arr.data[arr.data_offset + 3 * nt + 5] == loss_map.loss_nm[3, 5]
    with pytest.raises(ValueError, match="not a loss map"):
        from_multiarray(("speed_rpm", "torque_nm"), arr.sizes[:2], arr.data_offset - 1, arr.data)  # the old layout
    with pytest.raises(ValueError, match="needs"):
        from_multiarray(arr.labels, arr.sizes, arr.data_offset, arr.data[:-1])


def _warming_config(step_c: float = 5.0):
    return validate(load_config().to_flat() | {
        "effects.viscosity_temperature.enabled": True, "effects.viscosity_temperature.B_k": 1100.0,
        "node.map_oil_step_c": step_c})


def test_a_map_of_a_model_that_follows_the_oil_carries_its_temperature_and_is_due_when_the_oil_moved():
    config = _warming_config()
    _, at_ref = live_map(config, {}, None)  # no oil measured yet: the reference temperature
    _, cold = live_map(config, {}, 20.0)
    assert at_ref.temperature_c == 40.0 and cold.temperature_c == 20.0
    back = from_multiarray(*(lambda a: (a.labels, a.sizes, a.data_offset, a.data))(to_multiarray(cold)))
    assert back.oil_temperature_c == 20.0
    speeds, torques = map_grid(config)
    np.testing.assert_array_equal(back.loss_nm, build_map(config, speeds, torques, 20.0).loss_nm)
    assert (cold.loss_nm >= at_ref.loss_nm).all() and (cold.loss_nm > at_ref.loss_nm).any()  # cold oil costs
    assert not oil_moved(config, 40.0, None)  # no oil measured
    assert not oil_moved(config, 40.0, 44.9) and oil_moved(config, 40.0, 45.0) and oil_moved(config, 40.0, 30.0)
    assert not oil_moved(_warming_config(0.0), 40.0, 90.0)  # 0: only the coefficients
    assert not oil_moved(_drag_config(3e-4), None, 90.0)  # a model that follows no oil


def test_the_node_s_map_publisher_republishes_when_the_oil_moved_its_step():
    """:class:`ros.livemaps.LiveMapPublisher` (no DDS: its publisher is a list of what it was given)."""
    from rollergear_ros.ros.livemaps import LiveMapPublisher

    class Collected(list):
        publish = list.append

    class Quiet:
        def warn(self, text):
            raise AssertionError(text)

    config = _warming_config(step_c=5.0)
    estimator = Estimator(config)
    sent = Collected()
    publisher = LiveMapPublisher((sent,), "/test", Quiet())
    temperatures = []
    for oil in (None, 41.0, 44.0, 46.0, 49.0, 51.0, 30.0):
        publisher.oil_temperature_c = oil
        publisher.update(config, estimator)
        last = sent[-1]
        temperatures.append(from_multiarray([d.label for d in last.layout.dim], [d.size for d in last.layout.dim],
                                            last.layout.data_offset, last.data).oil_temperature_c)
    assert publisher.published == len(sent) == 4  # at start (40: the reference), 46, 51 (46 + 5), 30
    assert temperatures == [40.0, 40.0, 40.0, 46.0, 46.0, 51.0, 30.0]


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
