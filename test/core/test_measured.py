"""The measured efficiency (core/measured.py): per sample and energy-weighted against hand computations
on a recording with known losses, its uncertainty against a Monte-Carlo of the sensors' errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rollergear_ros.core.measured import EnergyBalance, MeasuredEfficiency, balance_of, measured_efficiency
from rollergear_ros.core.params import SensorParams, load_config
from rollergear_ros.replay.run import replay

from bagtools import float_series, read_mcap_ros2
from helpers import BAGS, CONFIG

RATIO = 4.0
#: a 0.05 %-class torque sensor pair, a drive encoder of 0.01 rad/s and an output one of 0.005 rad/s
SENSORS = SensorParams(input_torque_full_scale_nm=100.0, input_torque_fs_pct=0.05, input_torque_reading_pct=0.05,
                       output_torque_full_scale_nm=400.0, output_torque_fs_pct=0.05, output_torque_reading_pct=0.05,
                       input_speed_resolution_rad_s=0.01, output_speed_resolution_rad_s=0.005)


def rig(n: int = 20_000, regenerating_share: float = 0.0, seed: int = 0):
    """A rig run with a known loss: drive torque and speed, the output torque ``(T − L·sgn ω)·R``
    (motoring) -- power in at the output flows back less the loss -- and the output speed ω/R."""
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    t_ns = 1_700_000_000_000_000_000 + k * 1_000_000  # 1 kHz
    speed = 120.0 + 40.0 * np.sin(k / 2500.0)
    torque = 30.0 + 12.0 * np.sin(k / 900.0) + rng.normal(0, 0.2, n)
    back = (k % 5000) < regenerating_share * 5000
    torque = np.where(back, -torque, torque)
    loss = 0.15 + 0.004 * np.abs(torque) + 0.001 * speed  # input-referred, opposes rotation
    out_torque = (torque - loss) * RATIO  # speed > 0: the loss always lowers the drive side's torque
    return t_ns, torque, speed, out_torque, speed / RATIO


def hand_efficiency(torque, speed, out_torque, out_speed):
    """What a rig engineer computes: power delivered over power supplied, in either direction."""
    p_in, p_out = torque * speed, out_torque * out_speed
    eta = np.full(len(p_in), np.nan)
    eta[p_in > 0] = p_out[p_in > 0] / p_in[p_in > 0]
    back = (p_in < 0) & (p_out < 0)
    eta[back] = p_in[back] / p_out[back]
    supplied = np.where(p_in > 0, p_in, np.where(back, -p_out, 0.0))
    delivered = np.where(p_in > 0, p_out, np.where(back, -p_in, 0.0))
    return eta, supplied, delivered


@pytest.mark.parametrize("regenerating_share", [0.0, 0.4])
def test_per_sample_and_energy_weighted_efficiency_are_the_hand_computation(regenerating_share):
    t, tq, w, tq_out, w_out = rig(regenerating_share=regenerating_share)
    eta_hand, supplied, delivered = hand_efficiency(tq, w, tq_out, w_out)
    eta = measured_efficiency(tq, w, tq_out, w_out, RATIO)
    np.testing.assert_allclose(eta, eta_hand, rtol=1e-12)
    # without a measured output speed (NaN): the drive's over the ratio, the same here
    np.testing.assert_allclose(measured_efficiency(tq, w, tq_out, np.full(len(w), np.nan), RATIO), eta_hand,
                               rtol=1e-12)
    # energy-weighted (each sample over the 1 ms step since the one before): delivered over supplied
    # energy, not the mean of the ratios
    b = balance_of(t, tq, w, tq_out, w_out, RATIO)
    assert b.efficiency == pytest.approx(delivered[1:].sum() / supplied[1:].sum(), rel=1e-12)
    assert b.supplied_j == pytest.approx(supplied[1:].sum() * 1e-3, rel=1e-12)
    assert b.samples == len(t) - 1
    if regenerating_share:  # back-driven, the loss comes off the output's power: η = P_in/P_out < 1
        assert np.nanmax(eta) < 1.0 and (eta[tq < 0] < 1).all()
    # below the thresholds (the model's): NaN, as the model's efficiency
    low = measured_efficiency([0.1, 30.0], [100.0, 0.2], [0.3, 100.0], [25.0, 0.05], RATIO, 0.2, 0.5)
    assert np.isnan(low).all()


def test_the_sums_add_up_over_batches_seconds_and_cells():
    t, tq, w, tq_out, w_out = rig(regenerating_share=0.3)
    whole = balance_of(t, tq, w, tq_out, w_out, RATIO)
    tally = MeasuredEfficiency(RATIO, 1e-3, window_s=5.0, speed_step_rpm=200.0, torque_step_nm=10.0)
    for lo in range(0, len(t), 777):  # batches that cut seconds anywhere
        sl = slice(lo, lo + 777)
        tally.add(t[sl], tq[sl], w[sl], tq_out[sl], w_out[sl])
    for name in ("supplied_j", "delivered_j", "s_gain_in", "d_offset_out", "in_bb"):
        assert getattr(tally.total, name) == pytest.approx(getattr(whole, name), rel=1e-9)
    assert tally.total.samples == whole.samples
    parts = tally.motoring + tally.regenerating
    assert parts.supplied_j == pytest.approx(whole.supplied_j, rel=1e-9)
    assert tally.regenerating.supplied_j > 0 and tally.motoring.supplied_j > 0
    cells = tally.cells()
    assert sum(b.samples for _, _, b in cells) == whole.samples
    assert sum(b.supplied_j for _, _, b in cells) == pytest.approx(whole.supplied_j, rel=1e-9)
    # each cell is its samples' own balance: the nearest node of the grid
    rpm = w * 30 / math.pi
    for speed_rpm, torque_nm, b in cells[:5]:
        mine = (np.rint(rpm / 200.0) * 200.0 == speed_rpm) & (np.rint(tq / 10.0) * 10.0 == torque_nm)
        mine[0] = False  # the first sample: no step before it
        eta_hand, supplied, delivered = hand_efficiency(tq[mine], w[mine], tq_out[mine], w_out[mine])
        assert b.samples == mine.sum()
        assert b.efficiency == pytest.approx(delivered.sum() / supplied.sum(), rel=1e-9)
    # the window of 5 s before second boundary k holds the samples of seconds k-5 … k-1
    boundary = int(t[0] // 1_000_000_000) + 12
    inside = (t // 1_000_000_000 >= boundary - 5) & (t // 1_000_000_000 < boundary)
    _, supplied, delivered = hand_efficiency(tq[inside], w[inside], tq_out[inside], w_out[inside])
    assert tally.window(boundary).efficiency == pytest.approx(delivered.sum() / supplied.sum(), rel=1e-9)
    assert tally.window(boundary).samples == inside.sum()


def test_a_gap_is_not_integrated_across():
    t, tq, w, tq_out, w_out = rig(4000)
    t = t.copy()
    t[2000:] += 60 * 10**9  # the rig paused for a minute
    b = balance_of(t, tq, w, tq_out, w_out, RATIO)
    # 1 ms for each sample but the first and the one after the pause: it starts a new stretch
    assert b.seconds == pytest.approx(3.998, rel=1e-9)


def monte_carlo(t, tq, w, tq_out, w_out, sensors: SensorParams, draws: int, seed: int = 1, measured_out_speed=True):
    """Standard deviation of the energy-weighted efficiency over draws of the sensors' errors within
    their stated limits (uniform): one gain and one offset per torque sensor and run, the speed
    readings rounded to their resolution at a random phase each sample."""
    rng = np.random.default_rng(seed)
    dt = 1e-3
    etas = []
    for _ in range(draws):
        g_in, g_out = rng.uniform(-1, 1, 2) * np.array([sensors.input_torque_reading_pct,
                                                        sensors.output_torque_reading_pct]) / 100
        o_in = rng.uniform(-1, 1) * sensors.input_torque_fs_pct * sensors.input_torque_full_scale_nm / 100
        o_out = rng.uniform(-1, 1) * sensors.output_torque_fs_pct * sensors.output_torque_full_scale_nm / 100
        q_in, q_out = sensors.input_speed_resolution_rad_s, sensors.output_speed_resolution_rad_s
        w_m = w + rng.uniform(-0.5, 0.5, len(w)) * q_in
        w_out_m = (w_out + rng.uniform(-0.5, 0.5, len(w)) * q_out) if measured_out_speed else w_m / RATIO
        _, supplied, delivered = hand_efficiency(tq * (1 + g_in) + o_in, w_m, tq_out * (1 + g_out) + o_out, w_out_m)
        etas.append(delivered.sum() * dt / (supplied.sum() * dt))
    return float(np.std(etas, ddof=1))


@pytest.mark.parametrize("case", ["motoring", "both directions of power", "output speed not measured",
                                  "speed resolution dominates"])
def test_the_uncertainty_is_the_monte_carlo_of_the_sensors_errors_within_ten_percent(case):
    sensors, n, share, measured_out = SENSORS, 20_000, 0.0, True
    if case == "both directions of power":
        share = 0.3
    elif case == "output speed not measured":
        measured_out = False
    elif case == "speed resolution dominates":  # a coarse encoder on a short window: its steps count
        sensors = SensorParams(input_torque_full_scale_nm=100.0, input_torque_reading_pct=0.001,
                               output_torque_full_scale_nm=400.0, output_torque_reading_pct=0.001,
                               input_speed_resolution_rad_s=20.0, output_speed_resolution_rad_s=5.0)
        n = 200
    t, tq, w, tq_out, w_out = rig(n, regenerating_share=share)
    b = balance_of(t, tq, w, tq_out, w_out if measured_out else np.full(n, np.nan), RATIO)
    u = b.uncertainty(sensors)
    mc = monte_carlo(t, tq, w, tq_out, w_out, sensors, 4000, measured_out_speed=measured_out)
    assert u == pytest.approx(mc, rel=0.10), f"GUM {u:.3g} against Monte-Carlo {mc:.3g}"
    if case == "motoring":  # a 0.05 %-class pair at ~98 %: a few hundredths to tenths of a percent
        assert 2e-4 < u < 5e-3
    assert EnergyBalance().uncertainty(sensors) != EnergyBalance().uncertainty(sensors)  # NaN: no efficiency
    assert b.uncertainty(SensorParams()) == 0.0  # nothing stated


def test_replay_reports_the_measured_efficiency_of_the_recording_as_computed_by_hand(tmp_path):
    """The bundled rig recording with an extra drag: the recording's own inputs, read by another
    reader, give the figure replay prints, per sample, per window and over the whole recording."""
    bag = BAGS / "rig_map_drag.mcap"
    config = load_config(CONFIG)
    out = tmp_path / "out.mcap"
    summary, batches = replay(bag, config, out_mcap=out, show_progress=False, collect=True)
    raw = read_mcap_ros2(bag)
    t, tq = float_series(raw, "/rollergear/motor/torque")
    _, w = float_series(raw, "/rollergear/motor/speed")
    _, tq_out = float_series(raw, "/rollergear/output/torque")
    _, w_out = float_series(raw, "/rollergear/output/speed")
    eta_hand, supplied, delivered = hand_efficiency(tq, w, tq_out, w_out)
    # the samples with a measured loss (not those near standstill whose direction the speed reading
    # cannot tell), each over the step since the one before
    t_est = np.concatenate([b.t_ns for b in batches])
    with_loss = np.isin(t, t_est[np.isfinite(np.concatenate([b.measured_loss_nm for b in batches]))])
    assert 0.99 * len(t) < with_loss.sum() < len(t)
    t_m = t[with_loss]
    dt = np.zeros(len(t))
    dt[with_loss] = np.diff(t_m, prepend=t_m[0]) * 1e-9
    assert summary.efficiency_measured == pytest.approx((delivered * dt).sum() / (supplied * dt).sum(), rel=1e-12)
    assert summary.efficiency_measured < summary.measured.model_efficiency - 0.01  # the drag the model lacks
    assert "measured efficiency: 98.04 %" in summary.text()
    per_sample = np.concatenate([b.efficiency_measured for b in batches])
    i = np.searchsorted(t, t_est)
    big = (np.abs(tq[i]) >= config.estimator.min_torque_for_efficiency_nm) \
        & (np.abs(w[i]) >= config.estimator.min_speed_for_efficiency_rad_s)
    np.testing.assert_allclose(per_sample[big], eta_hand[i][big], rtol=1e-12)
    # the windows in the output MCAP: once a second, the 10 s before it
    windows = read_mcap_ros2(out)["/rollergear/efficiency/measured"]
    ends, values = windows[0], np.array([m.data for m in windows[1]])
    assert len(ends) == int(t[-1] // 10**9 - t[0] // 10**9)
    for end, value in zip(ends[::17], values[::17]):
        inside = (t >= end - 10 * 10**9) & (t < end)
        assert value == pytest.approx((delivered * dt)[inside].sum() / (supplied * dt)[inside].sum(), rel=1e-12)
    # every exported sample carries the window published at the start of its second
    window = np.concatenate([b.efficiency_measured_window for b in batches])
    k = np.searchsorted(ends, (t_est // 10**9) * 10**9)
    has = k < len(ends)
    has[has] &= ends[k[has]] == (t_est[has] // 10**9) * 10**9
    np.testing.assert_array_equal(window[has], values[k[has]])
    assert np.isnan(window[~has]).all()


def test_the_windows_of_an_idle_gap_are_not_published_when_the_samples_resume():
    """After an idle gap the node published every missed window at once (10 within 0.6 ms), each of
    stale samples or none: a window is due at a boundary whose last second holds samples."""
    t, tq, w, tq_out, w_out = rig(6000)
    t = t.copy()
    t[3000:] += 30 * 10**9  # 3 s of samples, 30 s idle, 3 s more
    tally = MeasuredEfficiency(RATIO, 1e-3, window_s=10.0)
    tally.add(t[:3000], tq[:3000], w[:3000], tq_out[:3000], w_out[:3000])
    before = tally.boundaries(None)
    assert len(before) == 2  # the seconds completed while samples came
    tally.add(t[3000:], tq[3000:], w[3000:], tq_out[3000:], w_out[3000:])
    after = tally.boundaries(before[-1])
    first_s = int(t[0]) // 10**9
    # the boundary after the last second of samples before the gap, then those after it resumed
    assert after == [first_s + 3, first_s + 34, first_s + 35]


def test_an_overall_uncertainty_below_either_directions_says_why():
    """A recording with both power flows was stated as ± 0.001 % without a word: the gain errors cancel
    between the directions, 90x below either one's uncertainty, said on the same line."""
    from helpers import ROOT

    summary, _ = replay(BAGS / "rig_map_drag.mcap", load_config(ROOT / "config" / "rig.yaml"), show_progress=False)
    first = next(line for line in summary.text().splitlines() if line.startswith("measured efficiency:"))
    (_, u_mot), (_, u_reg) = summary.measured_quadrants
    assert summary.measured_uncertainty < 0.1 * min(u_mot, u_reg)
    assert f"either direction alone ± {100 * min(u_mot, u_reg):.2g} %" in first and "cancels" in first
