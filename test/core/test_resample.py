"""Channels at another rate than the drive torque: resampled onto its stamps, live and offline alike."""

from __future__ import annotations

import math
from collections import deque
from pathlib import Path

import numpy as np
import pytest

from rollergear_ros.core.estimator import Estimator
from rollergear_ros.core.pairing import CHANNELS, OIL_TEMPERATURE, OUT_TORQUE, SPEED, TORQUE
from rollergear_ros.core.resample import DECIDE_TORQUE_MESSAGES, value_at

RATIO = 4.0


def _rig_messages(duration_s: float, rates_hz: dict[str, float], seed: int = 0,
                  speed_stops_at_s: float | None = None, first_within_periods: float = 0.9):
    """A rig logging each channel at its own rate on its own stamps (the first ones up to
    ``first_within_periods`` of a period apart): speed ``50 + 20 sin t`` rad/s, drive torque
    ``10 + sin t``, the output the drive torque less a 0.3 N·m drag times the ratio.  Messages in
    log-time order: ``codes, t_ns, values``."""
    rng = np.random.default_rng(seed)
    speed = lambda t: 50.0 + 20.0 * np.sin(t)  # noqa: E731
    torque = lambda t: 10.0 + np.sin(t)  # noqa: E731
    signals = {TORQUE: torque, SPEED: speed, OUT_TORQUE: lambda t: (torque(t) - 0.3) * RATIO,
               OIL_TEMPERATURE: lambda t: 40.0 + 0.0 * t}
    rows = []
    for channel, rate in rates_hz.items():
        t = np.arange(rng.uniform(0.0, first_within_periods) / rate, duration_s, 1.0 / rate)
        if channel == SPEED and speed_stops_at_s is not None:
            t = t[t < speed_stops_at_s]
        rows.append((np.full(len(t), CHANNELS.index(channel)), np.round(t * 1e9).astype(np.int64), signals[channel](t)))
    codes, t_ns, values = (np.concatenate(parts) for parts in zip(*rows))
    order = np.lexsort((codes, t_ns))
    return codes[order], t_ns[order], values[order], speed


def _config(config, **estimator):
    return config.with_values({"gearbox.ratio": RATIO, "estimator.paper_model": False, "estimator.adapt": False,
                               **{f"estimator.{k}": v for k, v in estimator.items()}})


def _batch(estimator, codes, t_ns, values, size):
    parts = [estimator.push_many(codes[k:k + size], t_ns[k:k + size], values[k:k + size])
             for k in range(0, len(codes), size)]
    parts.append(estimator.flush())
    parts = [p for p in parts if p is not None]
    return {name: np.concatenate([getattr(p, name) for p in parts])
            for name in ("t_ns", "speed_rad_s", "loss_torque_nm", "residual_nm")}


def _stream(estimator, codes, t_ns, values):
    out = []
    for c, t, v in zip(codes.tolist(), t_ns.tolist(), values.tolist()):
        out.extend(estimator.push(CHANNELS[c], t, v))
    out.extend(estimator.finish())
    return {"t_ns": np.array([e.t_ns for e in out]), "speed_rad_s": np.array([e.speed_rad_s for e in out]),
            "loss_torque_nm": np.array([e.loss_torque_nm for e in out]),
            "residual_nm": np.array([e.residual_nm for e in out])}


def test_value_at_interpolates_holds_within_the_age_and_gives_none_beyond():
    history = deque([(0, 1.0), (10, 3.0), (100, 5.0)])
    assert value_at(history, 10, 20) == (3.0, "exact")
    assert value_at(history, 5, 20) == (2.0, "interpolated")
    assert value_at(history, 25, 20) == (3.0, "held")  # the next one is 75 away: held, 15 old
    value, kind = value_at(history, 40, 20)
    assert kind == "none" and math.isnan(value)
    assert value_at(deque([(10, 3.0)]), 5, 20)[1] == "none"  # nothing before it


@pytest.mark.parametrize("rates", [{TORQUE: 1000.0, SPEED: 100.0, OUT_TORQUE: 1000.0, OIL_TEMPERATURE: 10.0},
                                   {TORQUE: 1000.0, SPEED: 1000.0, OUT_TORQUE: 200.0},
                                   {TORQUE: 500.0, SPEED: 5000.0, OUT_TORQUE: 500.0}])
def test_channels_at_other_rates_are_estimated_at_every_torque_stamp_live_and_offline(config, rates):
    codes, t_ns, values, speed = _rig_messages(30.0, rates)
    torques = int(np.count_nonzero(codes == CHANNELS.index(TORQUE)))
    cfg = _config(config, speed_noise_rad_s=0.01)
    estimator = Estimator(cfg)
    offline = _batch(estimator, codes, t_ns, values, 10_007)
    live = _stream(Estimator(cfg, "arrival_reliable"), codes, t_ns, values)
    assert len(offline["t_ns"]) >= 0.99 * torques
    for name in offline:  # the node's one-by-one path and replay's arrays: the same samples, bit for bit
        np.testing.assert_array_equal(live[name], offline[name])
    # a resampled speed is the line between its neighbours: within the sine's curvature of the truth
    # (|ω''| ≤ 20 rad/s³); one in step is paired, within the tolerance of the torque's stamp (|ω'| ≤ 20 rad/s²)
    t = offline["t_ns"] * 1e-9
    inside = t < t[-1] - 0.05
    resampled = SPEED in estimator.resampler.resampled
    assert resampled == (rates[SPEED] != rates[TORQUE] or not estimator.resampler._in_step(
        [int(x) for x in t_ns[codes == CHANNELS.index(SPEED)][:DECIDE_TORQUE_MESSAGES]]))
    bound = 20.0 * (1.0 / rates[SPEED]) ** 2 / 8 if resampled else 20.0 * estimator.resampler.tolerance_ns * 1e-9
    assert np.max(np.abs(offline["speed_rad_s"][inside] - speed(t[inside]))) < 1.01 * bound
    # the residual: the 0.3 N·m the model lacks, everywhere
    resid = offline["residual_nm"][inside]
    assert np.all(np.isfinite(resid)) and np.allclose(resid, 0.3, atol=0.01)


