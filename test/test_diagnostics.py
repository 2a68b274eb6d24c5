"""The node's /diagnostics levels and messages (rollergear_ros.diagnostics), without ROS."""

from __future__ import annotations

import math

from rollergear_ros.diagnostics import ERROR, OK, WARN, InputMonitor, diagnose
from rollergear_ros.estimator import Estimator
from rollergear_ros.pairing import SPEED, TORQUE
from rollergear_ros.params import load_config

MS = 1_000_000


def _monitor(now, last):
    m = InputMonitor(now - 10 * 10**9)
    for ch, t in last.items():
        m.record(ch, t)
    return m


def test_diagnostics_levels():
    est = Estimator(load_config())
    now = 100 * 10**9
    healthy = _monitor(now, {TORQUE: now - MS, SPEED: now - MS})
    rates = {TORQUE: 1000.0, SPEED: 1000.0}
    rep = diagnose(now, healthy, rates, est, 1000.0, 0.9, dict(est.counts), 0)
    assert rep.level == OK and rep.message == "estimating"
    stale = _monitor(now, {TORQUE: now - MS, SPEED: now - 3 * 10**9})
    rep = diagnose(now, stale, rates, est, 1000.0, 0.9, dict(est.counts), 0)
    assert rep.level == ERROR and "stale input: motor_speed" in rep.message
    rep = diagnose(now, healthy, {TORQUE: 500.0, SPEED: 500.0}, est, 1000.0, 0.9, dict(est.counts), 0)
    assert rep.level == WARN and "expected 1000 Hz" in rep.message
    missing = _monitor(now, {TORQUE: now - MS})
    rep = diagnose(now, missing, rates, est, 1000.0, 0.9, dict(est.counts), 0)
    assert rep.level == ERROR and "no input on motor_speed" in rep.message
    est.counts["non_finite"] += 3
    rep = diagnose(now, healthy, rates, est, 1000.0, 0.9, {**est.counts, "non_finite": 0}, 0)
    assert rep.level == WARN and "3 samples with non finite" in rep.message
    values = dict(rep.values)
    assert values["skipped non finite"] == "3 (+3)" and math.isfinite(float(values["expected rate [Hz]"]))
