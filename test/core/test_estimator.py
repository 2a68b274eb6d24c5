"""The estimator (rollergear_ros.core.estimator): the sensor errors it removes from the model's input."""

from __future__ import annotations

import numpy as np
import pytest

from rollergear_ros.core.estimator import Estimator
from rollergear_ros.core.params import load_config


def test_sensor_errors_are_removed_from_the_model_input():
    cfg = load_config().with_values({"effects.torque_offset.enabled": True, "effects.torque_offset.offset_nm": 0.5,
                                     "effects.torque_gain.enabled": True, "effects.torque_gain.gain": 0.01,
                                     "estimator.adapt": False})
    est = Estimator(cfg)
    assert est.corrected_torque(10.5 * 1.0 + 0.1) == pytest.approx((10.6 - 0.5) / 1.01)
    b = est.process_batch(np.array([0]), np.array([20.0]), np.array([100.0]))
    plain = Estimator(load_config()).process_batch(np.array([0]), np.array([(20.0 - 0.5) / 1.01]), np.array([100.0]))
    assert b.loss_torque_nm[0] == pytest.approx(plain.loss_torque_nm[0], rel=1e-12)
