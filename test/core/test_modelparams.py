"""Calibrating the paper model's own parameters (modelparams.py, selection, calibrate).

Recordings come from the full physics -- the literal chain of eq. 1-30 (``model.reference_terms``)
at the *true* parameters, which the parameter file calibrate reads does not hold -- not from the
calibrator's factored parts.  Each case: the parameter within its interval of the truth, no
spurious effect, and the calibrated file's estimator predicting the true loss over a speed x
torque (x temperature) grid within 3 %.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from rollergear_ros.calibration.calibrate import calibrate, load_samples
from rollergear_ros.core.model import reference_terms
from rollergear_ros.core.modelparams import MODEL_PARAMETERS, fitted_parameters
from rollergear_ros.core.operating_points import evaluate_points
from rollergear_ros.core.params import config_to_yaml, load_config
from rollergear_ros.replay.run import replay
from rollergear_ros.calibration.simulate import (DeclaredEffect, SimulationOptions, simulate, vogel_viscosity_ratio,
                                                write_rig_bag)

from helpers import run_cli


def rig(tmp_path, truth: dict, name: str, profile: str = "bidirectional_map", effects=(), seed: int = 1,
        rate: float = 200.0):
    """A recording of a gearbox whose parameters are ``truth`` (the file calibrate reads: the defaults)."""
    config = load_config().with_values(truth)
    opts = SimulationOptions(profile=profile, rate_hz=rate, seed=seed, effects=list(effects))
    path = tmp_path / f"{name}_{seed}.mcap"
    write_rig_bag(simulate(config, opts), opts, path)
    return path, config


def true_loss(config, torque, speed, eta_ratio=1.0, extra=0.0):
    return reference_terms(config.gearbox, torque, speed, config.gearbox.eta0_pa_s * eta_ratio)["T_loss"] + extra


def grid(speeds=(30.0, 80.0, 150.0, 250.0), torques=(10.0, 30.0, 60.0, 90.0)):
    w, t = np.meshgrid(np.asarray(speeds), np.asarray(torques), indexing="ij")
    return t.ravel(), w.ravel()


def calibrate_file(tmp_path, *bags):
    out = tmp_path / "cal.yaml"
    proc = run_cli("calibrate", *map(str, bags), "--json", "--out", str(out))
    return json.loads(proc.stdout), load_config(out)


def test_the_table_names_parameters_of_the_parameter_file_with_a_part_of_the_model_each():
    from rollergear_ros.core.model import LossModel
    from rollergear_ros.core.paramspecs import spec_by_name

    parts = LossModel(load_config().gearbox).parts(np.array([10.0]), np.array([100.0]))
    for key, p in MODEL_PARAMETERS.items():
        spec = spec_by_name()[key]  # a real parameter-file key
        assert spec.low <= p.low < p.high <= spec.high, key
        assert p.part in parts and p.tells_apart
        v = 0.5 * (p.low + p.high)
        assert p.value(v, 0.0) == pytest.approx(v)  # no change: the file's value
        assert p.factor(p.value(v, -0.1)) == pytest.approx(0.9 * p.factor(v))  # the part by 0.9
    assert set(fitted_parameters()) == {"gearbox.eta0_pa_s", "gearbox.mu_m", "gearbox.mu_b"}
    assert MODEL_PARAMETERS["gearbox.Y"].same_part_as == "gearbox.mu_m"


@pytest.mark.parametrize(("truth", "key", "value"), [
    ({"gearbox.mu_m": 0.06}, "gearbox.mu_m", 0.06),  # the paper only assumed 0.1
    ({"gearbox.eta0_pa_s": 0.13}, "gearbox.eta0_pa_s", 0.13),  # an oil thicker than its data sheet
    ({"gearbox.eta0_pa_s": 0.08}, "gearbox.eta0_pa_s", 0.08),
])
def test_a_parameter_that_is_off_is_found_within_its_interval_and_nothing_else(tmp_path, truth, key, value):
    bag, true = rig(tmp_path, truth, key.split(".")[1])
    result, cal = calibrate_file(tmp_path, bag)
    assert result["verdict"] == "effects_found" and result["effects"] == [], result["log"] if "log" in result else ""
    [found] = result["parameters"]
    assert found["name"] == key and found["file"] == pytest.approx(load_config().to_flat()[key])
    assert found["ci95"][0] <= value <= found["ci95"][1], found
    assert found["fitted"] == pytest.approx(value, rel=0.03)
    assert cal.to_flat()[key] == pytest.approx(found["fitted"])  # written into the gearbox's key
    torque, speed = grid()
    got = evaluate_points(cal, torque, speed).loss_magnitude_nm
    np.testing.assert_allclose(got, true_loss(true, torque, speed), rtol=0.03)
    assert result["error_after"]["rmse_nm"] < 0.3 * result["error_before"]["rmse_nm"]


def test_a_parameter_that_is_off_and_a_drag_nobody_declared_are_both_found(tmp_path):
    drag = 0.05
    bag, true = rig(tmp_path, {"gearbox.mu_m": 0.06}, "mu_drag", effects=[DeclaredEffect("drag_constant", {"c": drag})])
    result, cal = calibrate_file(tmp_path, bag)
    assert [e["name"] for e in result["effects"]] == ["drag_constant"]
    lo, hi = result["effects"][0]["ci95"]["c"]
    assert lo <= drag <= hi
    [found] = result["parameters"]
    assert found["name"] == "gearbox.mu_m" and found["ci95"][0] <= 0.06 <= found["ci95"][1]
    torque, speed = grid()
    np.testing.assert_allclose(evaluate_points(cal, torque, speed).loss_magnitude_nm,
                               true_loss(true, torque, speed, extra=drag), rtol=0.03)


OILS = [(0.117, 95.0, 900.0), (0.13, 70.0, 600.0), (0.08, 140.0, 1500.0), (0.16, 110.0, 1100.0)]


@pytest.mark.parametrize(("eta_ref", "c_k", "b_k"), OILS, ids=lambda v: f"{v:g}")
def test_an_oil_whose_reference_viscosity_is_not_eta0_is_its_law_and_its_level(tmp_path, eta_ref, c_k, b_k):
    """A warm-up from 20 to 85 °C with an oil of another viscosity at 40 °C than the file's eta0:
    the viscosity law's level is the parameter eta0 (= eta(40 °C)), its shape viscosity_temperature;
    no load friction takes the rest (it used to: load_dependent q = 0.55, the shape of Fr)."""
    vogel = {"B": b_k, "C": c_k, "theta_ref": 40.0}
    bag, true = rig(tmp_path, {"gearbox.eta0_pa_s": eta_ref}, "oil", profile="warmup",
                    effects=[DeclaredEffect("viscosity_temperature", vogel)])
    result, cal = calibrate_file(tmp_path, bag)
    assert [e["name"] for e in result["effects"]] == ["viscosity_temperature"], result["effects"]
    [found] = result["parameters"]
    assert found["name"] == "gearbox.eta0_pa_s" and found["ci95"][0] <= eta_ref <= found["ci95"][1], found
    torque, speed = grid(speeds=(50.0, 120.0, 200.0), torques=(20.0, 50.0, 90.0))
    for theta in (25.0, 40.0, 60.0, 80.0):
        got = evaluate_points(cal, torque, speed, theta).loss_magnitude_nm
        want = true_loss(true, torque, speed, vogel_viscosity_ratio(theta, b_k, c_k, 40.0))
        np.testing.assert_allclose(got, want, rtol=0.03, err_msg=f"{theta} °C")


@pytest.mark.slow
def test_the_papers_values_exactly_change_and_add_nothing_over_20_seeds(tmp_path):
    config = load_config()
    for seed in range(20):
        profile = ("bidirectional_map", "rig_map", "warmup")[seed % 3]
        bag, _ = rig(tmp_path, {}, "exact", profile=profile, seed=seed, rate=100.0)
        res = calibrate(load_samples([bag], config), config)
        assert res.verdict == "no_missing_effect", (seed, res.log)
        assert res.effects == [] and res.parameters == [], (seed, res.log)


def test_the_claimed_error_is_the_written_files_on_another_recording_of_the_same_gearbox(tmp_path):
    """What calibrate claims after is what the file it wrote does: replayed (adaptation off) on a
    second recording of the same gearbox, the residual is the claimed held-out error within its noise."""
    truth = {"gearbox.mu_m": 0.07}
    drag = [DeclaredEffect("drag_speed", {"c": 3e-4, "p": 1.4})]
    bag, _ = rig(tmp_path, truth, "claim", effects=drag, seed=1)
    other, _ = rig(tmp_path, truth, "claim", effects=drag, seed=2)
    result, cal = calibrate_file(tmp_path, bag)
    assert result["written"] and {p["name"] for p in result["parameters"]} == {"gearbox.mu_m"}
    replayed, _ = replay(other, cal.with_values({"estimator.adapt": False}), show_progress=False)
    claimed = result["sample_level_errors"]["after"]["rmse_nm"]  # per sample: the replay's residual is per sample
    assert replayed.residual_rms_nm == pytest.approx(claimed, rel=0.15)
    uncalibrated, _ = replay(other, load_config(), show_progress=False)
    assert uncalibrated.residual_rms_nm > 3 * replayed.residual_rms_nm


def test_a_loss_only_negative_frictions_would_explain_gets_no_file_and_one_line(tmp_path):
    """A gearbox losing less than anything the vocabulary writes as a loss (here: an output torque
    that reads high, so the measured loss is below the model's everywhere and often below 0):
    no negative friction is written, the paper's model off does no better, nothing is written."""
    config = load_config()
    opts = SimulationOptions(profile="bidirectional_map", rate_hz=100.0, seed=4)
    sim = simulate(config, opts)
    sim.out_torque_meas_nm = sim.out_torque_meas_nm + 0.4 * sim.ratio * np.sign(sim.speed_rad_s)
    bag = tmp_path / "negative.mcap"
    write_rig_bag(sim, opts, bag)
    out = tmp_path / "cal.yaml"
    proc = run_cli("calibrate", str(bag), "--out", str(out), check=False)
    result = json.loads(run_cli("calibrate", str(bag), "--json", check=False).stdout)
    assert not any(e["name"] in ("drag_constant", "drag_speed", "load_dependent", "load_speed") and
                   min(e["ci95"]["c"]) < 0 for e in result["effects"])
    written = [e["name"] for e in result["effects"] if "friction" in e["name"] or "drag" in e["name"]]
    assert written == [] and result["parameters"] == [] or not result["written"], result
    assert "needs a negative friction" in proc.stdout
    if not result["written"]:
        assert proc.returncode == 1 and not out.exists() and "not written" in proc.stdout


def test_a_calibration_that_would_predict_worse_than_the_file_is_not_written():
    from rollergear_ros.calibration.written import not_written_because
    from rollergear_ros.calibration.selection import ErrorStats

    def err(rmse):
        return ErrorStats(rmse, rmse, rmse, 10 * rmse)

    assert not_written_because(err(0.31), err(0.33), anything_changed=True) is not None
    assert "no better than the parameter file as given (RMSE 0.33 >= 0.31 N·m)" in not_written_because(
        err(0.31), err(0.33), True)
    assert not_written_because(err(0.31), err(0.2), anything_changed=True) is None
    # nothing changed: the file as it was
    assert not_written_because(err(0.31), err(0.31), anything_changed=False) is None


def test_parameters_are_in_the_json_contract_and_the_text_and_the_files_comments(tmp_path):
    bag, _ = rig(tmp_path, {"gearbox.eta0_pa_s": 0.13}, "eta", rate=100.0)
    result, _ = calibrate_file(tmp_path, bag)
    [p] = result["parameters"]
    assert set(p) >= {"name", "file", "fitted", "ci95"} and p["name"] == "gearbox.eta0_pa_s"
    text = run_cli("calibrate", str(bag), "--out", str(tmp_path / "c2.yaml")).stdout
    assert "oil viscosity at the reference temperature (gearbox.eta0_pa_s): 0.1" in text and "(file 0.1;" in text
    written = (tmp_path / "c2.yaml").read_text()
    assert "# gearbox.eta0_pa_s: 0.1" in written and "(was 0.1), calibrated" in written
    assert p["ci95"][0] <= 0.13 <= p["ci95"][1]
    assert math.isclose(load_config(tmp_path / "c2.yaml").gearbox.eta0_pa_s, p["fitted"], rel_tol=1e-5)
    assert "residual_structure" in result and result["residual_structure"]["statement"]
    assert config_to_yaml(load_config(tmp_path / "c2.yaml"))  # a file the node and replay accept


def test_a_loss_the_vocabulary_lacks_is_traced_by_the_residuals_structure(tmp_path):
    """A loss that appears above 60 °C only (a seal lip that swells: no law of the vocabulary) in a
    warm-up, where time and temperature rise together: calibrate finds a change where the oil passed
    60 °C and says that this recording cannot tell a change in time from a loss that follows the oil;
    analysed at once (``--segments off``) the residual's structure points at the oil temperature."""
    config = load_config()
    opts = SimulationOptions(profile="warmup", rate_hz=100.0, seed=2)
    sim = simulate(config, opts)
    hot = sim.temperature_c > 60.0
    sim.out_torque_meas_nm = sim.out_torque_meas_nm - sim.ratio * 0.08 * hot * np.sign(sim.speed_rad_s)
    bag = tmp_path / "hot.mcap"
    write_rig_bag(sim, opts, bag)
    split = json.loads(run_cli("calibrate", str(bag), "--json", check=False).stdout)
    [change] = split["changes"]
    t_hot = (sim.t_ns[np.argmax(hot)] - sim.t_ns[0]) * 1e-9
    assert abs(change["t_s"] - t_hot) < 2.0, (change, t_hot)
    assert change["temperature_c"] == pytest.approx(60.0, abs=2.0) and "follows the oil" in " ".join(split["notes"])
    report = tmp_path / "report"
    result = json.loads(run_cli("calibrate", str(bag), "--json", "--segments", "off", "--report", str(report),
                                check=False).stdout)
    structure = result["residual_structure"]
    assert structure["strongest"] == "temperature", structure
    assert structure["explained_share"]["temperature"] > 0.3
    assert (report / "residual_structure.png").exists()
    assert "depends most on temperature" in (report / "report.md").read_text()


def test_a_known_oil_starts_the_viscosity_law_from_its_data_sheet(tmp_path):
    """An axle oil (ν40 136, ν100 14.5 mm²/s: the shared data sheet) warming from 20 to 85 °C, its
    viscosity at 40 °C 0.12 Pa·s where the file says 0.1: with ``--oil`` the law starts from the data
    sheet's (ASTM D341) and stays near it; the level is eta0; the file predicts the loss within 3 %."""
    from rollergear_ros.core.oil import oil_viscosity_ratio

    config = load_config().with_values({"gearbox.eta0_pa_s": 0.12})
    opts = SimulationOptions(profile="warmup", rate_hz=100.0, seed=6, oil_nu40_nu100_mm2_s=(136.0, 14.5))
    bag = tmp_path / "axle_oil.mcap"
    write_rig_bag(simulate(config, opts), opts, bag)
    out = tmp_path / "cal.yaml"
    result = json.loads(run_cli("calibrate", str(bag), "--oil", "136,14.5,900", "--json", "--out", str(out)).stdout)
    assert [e["name"] for e in result["effects"]] == ["viscosity_temperature"]
    [eta] = result["parameters"]
    assert eta["name"] == "gearbox.eta0_pa_s" and eta["ci95"][0] <= 0.12 <= eta["ci95"][1]
    cal = load_config(out)
    torque, speed = grid(speeds=(50.0, 120.0, 200.0), torques=(20.0, 50.0, 90.0))
    for theta in (25.0, 40.0, 60.0, 80.0):
        np.testing.assert_allclose(evaluate_points(cal, torque, speed, theta).loss_magnitude_nm,
                                   true_loss(config, torque, speed, oil_viscosity_ratio(theta, 136.0, 14.5)),
                                   rtol=0.03, err_msg=f"{theta} °C")
    proc = run_cli("calibrate", str(bag), "--oil", "14.5,136", check=False)
    assert proc.returncode == 2 and "an oil is thinner when warm" in proc.stderr


def churning_warmup(tmp_path, seed: int, c=3e-4, a=0.5, p=1.5, b_k=900.0, c_k=95.0):
    """A warm-up (20 → 85 °C) whose oil follows Vogel B, C: the model's rolling part at η(θ) (the
    simulator's full model) and a churning drag computed here from the viscosity law directly,
    ``c·(η(θ)/η(40))^a·|ω|^p``, put into the measured output torque."""
    config = load_config()
    law = {"B": b_k, "C": c_k, "theta_ref": 40.0}
    opts = SimulationOptions(profile="warmup", rate_hz=100.0, seed=seed,
                             effects=[DeclaredEffect("viscosity_temperature", law)])
    sim = simulate(config, opts)
    theta = sim.temperature_c  # as measured (the churning follows the oil's real temperature, near enough)
    eta_ratio = np.exp(b_k / (theta + c_k) - b_k / (40.0 + c_k))
    churn = c * eta_ratio ** a * np.abs(sim.speed_rad_s) ** p
    sim.out_torque_meas_nm = sim.out_torque_meas_nm - sim.ratio * churn * np.sign(sim.speed_rad_s)
    bag = tmp_path / f"churn_{seed}.mcap"
    write_rig_bag(sim, opts, bag)
    return bag


def test_churning_that_follows_the_oil_is_found_with_its_law(tmp_path):
    """A churning drag that follows the oil's viscosity (thick cold oil churns harder): found as
    drag_viscous beside the viscosity law, its exponents within their intervals; the file cuts the
    error on another recording of the same gearbox by >= 80 % (a fixed speed drag cut it by 65 %)."""
    result, cal = calibrate_file(tmp_path, churning_warmup(tmp_path, 1))
    found = {e["name"]: e for e in result["effects"]}
    assert set(found) == {"viscosity_temperature", "drag_viscous"}, sorted(found)
    churn = found["drag_viscous"]
    for key, true in (("p", 1.5), ("a", 0.5), ("c", 3e-4)):
        lo, hi = churn["ci95"][key]
        assert lo <= true <= hi, (key, churn["params"][key], churn["ci95"][key])
    assert churn["params"]["B"] == found["viscosity_temperature"]["params"]["B"]  # the calibrated oil's law
    other = churning_warmup(tmp_path, 2)
    after, _ = replay(other, cal.with_values({"estimator.adapt": False}), show_progress=False)
    before, _ = replay(other, load_config(), show_progress=False)
    assert after.residual_rms_nm < 0.2 * before.residual_rms_nm


def test_at_one_temperature_no_drag_follows_the_oil(tmp_path):
    bag, _ = rig(tmp_path, {}, "drag", effects=[DeclaredEffect("drag_speed", {"c": 3e-4, "p": 1.5})], rate=100.0)
    result, _ = calibrate_file(tmp_path, bag)
    assert [e["name"] for e in result["effects"]] == ["drag_speed"]
    assert "drag_viscous" in result["unavailable"]
