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


def test_an_executor_behind_its_input_queue_is_an_overload_warning():
    """Half of what a best-effort queue holds (1000 messages at 1 kHz: 1 s) behind: WARN, before
    the queue overflows and messages are lost uncounted; a reliable keep-all input is allowed 0.5 s."""
    est = Estimator(load_config(None))
    now = 100 * 10**9
    healthy = _monitor(now, {TORQUE: now - MS, SPEED: now - MS})

    def report(lag_s: float, depth: int | None, rate: float = 1000.0):
        return diagnose(now, healthy, {TORQUE: rate, SPEED: rate}, est, rate, 0.9, dict(est.counts), 0,
                        busy_fraction=0.4, executor_lag_s=lag_s, queue_depth=depth)

    assert report(0.45, 1000).level == OK
    rep = report(0.55, 1000)
    assert rep.level == WARN and "overloaded: the node runs 0.55 s behind" in rep.message
    assert "input queues overflow" in rep.message and dict(rep.values)["executor lag [s]"] == "0.55"
    assert report(0.15, 1000, rate=5000.0).level == WARN  # 1000 messages at 5 kHz hold 0.2 s
    assert report(0.45, None).level == OK and "publishers are slowed" in report(0.55, None).message


def test_received_and_not_estimated_per_input():
    est = Estimator(load_config(None))
    now = 100 * 10**9
    mon = _monitor(now, {TORQUE: now - MS, SPEED: now - MS})
    mon.counts[TORQUE], mon.counts[SPEED] = 120, 117
    est.estimated = 110
    values = dict(diagnose(now, mon, {TORQUE: 1000.0, SPEED: 1000.0}, est, 1000.0, 0.9, dict(est.counts), 0).values)
    assert (values["motor_torque messages"], values["motor_torque not estimated"]) == ("120", "10")
    assert (values["motor_speed messages"], values["motor_speed not estimated"]) == ("117", "7")
