"""The estimator (rollergear_ros.core.estimator): the sensor errors it removes from the model's input; its
per-sample path (the node's) against its batch path (replay's)."""

from __future__ import annotations

import numpy as np
import pytest

from rollergear_ros.calibration.simulate import SimulationOptions, simulate
from rollergear_ros.core.effects import EFFECTS, EffectInputs
from rollergear_ros.core.estimator import Estimator
from rollergear_ros.core.model import SIGN_BAND
from rollergear_ros.core.pairing import SyncedSample
from rollergear_ros.core.params import load_config

from helpers import with_effect


def test_sensor_errors_are_removed_from_the_model_input():
    cfg = load_config().with_values({"effects.torque_offset.enabled": True, "effects.torque_offset.offset_nm": 0.5,
                                     "effects.torque_gain.enabled": True, "effects.torque_gain.gain": 0.01,
                                     "estimator.adapt": False})
    est = Estimator(cfg)
    assert est.corrected_torque(10.5 * 1.0 + 0.1) == pytest.approx((10.6 - 0.5) / 1.01)
    b = est.process_batch(np.array([0]), np.array([20.0]), np.array([100.0]))
    plain = Estimator(load_config()).process_batch(np.array([0]), np.array([(20.0 - 0.5) / 1.01]), np.array([100.0]))
    assert b.loss_torque_nm[0] == pytest.approx(plain.loss_torque_nm[0], rel=1e-12)


@pytest.mark.parametrize("adapt", [True, False], ids=["adapted", "fixed"])
@pytest.mark.parametrize("name", [None, *EFFECTS])
def test_the_nodes_sample_by_sample_path_equals_replays_arrays_bit_for_bit(name, adapt):
    """What the node publishes (:meth:`Estimator.process` on Python floats) is what replay computes
    for the same samples (:meth:`Estimator.process_batch` on arrays), to the last bit: a drive cycle
    through standstill (the smooth sign, its width the speed noise learned over the first samples)
    with the oil warming (the temperature effects), each effect on, adapted online and fixed."""
    config = load_config().with_values({"estimator.adapt": adapt})
    if name is not None:  # on at the values simulate gives it
        config = with_effect(config, name, EFFECTS[name].simulated_defaults())
    rig = simulate(config, SimulationOptions("drive_cycle", 100.0, 5))
    columns = (rig.t_ns, rig.torque_meas_nm, rig.speed_rad_s, rig.out_torque_meas_nm, rig.out_speed_meas_rad_s,
               rig.temperature_c)
    replayed = Estimator(config)
    batch = replayed.process_batch(*columns, breakdown=False)
    node = Estimator(config)
    live = [e for e in (node.process(SyncedSample(*row)) for row in zip(*(np.asarray(c).tolist() for c in columns)))
            if e is not None]
    assert len(live) == len(batch.t_ns) > 1000
    # the speed noise learned (auto) at the same samples, to the same value
    assert node.speed_noise.value == replayed.speed_noise.value > 0 and node.speed_noise.learned_from == 1000
    assert np.any(np.abs(rig.speed_rad_s) < SIGN_BAND * node.speed_noise.value)  # the tanh band
    for field in ("loss_torque_nm", "loss_power_w", "efficiency", "measured_loss_nm", "residual_nm"):
        np.testing.assert_array_equal(np.array([getattr(e, field) for e in live]), getattr(batch, field), err_msg=field)