def test_channels_at_one_rate_are_paired_exactly_as_without_resampling(config):
    codes, t_ns, values, _ = _rig_messages(10.0, {TORQUE: 1000.0, SPEED: 1000.0, OUT_TORQUE: 1000.0},
                                           first_within_periods=0.3)
    on = _batch(Estimator(_config(config)), codes, t_ns, values, 4096)
    off = _batch(Estimator(_config(config, resample_max_age_s=0.0)), codes, t_ns, values, 4096)
    estimator = Estimator(_config(config))
    _batch(estimator, codes, t_ns, values, 4096)
    assert estimator.resampler.resampled == () and estimator.resampler.describe() is None
    for name in on:
        np.testing.assert_array_equal(on[name], off[name])


def test_without_resampling_a_slower_speed_pairs_a_tenth_of_the_samples(config):
    """What the resampling is for (the same messages, paired message by message)."""
    codes, t_ns, values, _ = _rig_messages(10.0, {TORQUE: 1000.0, SPEED: 100.0})
    off = Estimator(_config(config, resample_max_age_s=0.0))
    assert len(_batch(off, codes, t_ns, values, 4096)["t_ns"]) < 0.15 * np.count_nonzero(codes == 0)


def test_a_speed_that_stops_holds_its_last_value_for_the_age_limit_then_samples_are_stale(config):
    codes, t_ns, values, _ = _rig_messages(10.0, {TORQUE: 1000.0, SPEED: 100.0}, speed_stops_at_s=5.0)
    estimator = Estimator(_config(config, resample_max_age_s=0.05))
    out = _batch(estimator, codes, t_ns, values, 3000)
    made = estimator.resampler.made[SPEED]
    assert 45 <= made["held"] <= 55  # 50 ms at 1 kHz after the last speed message
    assert estimator.counts["stale"] == made["none"] >= 4900
    assert out["t_ns"].max() < 5.06e9
    assert "held value" in estimator.resampler.describe()


def test_a_busy_machines_recorded_arrivals_at_one_rate_are_paired_not_resampled(config):
    """The arrival times, order and publisher timestamps of 8 000 input messages a node received in
    a stress run (``data/preempted_publisher_events.npz``: rig_map_drag played at 5x, reliable, keep
    all, two test processes busy on the two cores).  The player was preempted between the messages
    of some samples, stamping their outputs 0.3-0.5 periods late (a few 2 ms late): the output speed
    was once told out of step and resampled, its first value one sample ahead, and two samples were
    lost.  Every channel is at the torque's rate and nothing was lost, so every sample pairs with its
    own partners and none is resampled."""
    data = np.load(Path(__file__).resolve().parents[1] / "data" / "preempted_publisher_events.npz")
    t_ns = np.cumsum(data["dt_ns"]) + 1_000_000_000
    estimator = Estimator(config.with_values({"estimator.paper_model": False}), "arrival_reliable", 0.001)
    seen = dict.fromkeys(range(4), 0)
    out = []
    for t, code, offset in zip(t_ns.tolist(), data["channel"].tolist(), data["source_offset_ns"].tolist()):
        k = seen[code]
        seen[code] += 1
        # the value: the message's index on its topic, in a plausible operating point
        value = (10.0, 100.0, 30.0, 25.0)[code] + 1e-4 * k
        out += estimator.push(CHANNELS[code], t, value, t + offset)
    out += estimator.finish()
    assert estimator.resampler.resampled == () and estimator.counts["unpaired"] == 0
    assert len(out) == min(seen.values())
    index = np.array([[(e.torque_nm - 10.0), (e.speed_rad_s - 100.0), (e.out_torque_nm - 30.0),
                       (e.out_speed_rad_s - 25.0)] for e in out]) / 1e-4
    np.testing.assert_allclose(index, np.repeat(np.arange(len(out))[:, None], 4, axis=1), atol=1e-6)


@pytest.mark.parametrize("late_share", [0.0, 0.6])
def test_a_channel_on_a_clock_of_its_own_is_resampled_and_one_sometimes_late_is_not(config, late_share):
    """At the torque's 1 kHz: an output torque half a period after every torque stamp (a DAQ on its
    own clock) is resampled; one sent with its sample but stamped 0.45 periods late in 60 % of the
    samples (a preempted publisher) is paired."""
    rng = np.random.default_rng(3)
    n = 400
    t = 1_000_000_000 + 1_000_000 * np.arange(n)
    late = rng.random(n) < late_share
    out_offset = np.where(late, 450_000, 20_000) if late_share else np.full(n, 500_000)
    estimator = Estimator(config.with_values({"estimator.paper_model": False}), "arrival_reliable", 0.001)
    for k in range(n):
        for channel, offset, value in ((TORQUE, 0, 10.0), (SPEED, 10_000, 100.0), (OUT_TORQUE, out_offset[k], 38.0)):
            estimator.push(channel, int(t[k] + offset), value, int(t[k] + offset))
    estimator.finish()
    assert estimator.resampler.resampled == (() if late_share else (OUT_TORQUE,))
