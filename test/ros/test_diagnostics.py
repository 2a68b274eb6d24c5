"""The node's /diagnostics levels and messages (rollergear_ros.ros.diagnostics), without ROS."""

from __future__ import annotations

import math

from rollergear_ros.ros.diagnostics import (OK, STALE, WARN, DiagnosticLimits, InputMonitor, InputsNow, NodeLoad,
                                            SinceLast, diagnose)
from rollergear_ros.core.estimator import Estimator
from rollergear_ros.core.pairing import SPEED, TORQUE
from rollergear_ros.core.params import load_config

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
    rep = diagnose(InputsNow(now, healthy, rates), est, DiagnosticLimits(1000.0, 0.9), SinceLast(dict(est.counts), 0))
    assert rep.level == OK and rep.message == "estimating"
    stale = _monitor(now, {TORQUE: now - MS, SPEED: now - 3 * 10**9})
    rep = diagnose(InputsNow(now, stale, rates), est, DiagnosticLimits(1000.0, 0.9), SinceLast(dict(est.counts), 0))
    assert rep.level == STALE and "stale input: motor_speed" in rep.message and "idle" in rep.message
    rep = diagnose(InputsNow(now, healthy, {TORQUE: 500.0, SPEED: 500.0}), est, DiagnosticLimits(1000.0, 0.9),
                   SinceLast(dict(est.counts), 0))
    assert rep.level == WARN and "expected 1000 Hz" in rep.message
    missing = _monitor(now, {TORQUE: now - MS})
    rep = diagnose(InputsNow(now, missing, rates), est, DiagnosticLimits(1000.0, 0.9), SinceLast(dict(est.counts), 0))
    assert rep.level == STALE and "no input on motor_speed" in rep.message
    est.counts["non_finite"] += 3
    rep = diagnose(InputsNow(now, healthy, rates), est, DiagnosticLimits(1000.0, 0.9),
                   SinceLast({**est.counts, "non_finite": 0}, 0))
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
        return diagnose(InputsNow(now, healthy, {TORQUE: rate, SPEED: rate}), est,
                        DiagnosticLimits(rate, 0.9, queue_depth=depth), SinceLast(dict(est.counts), 0),
                        NodeLoad(busy_fraction=0.4, executor_lag_s=lag_s))

    assert report(0.45, 1000).level == OK
    rep = report(0.55, 1000)
    assert rep.level == WARN and "overloaded: the node runs 0.55 s behind" in rep.message
    assert "input queues overflow" in rep.message and dict(rep.values)["executor lag [s]"] == "0.55"
    assert report(0.15, 1000, rate=5000.0).level == WARN  # 1000 messages at 5 kHz hold 0.2 s
    assert report(0.45, None).level == OK and "publishers are slowed" in report(0.55, None).message
    # a node starting with no input yet: its first timers lag, but no queue holds anything to lose
    quiet = diagnose(InputsNow(now, InputMonitor(now - 2 * 10**9), {TORQUE: 0.0, SPEED: 0.0}), est,
                     DiagnosticLimits(1000.0, 0.9, queue_depth=1000), SinceLast(dict(est.counts), 0),
                     NodeLoad(busy_fraction=0.0, executor_lag_s=2.0))
    assert "overloaded" not in quiet.message, quiet.message


def test_silence_the_node_s_own_lag_explains_is_no_stale_input():
    """A node 0.6 s behind its queues (or not run by a busy machine for that long) last took a message
    0.5 s ago: overloaded (WARN), not STALE "idle"; silent for longer than its lag explains: STALE."""
    est = Estimator(load_config(None))
    now = 100 * 10**9
    rates = {TORQUE: 1000.0, SPEED: 1000.0}

    def report(silent_s: float, lag_s: float):
        monitor = _monitor(now, {TORQUE: now - int(silent_s * 1e9), SPEED: now - MS})
        return diagnose(InputsNow(now, monitor, rates), est, DiagnosticLimits(1000.0, 0.9, queue_depth=1000),
                        SinceLast(dict(est.counts), 0), NodeLoad(busy_fraction=1.0, executor_lag_s=lag_s))

    rep = report(0.5, 0.6)
    assert rep.level == WARN and "overloaded" in rep.message and "stale" not in rep.message
    rep = report(0.8, 0.6)
    assert rep.level == STALE and "stale input: motor_torque silent for 0.80 s" in rep.message
    assert report(0.5, 0.0).level == STALE  # no lag: silence is silence


def test_received_and_not_estimated_per_input():
    est = Estimator(load_config(None))
    now = 100 * 10**9
    mon = _monitor(now, {TORQUE: now - MS, SPEED: now - MS})
    mon.counts[TORQUE], mon.counts[SPEED] = 120, 117
    est.estimated = 110
    values = dict(diagnose(InputsNow(now, mon, {TORQUE: 1000.0, SPEED: 1000.0}), est, DiagnosticLimits(1000.0, 0.9),
                           SinceLast(dict(est.counts), 0)).values)
    assert (values["motor_torque messages"], values["motor_torque not estimated"]) == ("120", "10")
    assert (values["motor_speed messages"], values["motor_speed not estimated"]) == ("117", "7")


