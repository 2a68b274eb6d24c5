"""The simulator's oil: viscosity laws written out independently of the effect the calibrator fits."""

from __future__ import annotations

import numpy as np
import pytest

from rollergear_ros.core.model import LossModel
from rollergear_ros.core.params import load_config
from rollergear_ros.calibration.simulate import (DeclaredEffect, SimulationOptions, oil_viscosity_ratio, simulate,
                                                 vogel_viscosity_ratio, walther_viscosity_mm2_s, warmup)

from helpers import run_cli


def test_the_astm_d341_line_passes_through_the_data_sheet_points():
    nu = walther_viscosity_mm2_s(np.array([40.0, 100.0]), 136.0, 14.5)
    np.testing.assert_allclose(nu, [136.0, 14.5], rtol=1e-12)
    # the shared data's PROVENANCE.md: Mobilube HD 80W-90 gives ~26 mm²/s at 80 °C
    assert walther_viscosity_mm2_s(80.0, 136.0, 14.5) == pytest.approx(26.0, abs=0.5)
    # dynamic viscosity: the density falls as the oil warms, so η falls faster than ν
    assert oil_viscosity_ratio(85.0, 136.0, 14.5) < walther_viscosity_mm2_s(85.0, 136.0, 14.5) / 136.0


@pytest.mark.parametrize("oil", [None, (220.0, 25.2)])
def test_the_rig_loss_is_the_whole_model_at_the_oils_viscosity(oil):
    """The rig evaluates eq. 1–30 at η(θ) per sample; the estimator's factored model scales only its
    Fr part by (η/η0)^0.66 -- the two must agree, or one of them treats the viscosity wrongly."""
    config = load_config()
    effects = [] if oil else [DeclaredEffect("viscosity_temperature", {"B": 1100.0, "C": 130.0, "theta_ref": 40.0})]
    rig = simulate(config, SimulationOptions(profile="warmup", rate_hz=20.0, effects=effects,
                                             oil_nu40_nu100_mm2_s=oil))
    prof = warmup(20.0)  # the profile's true temperatures (the rig's are measured, with noise)
    ratio = (oil_viscosity_ratio(prof.temperature_c, *oil) if oil
             else vogel_viscosity_ratio(prof.temperature_c, 1100.0, 130.0, 40.0))
    factored = LossModel(config.gearbox).loss_magnitude(prof.torque_nm, prof.speed_rad_s, ratio ** 0.66)
    np.testing.assert_allclose(rig.loss_true_nm, factored, rtol=1e-12)
    assert np.ptp(prof.temperature_c) > 60.0 and ratio.max() / ratio.min() > 5.0  # a warm-up that matters
    assert not np.allclose(rig.loss_true_nm, rig.model_loss_nm, rtol=0.05)


@pytest.mark.parametrize(("value", "message"), [
    ("220", "--oil takes NU40,NU100"), ("25,220", "an oil is thinner when warm"),
    ("220,x", "--oil takes NU40,NU100"), ("nan,1", "oil_nu40_mm2_s' = nan is invalid: must be a finite number")])
def test_a_bad_oil_is_one_line(tmp_path, value, message):
    proc = run_cli("simulate", "--out", str(tmp_path / "x.mcap"), "--oil", value, check=False)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and message in proc.stderr, proc.stderr
    assert not (tmp_path / "x.mcap").exists()


def test_simulate_duration_repeats_the_profile_with_its_seed_advancing(tmp_path):
    """``--duration`` longer than the profile (rig_map: 50.4 s) makes what it says: 250 s of
    samples on one regular clock, read back by two readers; the profile runs again with the next seed (the
    same operating points, other noise), the last pass cut; a shorter one cuts; a negative one is one error."""
    from bagtools import float_series, read_mcap_ros2, read_rosbags

    out = tmp_path / "long.mcap"
    said = run_cli("simulate", "--rate", "20", "--duration", "250", "--out", str(out),
                   "--start", "2026-01-01T00:00:00").stdout
    assert "250.0 s at 20 Hz" in said and "the profile 5 times, seeds 0…4" in said, said
    for read in (read_mcap_ros2, read_rosbags):
        t, speed = float_series(read(out), "/rollergear/motor/speed")
        assert len(t) == 250 * 20 + 1 and set(np.diff(t).tolist()) == {50_000_000}, (len(t), set(np.diff(t)))
    once = simulate(load_config(), SimulationOptions(rate_hz=20.0))
    n = len(once.t_ns)
    np.testing.assert_array_equal(speed[:n], once.speed_rad_s)
    second = simulate(load_config(), SimulationOptions(rate_hz=20.0, seed=1))
    np.testing.assert_array_equal(speed[n:2 * n], second.speed_rad_s)
    assert not np.array_equal(speed[n:2 * n], speed[:n])
    short = run_cli("simulate", "--rate", "20", "--duration", "30", "--out", str(tmp_path / "short.mcap")).stdout
    assert "30.0 s at 20 Hz" in short and "times" not in short, short
    bad = run_cli("simulate", "--duration", "-5", "--out", str(tmp_path / "bad.mcap"), check=False)
    assert bad.returncode == 2 and bad.stderr.strip().splitlines() == [
        "rollergear: error: --duration must be a positive number of seconds, not -5.0"], bad.stderr


def test_a_long_simulation_is_written_in_the_memory_of_one_pass(tmp_path):
    """Ten passes of the profile hold no more memory at their peak than one: each pass is written as it is
    made (the time-ordered writer releases what is older than the next), so a week costs what a pass does."""
    import tracemalloc

    from rollergear_ros.calibration.simulate import write_simulation

    opts = SimulationOptions(rate_hz=200.0)
    peaks = []
    for passes in (1, 10):
        tracemalloc.start()
        written = write_simulation(load_config(), opts, tmp_path / f"p{passes}.mcap", passes * 50.0)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        assert written.repeats == passes and written.samples == passes * 50 * 200 + 1
    assert peaks[1] < 1.3 * peaks[0], peaks
