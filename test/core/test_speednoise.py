"""The speed reading's noise, learned from the first samples (``estimator.speed_noise_rad_s: auto``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rollergear_ros.core.estimator import Estimator
from rollergear_ros.core.params import load_config
from rollergear_ros.core.speednoise import CHECKPOINTS, SpeedNoise, reading_noise


@pytest.mark.parametrize("sigma", [1e-4, 0.02, 3.0])
def test_a_readings_noise_is_found_under_a_moving_signal(sigma):
    """White noise on a signal that ramps and curves (second differences of a smooth signal are next
    to nothing): σ within 5 %; a few jumps change nothing."""
    rng = np.random.default_rng(0)
    t = np.arange(20_000) * 1e-3
    signal = 50.0 * np.sin(0.3 * t) + 10.0 * t
    x = signal + rng.normal(0, sigma, len(t))
    assert reading_noise(x) == pytest.approx(sigma, rel=0.05)
    x[::997] += 100 * sigma  # a glitch now and then
    assert reading_noise(x) == pytest.approx(sigma, rel=0.05)
    assert reading_noise(signal) < 5e-6  # the signal's own second differences: 50·0.3²·(1 ms)² at most


def test_a_quantised_reading_is_not_taken_for_a_noiseless_one():
    """An encoder's speed in steps of 0.01 rad/s, mostly repeating: the median of the second differences
    is 0, their spread is not."""
    rng = np.random.default_rng(1)
    x = np.round((5.0 + rng.normal(0, 0.006, 5000)) / 0.01) * 0.01
    assert reading_noise(x) > 0.002


def test_sigma_is_learned_at_its_checkpoints_and_kept():
    noise = SpeedNoise("auto")
    assert noise.learning and not noise.known and noise.min_measured_rad_s == math.inf
    rng = np.random.default_rng(2)
    seen = []
    for k in range(1, 2001):
        changed = noise.add([10.0 + rng.normal(0, 0.05)], k)
        seen.append((k, changed))
        if k < CHECKPOINTS[-1]:
            assert noise.until_checkpoint() > 0
    assert [k for k, changed in seen if changed] == list(CHECKPOINTS)
    assert noise.value == pytest.approx(0.05, rel=0.1) and not noise.learning
    assert [t for t, _ in noise.learned] == list(CHECKPOINTS)
    given = SpeedNoise(0.01)
    assert not given.learning and given.value == 0.01 and given.min_measured_rad_s == pytest.approx(0.03)


def test_an_estimator_that_follows_the_checkpoints_uses_them_by_sample_time():
    """A time slice's estimator applies the checkpoints its recording's first samples gave, each from the
    time of the sample that completed it on: the same σ at the same samples as the whole recording."""
    config = load_config()
    rng = np.random.default_rng(3)
    n = 3000
    t = (np.arange(n) * 1_000_000).astype(np.int64)
    torque, speed = 20.0 + rng.normal(0, 0.01, n), 0.05 + rng.normal(0, 0.02, n)
    whole = Estimator(config)
    a = whole.process_batch(t, torque, speed)
    follower = Estimator(config)
    follower.follow_speed_noise(whole)
    b = follower.process_batch(t, torque, speed)
    np.testing.assert_array_equal(a.loss_torque_nm, b.loss_torque_nm)
    np.testing.assert_array_equal(a.measured_loss_nm, b.measured_loss_nm)
    assert follower.speed_noise.value == whole.speed_noise.value