def _feed(monitor, start_s, seconds, rate_hz, est, learn=True):
    """Both drive inputs at ``rate_hz`` from ``start_s`` for ``seconds``, a report at each whole
    second (as the node's 1 s loop) -> the reports."""
    reports = []
    t_ns, period_ns = round(start_s * 1e9), round(1e9 / rate_hz)
    for second in range(math.floor(start_s) + 1, math.floor(start_s + seconds) + 1):
        while t_ns < second * 10**9:
            for ch in (TORQUE, SPEED):
                monitor.record(ch, t_ns)
            t_ns += period_ns
        now = second * 10**9
        reports.append(diagnose(InputsNow(now, monitor, monitor.rates(now)), est,
                                DiagnosticLimits(1000.0, 0.5, learn_rate=learn), SinceLast(dict(est.counts), 0)))
    return reports


def test_a_bag_played_at_another_rate_is_learned_not_warned_about_for_ever():
    """500 Hz against the configured 1000 Hz from the stream's start: with learning, nothing is
    said while three whole windows are learned (the first, partial window is not one of them), then
    OK; without, a WARN at every report."""
    est = Estimator(load_config())
    learning = InputMonitor(0)
    reports = _feed(learning, 0.4, 8.0, 500.0, est)
    assert all(r.level == OK for r in reports), [r.message for r in reports]
    values = dict(reports[-1].values)
    assert values["motor_torque learned rate [Hz]"] == "500" and dict(reports[1].values)[
        "motor_torque learned rate [Hz]"] == "learning"
    assert learning.learned_rate_hz(TORQUE) == 500.0  # not the partial first window's 300 Hz
    fixed = _feed(InputMonitor(0), 0.4, 8.0, 500.0, est, learn=False)
    assert all(r.level == WARN and "motor_torque at 500 Hz, expected 1000 Hz" in r.message for r in fixed[1:])


def test_a_stream_that_slows_down_is_still_a_warning_and_a_new_stream_is_learned_anew():
    est = Estimator(load_config())
    monitor = InputMonitor(0)
    assert all(r.level == OK for r in _feed(monitor, 0.0, 6.0, 1000.0, est))
    slowed = _feed(monitor, 6.0, 3.0, 400.0, est)
    assert slowed[-1].level == WARN and "motor_torque at 400 Hz, its stream started at 1000 Hz" in slowed[-1].message
    monitor.rates(10 * 10**9)  # a whole window without a message: the player stopped
    assert monitor.learned_rate_hz(TORQUE) is None
    restarted = _feed(monitor, 10.5, 6.0, 200.0, est)
    assert all(r.level == OK for r in restarted) and monitor.learned_rate_hz(TORQUE) == 200.0


def _residual_report(est: Estimator, previous_alarms: int = 0):
    now = 100 * 10**9
    healthy = _monitor(now, {TORQUE: now - MS, SPEED: now - MS})
    return diagnose(InputsNow(now, healthy, {TORQUE: 1000.0, SPEED: 1000.0}), est, DiagnosticLimits(1000.0, 0.9),
                    SinceLast(dict(est.counts), previous_alarms))


def test_the_residual_warning_holds_while_the_residual_stays_and_says_whether_it_changed():
    config = load_config().with_values({"estimator.change_block_samples": 10})
    est = Estimator(config)
    det = est.detector
    t = iter(range(10**6))
    for level, blocks in ((0.0, 5), (0.1, 1)):  # calm, then a loss appears
        for _ in range(10 * blocks):
            det.add(level, next(t))
    assert det.alarms == 1 and det.alarm_from_start == [False]
    for _ in range(5):  # the loss stays: every report says so, not only the one after the alarm
        for _ in range(10):
            det.add(0.1, next(t))
        rep = _residual_report(est, previous_alarms=1)
        assert rep.level == WARN and "changed" in rep.message and "stays beyond" in rep.message
        assert dict(rep.values)["residual beyond threshold"] == "yes"
    for _ in range(30):  # it returns: three calm blocks, then OK
        det.add(0.0, next(t))
    rep = _residual_report(est, previous_alarms=1)
    assert rep.level == OK and dict(rep.values)["residual beyond threshold"] == "no"
    # a residual off from the first block on: no change, the parameters lack an effect
    off = Estimator(config)
    for _ in range(30):
        off.detector.add(0.1, next(t))
    assert off.detector.alarm_from_start == [True]
    rep = _residual_report(off)
    assert rep.level == WARN and "since the estimates began" in rep.message and "not a change" in rep.message


def test_the_alarm_points_to_loss_traced_only_where_a_trace_exists_or_will_come():
    """The status says where the trace of its alarm is: nothing with tracing off, when it will start
    while samples after the alarm are still to come, ``see loss/traced`` once there is one."""
    config = load_config().with_values({"estimator.change_block_samples": 10})
    est = Estimator(config)
    for k in range(30):
        est.detector.add(0.1, k)

    def message(hint: str) -> str:
        now = 100 * 10**9
        healthy = _monitor(now, {TORQUE: now - MS, SPEED: now - MS})
        return diagnose(InputsNow(now, healthy, {TORQUE: 1000.0, SPEED: 1000.0}), est, DiagnosticLimits(1000.0, 0.9),
                        SinceLast(dict(est.counts), 0), trace_hint=hint).message

    assert "loss/traced" not in message("")
    assert "(traced on loss/traced once 12 s more samples have come)" in message(
        "traced on loss/traced once 12 s more samples have come")
    assert "(see loss/traced)" in message("see loss/traced")