@pytest.mark.parametrize("adapt", [True, False], ids=["adapted", "fixed"])
def test_laws_in_the_load_give_one_answer_sample_by_sample_and_in_arrays_with_and_without_an_output(adapt):
    """The laws in the load beside other losses, the output torque measured over stretches only: where it
    is, the adapted laws take the measured load; where not, the load solved at the coefficients of the
    moment.  The node's path and replay's give the same bits."""
    config = load_config().with_values({"estimator.adapt": adapt})
    for name, params in (("drag_speed", {"c": 3e-3, "p": 1.2}), ("load_dependent", {"c": 0.05, "q": 1.3}),
                         ("load_speed", {"c": 2e-4, "p": 1.0}), ("backdrive", {"c": 0.03, "q": 0.8})):
        config = with_effect(config, name, params)
    rig = simulate(config, SimulationOptions("drive_cycle", 100.0, 5))
    out = np.where((np.arange(len(rig.t_ns)) // 700) % 2 == 0, rig.out_torque_meas_nm, np.nan)
    columns = (rig.t_ns, rig.torque_meas_nm, rig.speed_rad_s, out, rig.out_speed_meas_rad_s, rig.temperature_c)
    batch = Estimator(config).process_batch(*columns, breakdown=False)
    node = Estimator(config)
    live = [e for e in (node.process(SyncedSample(*row)) for row in zip(*(np.asarray(c).tolist() for c in columns)))
            if e is not None]
    assert len(live) == len(batch.t_ns) > 1000
    assert np.isfinite(batch.measured_loss_nm).any() and np.isnan(batch.measured_loss_nm).any()
    for field in ("loss_torque_nm", "loss_power_w", "efficiency", "residual_nm"):
        np.testing.assert_array_equal(np.array([getattr(e, field) for e in live]), getattr(batch, field), err_msg=field)


def test_a_lag_aligns_a_recording_whose_samples_are_further_apart_than_the_staleness():
    """A controller read every 256 ms (a worm drive's slowest levels) with its speed 43 ms late (what
    calibrate finds in the faster levels): each sample takes the speed at t + lag between the two
    samples around it, the node's path and replay's alike; one sample missing is bridged, a pause of
    a second is not (staleness 0.1 s; with it alone no two samples bracketed any time, and every
    sample was skipped): there, and at the end, no reading comes 43 ms later, and the nearest one --
    the sample's own -- is held and counted."""
    from rollergear_ros.core.pairing import CHANNELS

    grid = np.arange(300) * 256_000_000
    t = np.concatenate([grid[:100], grid[101:200], grid[200:] + 1_000_000_000])  # one missing, then a 1.3 s pause
    before_pause = int(grid[199])
    speed = 0.5 + 0.2 * np.sin(t * 1e-9)
    torque = 0.002 + 0.0 * t
    n = len(t)
    codes = np.tile(np.arange(4), n)
    t_ns = np.repeat(t.astype(np.int64), 4)
    values = np.column_stack([torque, speed, np.zeros(n), speed]).ravel()
    config = load_config().with_values({"estimator.motor_speed_lag_s": 0.0426, "estimator.adapt": False,
                                        "estimator.paper_model": False})

    def estimates(by_message: bool):
        est = Estimator(config, sample_period_s=0.256)
        if by_message:
            out = [e for c, ts, v in zip(codes.tolist(), t_ns.tolist(), values.tolist())
                   for e in est.push(CHANNELS[c], ts, v)] + list(est.finish())
            return np.array([e.t_ns for e in out]), np.array([e.speed_rad_s for e in out]), est.aligner.held
        parts = [p for p in (est.push_many(codes, t_ns, values), est.flush()) if p is not None]
        return (np.concatenate([p.t_ns for p in parts]), np.concatenate([p.speed_rad_s for p in parts]),
                est.aligner.held)

    (t_node, w_node, held_node), (t_replay, w_replay, held) = estimates(True), estimates(False)
    np.testing.assert_array_equal(t_node, t_replay)
    np.testing.assert_array_equal(w_node, w_replay)
    assert set(t_replay.tolist()) == set(t.tolist())  # none lost
    ends = np.isin(t_replay, [before_pause, int(t[-1])])  # before the pause, and the last: nothing after
    np.testing.assert_array_equal(w_replay[ends], speed[np.isin(t, [before_pause, int(t[-1])])])
    assert held == held_node == {"motor_speed": 2}, held
    expected = 0.5 + 0.2 * np.sin((t_replay[~ends] + 42_600_000) * 1e-9)
    np.testing.assert_allclose(w_replay[~ends], expected, atol=0.2 * 0.256 ** 2 / 8 * 1.01)  # linear between


@pytest.mark.parametrize("lag_s", [0.03, 0.0173])
def test_a_lagging_channel_is_aligned_alike_message_by_message_and_in_arrays(lag_s):
    """An output torque channel 30 ms late (and one late by a fraction of a period): with
    ``estimator.output_torque_lag_s`` the node's path (one message at a time) and replay's (arrays) give
    the same estimates to the last bit, and the residual the lag left is gone (within 1.5x what a rig
    without the lag leaves: linear interpolation between samples 10 ms apart)."""
    from rollergear_ros.core.pairing import CHANNELS

    rig = simulate(load_config(), SimulationOptions("drive_cycle", 100.0, 5, output_lag_s=lag_s))
    n = len(rig.t_ns)
    streams = [rig.torque_meas_nm, rig.speed_rad_s, rig.out_torque_meas_nm, rig.out_speed_meas_rad_s]
    codes = np.tile(np.arange(4), n)
    t_ns = np.repeat(np.asarray(rig.t_ns, dtype=np.int64), 4)
    values = np.column_stack(streams).ravel()

    def residuals(config, by_message: bool) -> np.ndarray:
        est = Estimator(config)
        if by_message:
            out = [e.residual_nm for c, t, v in zip(codes.tolist(), t_ns.tolist(), values.tolist())
                   for e in est.push(CHANNELS[c], t, v)]
            return np.array(out + [e.residual_nm for e in est.finish()])
        parts = [est.push_many(codes, t_ns, values), est.flush()]
        return np.concatenate([p.residual_nm for p in parts if p is not None])

    aligned = load_config().with_values({"estimator.output_torque_lag_s": lag_s, "estimator.adapt": False})
    node, replayed = residuals(aligned, True), residuals(aligned, False)
    np.testing.assert_array_equal(node, replayed)
    plain = residuals(load_config().with_values({"estimator.adapt": False}), False)
    rms = float(np.sqrt(np.nanmean(replayed ** 2)))
    assert len(replayed) == len(plain) and rms < 0.25 * float(np.sqrt(np.nanmean(plain ** 2))), rms
    rig = simulate(load_config(), SimulationOptions("drive_cycle", 100.0, 5))  # the same rig without the lag
    streams = [rig.torque_meas_nm, rig.speed_rad_s, rig.out_torque_meas_nm, rig.out_speed_meas_rad_s]
    values = np.column_stack(streams).ravel()
    floor = residuals(load_config().with_values({"estimator.adapt": False}), False)
    assert rms < 1.5 * float(np.sqrt(np.nanmean(floor ** 2))), rms


def test_online_adaptation_stays_inside_the_range_a_parameter_file_may_hold():
    """A gearbox that loses less than the file's model (measured: no loss at all) drives the adapted
    constant drag below zero, a value the parameter file refuses ("a power source"): the coefficient
    is projected back to its bound, the model never claims an efficiency above 100 %, the clamp is
    counted and said, and the node's path and replay's still agree bit for bit."""
    rig = simulate(load_config(), SimulationOptions("drive_cycle", 100.0, 5))
    moving = np.abs(rig.out_speed_meas_rad_s) > 1e-3
    out_torque = np.full(len(rig.t_ns), np.nan)  # every watt in comes out: P_out = T·ω
    out_torque[moving] = rig.torque_meas_nm[moving] * rig.speed_rad_s[moving] / rig.out_speed_meas_rad_s[moving]
    config = with_effect(load_config().with_values({"estimator.adapt": True}), "drag_constant", {"c": 0.05})
    columns = (rig.t_ns, rig.torque_meas_nm, rig.speed_rad_s, out_torque, rig.out_speed_meas_rad_s, rig.temperature_c)
    replayed = Estimator(config)
    batch = replayed.process_batch(*columns, breakdown=False)
    unbounded = Estimator(config)
    unbounded.rls.bounds = [(-np.inf, np.inf)]
    unbounded.process_batch(*columns, breakdown=False)
    assert unbounded.coefficients()["drag_constant"] < -0.01  # what adaptation wanted
    assert replayed.coefficients()["drag_constant"] == 0.0 and replayed.rls.held[0] > 100
    assert np.nanmax(batch.efficiency) <= 1.0
    said = replayed.adaptation_text()
    assert "effects.drag_constant.c_nm kept within the range a parameter file may hold [0," in said
    node = Estimator(config)
    live = [e for e in (node.process(SyncedSample(*row)) for row in zip(*(np.asarray(c).tolist() for c in columns)))
            if e is not None]
    np.testing.assert_array_equal(np.array([e.loss_torque_nm for e in live]), batch.loss_torque_nm)
    assert node.rls.held == replayed.rls.held


@pytest.mark.parametrize("sigma", [0.3, 1.0, 3.0])
def test_a_drive_at_rest_gives_no_measured_loss_whatever_its_speed_readings_noise(sigma):
    """A servo stuck at rest, its output held by a load (the input torque 0, the output torque what holds
    it), its speed readings noise of σ on either side of the efficiency's speed threshold (0.5 rad/s): a
    reading's sign is no direction there, so no loss is measured from it -- it was, as ± the holding
    torque, wherever |ω| passed 0.5 rad/s, and a law without a Coulomb part fitted those zeros -- while a
    drive turning at 5σ is measured at every sample.  The node's path and replay's alike."""
    config = load_config().with_values({"estimator.speed_noise_rad_s": sigma, "estimator.paper_model": False,
                                        "gearbox.ratio": 288.0})
    rng = np.random.default_rng(1)
    n = 4000
    t = np.arange(n, dtype=np.int64) * 2_000_000
    speed = np.r_[rng.normal(0.0, sigma, n // 2), 5.0 * sigma + rng.normal(0.0, sigma, n // 2)]
    torque = np.r_[np.zeros(n // 2), np.full(n // 2, 3e-4)]
    out = np.full(n, -0.05)
    columns = (t, torque, speed, out, np.full(n, np.nan), np.full(n, np.nan))
    batch = Estimator(config).process_batch(*columns, breakdown=False)
    node = Estimator(config)
    live = np.array([e.measured_loss_nm for e in (node.process(SyncedSample(*row))
                                                  for row in zip(*(np.asarray(c).tolist() for c in columns)))])
    np.testing.assert_array_equal(live, batch.measured_loss_nm)
    at_rest, turning = batch.measured_loss_nm[: n // 2], batch.measured_loss_nm[n // 2:]
    assert np.count_nonzero(np.isfinite(at_rest)) <= 0.005 * len(at_rest), np.count_nonzero(np.isfinite(at_rest))
    assert np.count_nonzero(np.isfinite(turning)) >= 0.97 * len(turning)
    assert np.nanmean(turning) == pytest.approx(3e-4 + 0.05 / 288.0, rel=0.02)


@pytest.mark.parametrize(("law", "params"), [("load_dependent", {"c": 0.08, "q": 1.3}),
                                             ("load_dependent", {"c": 0.05, "q": 0.6}),
                                             ("load_speed", {"c": 4e-4, "p": 1.0}),
                                             ("backdrive", {"c": 0.2, "q": 1.0})])
def test_a_law_in_the_load_takes_the_output_side_load_not_the_drive_torque(law, params):
    """Operating points made from the output side: a load ``T_load`` and a speed give the drive torque
    ``T = T_load + sgn ω·(drag + law(|T_load|))`` (the paper's model off).  Fed the drive torque alone,
    as a node without an output sensor is, the estimator's loss is the drag plus the law at ``T_load`` --
    under a light load, where the drive torque is mostly the loss, as under a heavy one, motoring and
    back-driven."""
    config = with_effect(with_effect(load_config().with_values({"estimator.paper_model": False,
                                                                "estimator.speed_noise_rad_s": 0.0}),
                                     "drag_constant", {"c": 1.5}), law, params)
    load = np.array([-60.0, -5.0, -0.3, 0.0, 0.25, 4.0, 60.0, 60.0, -60.0])
    speed = np.array([30.0, 30.0, 30.0, 30.0, 30.0, -30.0, 200.0, -200.0, -200.0])
    s = np.sign(speed)
    x = EffectInputs(np.abs(load), np.abs(speed), load, s, abs_load=np.abs(load))
    drive = load + s * (1.5 + EFFECTS[law].term(x._replace(torque=load + s * 1.5), **params))
    # backdrive's condition is the drive torque's: the point above, re-made at its own drive torque
    if law == "backdrive":
        drive = load + s * (1.5 + EFFECTS[law].term(x._replace(torque=drive), **params))
    est = Estimator(config, operating_points=True)
    b = est.process_batch(np.arange(len(load), dtype=np.int64), drive, speed)
    truth = drive - load
    np.testing.assert_allclose(b.loss_torque_nm, truth, rtol=1e-11, atol=1e-12)
    # the drive torque taken as the load instead would miss by the law's slope times the loss
    wrong = s * (1.5 + EFFECTS[law].term(EffectInputs(np.abs(drive), np.abs(speed), drive, s,
                                                     abs_load=np.abs(drive)), **params))
    assert np.max(np.abs(wrong - truth)) > 1e-3
