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