def test_an_adapted_coefficient_kept_inside_the_files_range_is_in_the_status():
    """Adaptation that wanted a constant drag below zero (held at 0) shows the count in the status."""
    config = load_config().with_values({"effects.drag_constant.enabled": True, "effects.drag_constant.c_nm": 0.01})
    est = Estimator(config)
    now = 100 * 10**9
    healthy = _monitor(now, {TORQUE: now - MS, SPEED: now - MS})
    rates = {TORQUE: 1000.0, SPEED: 1000.0}

    def values():
        return dict(diagnose(InputsNow(now, healthy, rates), est, DiagnosticLimits(1000.0, 0.9),
                             SinceLast(dict(est.counts), 0)).values)

    assert "adapted drag_constant kept in range [updates]" not in values()
    for _ in range(50):  # a measured loss far below the model's: the drag wants to be negative
        est.rls.update([1.0], -5.0)
    assert est.coefficients()["drag_constant"] == 0.0
    shown = values()
    assert shown["adapted drag_constant"] == "0" and int(shown["adapted drag_constant kept in range [updates]"]) > 0


def test_a_spin_test_is_said_as_a_loss_not_an_efficiency():
    """Nothing on the output (its torque reads 0): the drive power is all loss -- the status says so instead of
    a measured efficiency of 0.00 % and a WARN that the model's efficiency is below the limit; with power
    leaving the output the efficiency is the headline and a low model efficiency is warned of."""
    from rollergear_ros.core.measured import WindowValue
    from rollergear_ros.core.pairing import SyncedSample

    est = Estimator(load_config().with_values({"estimator.paper_model": False, "effects.drag_constant.enabled": True,
                                               "effects.drag_constant.c_nm": 0.5}))
    assert est.process(SyncedSample(10**9, 0.6, 100.0, 0.0, math.nan, math.nan)) is not None
    assert est.last.efficiency < 0.9
    now = 100 * 10**9
    healthy = _monitor(now, {TORQUE: now - MS, SPEED: now - MS})
    rates = {TORQUE: 1000.0, SPEED: 1000.0}

    def report(efficiency: float):
        return diagnose(InputsNow(now, healthy, rates), est, DiagnosticLimits(1000.0, 0.9),
                        SinceLast(dict(est.counts), 0), measured=WindowValue(now, efficiency, 0.0, 1000, 5.0))

    spin = report(0.0)
    assert "no power leaves the output over 5 s (a spin test)" in spin.message, spin.message
    assert "efficiency" not in spin.message and spin.level == OK, spin.message
    assert dict(spin.values)["measured efficiency"] == "0.0"  # the number stays for loggers
    loaded = report(0.85)
    assert "measured efficiency 85.00 % over 5 s" in loaded.message and loaded.level == WARN
    assert "below 90 %" in loaded.message


def test_the_sequence_clock_shows_its_rate_and_warns_when_the_publishers_say_another():
    """``node.sample_clock: sequence``: the status shows the clock's rate and the pauses it moved on at;
    once a topic's publisher has shown another rate (a recording played 10x), a WARN says both."""
    from rollergear_ros.core.seqclock import RATE_LEARN, SequenceClock

    est = Estimator(load_config())
    now = 100 * 10**9
    monitor = _monitor(now, {TORQUE: now - MS, SPEED: now - MS})
    monitor.sample_clock = clock = SequenceClock(0.01)
    rates = {TORQUE: 1000.0, SPEED: 1000.0}

    def report():
        return diagnose(InputsNow(now, monitor, rates), est, DiagnosticLimits(1000.0, 0.9),
                        SinceLast(dict(est.counts), 0))

    for k in range(RATE_LEARN):  # 100 Hz, as the clock
        clock.time_ns("motor_torque", k + 1, k * 10 * MS)
    rep = report()
    assert rep.level == OK, rep.message
    assert dict(rep.values)["sample clock"] == "publishers' numbers at 100 Hz; 0 pause(s) or restart(s)"
    for k in range(RATE_LEARN + 1):  # ten times as fast
        clock.time_ns("motor_speed", k + 1, k * MS)
    rep = report()
    assert rep.level == WARN and "motor_speed is published at 1000 Hz, the sample clock runs at 100 Hz" in rep.message
    monitor.sample_clock = clock = SequenceClock(0.01)  # an output publisher three samples out of step
    for k in range(RATE_LEARN + 3):
        clock.time_ns("motor_torque", k + 1, k * 10 * MS)
        clock.time_ns("output_torque", k + 1, (k + 3) * 10 * MS)
    rep = report()
    assert rep.level == WARN
    assert "output_torque's publisher numbers its messages out of step with motor_torque's" in rep.message
