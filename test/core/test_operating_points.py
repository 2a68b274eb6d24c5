"""The calibrated model at operating points (what ``model`` and ``map`` evaluate)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from rollergear_ros.base.errors import UsageError
from rollergear_ros.core.model import LossModel, evaluate_reference
from rollergear_ros.core.operating_points import evaluate_points
from rollergear_ros.core.params import load_config

from helpers import CALIBRATED

@pytest.fixture(scope="module")
def calibrated():
    return load_config(None, CALIBRATED)


def grid_points():
    tt, ww = np.meshgrid(np.array([-80.0, -10.0, 1.0, 25.0, 90.0]), np.array([-300.0, 5.0, 120.0, 400.0]),
                         indexing="ij")
    return tt.ravel(), ww.ravel()


def test_shares_add_up_to_the_loss_and_each_follows_its_formula(calibrated):
    torque, speed = grid_points()
    theta = 75.0
    res = evaluate_points(calibrated, torque, speed, theta)
    assert set(res.effects_nm) == {"drag_speed", "load_dependent", "viscosity_temperature"}
    total = res.model_nm + sum(res.effects_nm.values())
    np.testing.assert_allclose(total, res.loss_magnitude_nm, rtol=1e-12)
    np.testing.assert_allclose(np.abs(res.loss_torque_nm), res.loss_magnitude_nm, rtol=0)
    # the paper's model alone, at eta0
    np.testing.assert_allclose(res.model_nm, LossModel(calibrated.gearbox).loss_magnitude(torque, speed), rtol=1e-12)
    # the additive effects, written out by hand
    np.testing.assert_allclose(res.effects_nm["drag_speed"], 2e-4 * np.abs(speed) ** 1.5, rtol=1e-12)
    # the load friction at the output-side load: the drive torque less the whole loss
    load = torque - res.loss_torque_nm
    np.testing.assert_allclose(res.effects_nm["load_dependent"], 1e-3 * np.abs(load) ** 1.2, rtol=1e-12)
    # the viscosity effect against the literal chain of eq. 1-30 at the Vogel viscosity eta(theta)
    eta = calibrated.gearbox.eta0_pa_s * math.exp(900.0 / (theta + 95.0) - 900.0 / (40.0 + 95.0))
    for i in range(len(torque)):
        hot = evaluate_reference(calibrated.gearbox, torque[i], speed[i], eta)["T_loss"]
        cold = evaluate_reference(calibrated.gearbox, torque[i], speed[i])["T_loss"]
        assert res.effects_nm["viscosity_temperature"][i] == pytest.approx(abs(hot) - abs(cold), rel=1e-6, abs=1e-12)


def test_torque_sensor_errors_are_not_applied_to_operating_points(calibrated):
    """An operating point's torque is the true one: the rig's sensor errors are not the gearbox's."""
    torque, speed = grid_points()
    with_sensor = evaluate_points(calibrated, torque, speed, 60.0)
    switches = dict(calibrated.effects.switches, torque_offset=False, torque_gain=False)
    without = evaluate_points(replace(calibrated, effects=replace(calibrated.effects, switches=switches)),
                              torque, speed, 60.0)
    np.testing.assert_array_equal(with_sensor.loss_torque_nm, without.loss_torque_nm)
    np.testing.assert_array_equal(with_sensor.efficiency, without.efficiency)


def test_a_temperature_effect_without_a_temperature_is_refused(calibrated):
    with pytest.raises(UsageError, match="oil temperature"):
        evaluate_points(calibrated, [10.0], [100.0])
    # without the viscosity effect no temperature is needed
    plain = load_config(None, {"effects.drag_speed.enabled": True, "effects.drag_speed.c": 1e-4})
    assert evaluate_points(plain, [10.0], [100.0]).loss_magnitude_nm[0] > 0


def test_implausible_points_are_flagged_not_dropped():
    config = load_config(None)
    res = evaluate_points(config, [10.0, 1e6, 20.0], [100.0, 100.0, 100.0])
    assert np.isfinite(res.loss_torque_nm[[0, 2]]).all() and np.isnan(res.loss_torque_nm[1])
    assert res.skipped == {"implausible": 1}


@pytest.mark.parametrize("speed_noise", ["auto", 0.5])
def test_a_point_has_the_same_loss_alone_and_in_any_list(calibrated, speed_noise):
    """Nothing is learned from a list of points: a 20 x 20 grid (slow points among fast ones) gives each
    point's loss exactly as that point alone does; with a speed noise in the file, the file's smooth
    sign (tanh(ω/σ) near standstill) as replay applies it."""
    config = calibrated.with_values({"estimator.speed_noise_rad_s": speed_noise})
    rng = np.random.default_rng(7)
    tt, ww = np.meshgrid(np.linspace(-90.0, 90.0, 20), np.concatenate([rng.uniform(-2.0, 2.0, 10),
                                                                          rng.uniform(-300.0, 300.0, 10)]),
                         indexing="ij")
    torque, speed = tt.ravel(), ww.ravel()
    grid = evaluate_points(config, torque, speed, 60.0)
    alone = np.array([evaluate_points(config, [t], [w], 60.0).loss_torque_nm[0] for t, w in zip(torque, speed)])
    np.testing.assert_array_equal(grid.loss_torque_nm, alone)
    slow = np.abs(speed) < 1.0
    sign = np.sign(speed) if speed_noise == "auto" else np.tanh(speed / speed_noise)
    # the sign of the loss: the plain sign without a noise to smooth it, the file's tanh with one
    np.testing.assert_allclose((grid.loss_torque_nm / grid.loss_magnitude_nm)[slow], sign[slow], rtol=1e-12)
