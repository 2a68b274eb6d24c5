"""Online adaptation (rollergear_ros.core.adaptation): RLS, the change detector, residual statistics."""

from __future__ import annotations


import numpy as np
import pytest

from rollergear_ros.core.adaptation import ChangeDetector, RecursiveLeastSquares, ResidualStats

MS = 1_000_000

def test_change_detector_vectorised_equals_scalar():
    rng = np.random.default_rng(3)
    x = rng.normal(0, 0.01, 20000)
    x[9000:] += 0.05
    t = np.arange(len(x)) * MS
    a, b = ChangeDetector(200, 0.02), ChangeDetector(200, 0.02)
    for xi, ti in zip(x.tolist(), t.tolist()):
        a.add(xi, ti)
    b.add_many(x[:777], t[:777])
    b.add_many(x[777:], t[777:])
    assert a.alarms == b.alarms == 1 and a.alarm_times_ns == b.alarm_times_ns
    assert 9000 * MS <= a.alarm_times_ns[0] <= 10000 * MS


def test_residual_stats_vectorised_equals_scalar():
    x = np.random.default_rng(4).normal(0.1, 0.02, 5000)
    a, b = ResidualStats(), ResidualStats()
    for xi in x.tolist():
        a.add(xi)
    b.add_many(x[:300])
    b.add_many(x[300:])
    assert a.count == b.count and a.mean == pytest.approx(b.mean, rel=1e-9) and a.rms == pytest.approx(b.rms, rel=1e-9)


def test_rls_tracks_coefficients_with_bounded_covariance():
    rng = np.random.default_rng(5)
    rls = RecursiveLeastSquares([0.0, 0.0], 0.999, p0=1.0, max_trace=10.0)
    for _ in range(5000):
        phi = [1.0, rng.uniform(0, 2)]
        rls.update(phi, 0.3 + 0.7 * phi[1] + rng.normal(0, 0.01))
        assert sum(rls.P[j][j] for j in range(2)) <= 10.0 + 1e-9
    assert rls.theta[0] == pytest.approx(0.3, abs=0.01) and rls.theta[1] == pytest.approx(0.7, abs=0.01)


def test_rls_with_one_coefficient_is_the_general_update_bit_for_bit():
    """The one-parameter shortcut does the general update's operations in the same order: the same
    errors, coefficients and covariance to the last bit, with and without the trace bound acting."""
    rng = np.random.default_rng(11)
    for p0, max_trace in ((1.0, 1e6), (100.0, 0.5)):
        one = RecursiveLeastSquares([0.2], 0.995, p0=p0, max_trace=max_trace)
        general = RecursiveLeastSquares([0.2, 0.0], 0.995, p0=p0, max_trace=max_trace)
        for _ in range(3000):  # a second regressor that is always 0 leaves the first one's update as it is
            f, y = float(rng.normal() * rng.choice([1e-3, 1.0, 1e3])), float(rng.normal())
            general.P[0][1] = general.P[1][0] = 0.0
            general.P[1][1] = 0.0
            assert one.update([f], y) == general.update([f, 0.0], y)
            assert one.theta[0] == general.theta[0] and one.P[0][0] == general.P[0][0]
