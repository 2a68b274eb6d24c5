"""The speed reading's noise, learned from the first samples (``estimator.speed_noise_rad_s: auto``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rollergear_ros.core.estimator import Estimator
from rollergear_ros.core.params import load_config
from rollergear_ros.core.pairing import SyncedSample
from rollergear_ros.core.speednoise import CHECKPOINTS, DirectionRun, SpeedNoise, reading_noise


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


def _stick_slip(n: int, direction: int, rng: np.random.Generator) -> np.ndarray:
    """A controller's speed readings of a drive that sticks and slips at about 1 unit per sample: it sticks
    for 3 samples on average (readings of 0), then slips for 4 at about 2 units, each reading the slip's
    average over its sample in whole units -- as a worm drive set to 1 rpm reads 0…10 rpm, 0 at 43 % of
    its samples."""
    out: list[float] = []
    sticking = True
    while len(out) < n:
        if sticking:
            out += [0.0] * int(rng.geometric(1 / 3))
        else:
            k = int(rng.geometric(1 / 4))
            out += np.round(np.abs(rng.normal(2.0, 0.5) + rng.normal(0.0, 0.7, k))).tolist()
        sticking = not sticking
    return direction * np.array(out[:n])


def test_a_run_of_readings_tells_the_direction_of_a_drive_slower_than_one_reading_can():
    """Stick-slip readings whose learned σ puts most of them within 3σ of standstill: the run tells the
    direction at most readings beyond σ, never the wrong one, and none while the drive sticks (0)."""
    rng = np.random.default_rng(4)
    for direction in (1, -1):
        x = _stick_slip(4000, direction, rng)
        sigma = reading_noise(x)
        assert np.mean(np.abs(x) >= 3 * sigma) < 0.25  # one reading alone mostly cannot tell
        run = DirectionRun().many(x, sigma)
        moving = np.abs(x) > sigma
        assert np.mean(run[moving] == direction) > 0.6 and not np.any(run == -direction)
        assert not np.any(run[x == 0])


def test_a_run_tells_no_direction_at_rest_more_often_than_two_readings_beyond_3_sigma():
    """White noise at rest: the run names a direction about as seldom as two readings in a row beyond 3σ
    in one direction (once in ~300 000 samples); never for readings that are exactly 0."""
    rng = np.random.default_rng(5)
    x = rng.normal(0.0, 1.0, 4_000_000)
    run_rate = np.mean(DirectionRun().many(x, 1.0) != 0)
    pair_rate = np.mean((np.abs(x[1:]) >= 3) & (np.abs(x[:-1]) >= 3) & (np.sign(x[1:]) == np.sign(x[:-1])))
    assert run_rate < 3 * max(pair_rate, 1e-6)
    assert not np.any(DirectionRun().many(np.zeros(1000), 1.0))


def test_a_reading_near_zero_inside_a_fast_run_is_a_glitch_not_a_direction():
    """A run of readings mostly beyond 3σ is told by them one by one: a reading of 0 inside it (a dropped
    encoder count) gets no direction from the run."""
    x = np.full(200, 50.0)
    x[100] = 0.0
    assert DirectionRun().many(x, 1.0)[100] == 0


def test_a_runs_step_and_its_arrays_agree_on_every_sample():
    """The node's one reading at a time, replay's arrays and arrays in pieces of any length give the same
    directions; a σ learned later does not change what the readings before it were flagged with."""
    rng = np.random.default_rng(6)
    x = np.concatenate([rng.normal(0, 1, 500), _stick_slip(1500, 1, rng), rng.normal(40, 1, 300),
                        _stick_slip(1500, -1, rng)])
    sigma = np.where(np.arange(len(x)) < 1700, 1.0, 1.3)  # σ changes at a checkpoint
    stepped = DirectionRun()
    one = np.array([stepped.step(v, s) for v, s in zip(x.tolist(), sigma.tolist())])
    whole = DirectionRun()
    arrays = np.concatenate([whole.many(x[:1700], 1.0), whole.many(x[1700:], 1.3)])
    pieces = DirectionRun()
    cut = [0, 7, 23, 1000, 1700, 1701, 2900, len(x)]
    parts = np.concatenate([pieces.many(x[a:b], float(sigma[a])) for a, b in zip(cut[:-1], cut[1:])])
    np.testing.assert_array_equal(one, arrays)
    np.testing.assert_array_equal(one, parts)
    assert np.count_nonzero(one == 1) > 200 and np.count_nonzero(one == -1) > 200


def test_the_estimator_measures_a_loss_where_a_run_tells_the_direction():
    """A spin test of a stick-slipping drive, forward then reversed through a stick (its friction 2 mN·m,
    σ learned from its readings): the measured loss is the drive torque at every sample whose direction
    the run tells, of the right sign across the reversal; the loss's sign at the slow ones is the run's;
    the node's path equals replay's to the bit."""
    rng = np.random.default_rng(7)
    n = 3000
    speed = np.concatenate([_stick_slip(n // 2, 1, rng), _stick_slip(n // 2, -1, rng)]) * 0.1
    torque = np.sign(np.repeat([1.0, -1.0], n // 2)) * (0.002 + rng.normal(0, 1e-4, n))
    t = (np.arange(n) * 100_000_000).astype(np.int64)
    config = load_config().with_values({"estimator.adapt": False, "estimator.paper_model": False})
    columns = (t, torque, speed, np.zeros(n), np.full(n, np.nan), np.full(n, np.nan))
    batch = Estimator(config).process_batch(*columns)
    node = Estimator(config)
    live = [node.process(SyncedSample(*row)) for row in zip(*(np.asarray(c).tolist() for c in columns))]
    for field in ("measured_loss_nm", "residual_nm", "loss_torque_nm", "sign"):
        np.testing.assert_array_equal(np.array([getattr(e, field) for e in live]), getattr(batch, field), err_msg=field)
    measured = np.isfinite(batch.measured_loss_nm)
    still = speed == 0
    least = node.min_measured_speed_rad_s  # two readings in a row beyond 3σ: what one reading at a time tells
    pairs = (np.abs(speed[1:]) >= least) & (np.abs(speed[:-1]) >= least) & (np.sign(speed[1:]) == np.sign(speed[:-1]))
    after = slice(CHECKPOINTS[-1], None)
    assert np.mean(measured[after][~still[after]]) > 0.5
    assert np.sum(measured[after]) > 1.4 * np.sum(pairs[CHECKPOINTS[-1] - 1:])
    slow = measured & (np.abs(speed) < least)
    assert np.sum(slow) > 150 and not np.any(measured & still)  # none of these without the run
    np.testing.assert_allclose(batch.measured_loss_nm[measured], np.abs(torque[measured]), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(batch.sign[slow], np.sign(torque[slow]))
