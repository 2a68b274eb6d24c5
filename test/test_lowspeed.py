"""Friction near standstill: the smooth sign of the estimator, low-speed samples in the analysis,
and the ``stribeck`` effect, on a spin test written as a CSV with a constant output torque.

The joint's friction is computed here, from its own formula (not the effect registry's): a Coulomb
level, a Stribeck excess and a viscous term, each opposing rotation, measured through a drive
torque sensor with noise.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from rollergear_ros.estimator import Estimator
from rollergear_ros.params import load_config

from helpers import run_cli

JOINT = "/**/loss_estimator:\n  ros__parameters:\n    estimator: {paper_model: false, speed_noise_rad_s: 0.005}\n"


def spin_test_csv(tmp_path, stribeck: bool, seed: int = 0, name: str = "spin"):
    """A joint driven back and forth at low speeds with nothing on its output: dwells at ±0.08 …
    5 rad/s, the drive torque all friction (Fc 0.30 N·m, Fs − Fc 0.25 N·m at ω_s 0.15 rad/s,
    Gaussian, viscous 0.01 N·m/(rad/s)), 1 kHz noise on torque and speed."""
    rng = np.random.default_rng(seed)
    levels = [0.08, 0.1, 0.13, 0.17, 0.22, 0.3, 0.4, 0.6, 1.0, 1.5, 2.5, 5.0]
    rate, dwell = 200.0, 1.5
    w = np.concatenate([np.full(int(rate * dwell), d * v) for _ in range(2) for v in levels for d in (1, -1)])
    t = np.arange(len(w)) / rate
    fc, excess, ws, visc = 0.30, 0.25 if stribeck else 0.0, 0.15, 0.01
    friction = (fc + excess * np.exp(-(np.abs(w) / ws) ** 2) + visc * np.abs(w)) * np.sign(w)
    torque = friction + rng.normal(0, 0.005, len(w))
    speed = w + rng.normal(0, 0.005, len(w))
    path = tmp_path / f"{name}.csv"
    path.write_text("t,T,w\n" + "".join(f"{a:.4f},{b:.6f},{c:.6f}\n" for a, b, c in zip(t, torque, speed)))
    cmap = tmp_path / "spin.yaml"
    cmap.write_text("time: {column: t, unit: s}\nmotor_torque: {column: T, unit: N*m}\n"
                    "motor_speed: {column: w, unit: rad/s}\noutput_torque: {constant: 0, unit: N*m}\n")
    params = tmp_path / "joint.yaml"  # a joint (no ball track), its speed reading's noise
    params.write_text(JOINT)
    return path, cmap, params


def test_a_joints_stribeck_friction_is_found_on_a_spin_test_csv(tmp_path):
    csv, cmap, params = spin_test_csv(tmp_path, stribeck=True)
    out = tmp_path / "cal.yaml"
    result = json.loads(run_cli("calibrate", str(csv), "--channels", str(cmap), "--params", str(params), "--json",
                                "--out", str(out)).stdout)
    found = {e["name"]: e for e in result["effects"]}
    assert "stribeck" in found and "torque_offset" not in found, sorted(found)
    s = found["stribeck"]
    assert s["ci95"]["c"][0] <= 0.25 <= s["ci95"]["c"][1], s
    assert s["ci95"]["omega_s"][0] <= 0.15 <= s["ci95"]["omega_s"][1], s
    assert found["drag_constant"]["params"]["c"] == pytest.approx(0.30, rel=0.05)
    assert result["error_after"]["rmse_nm"] < 0.2 * result["error_before"]["rmse_nm"]
    # the file on another run of the joint: the friction it predicts near standstill
    csv2, _, _ = spin_test_csv(tmp_path, stribeck=True, seed=1, name="spin2")
    replayed = run_cli("replay", str(csv2), "--channels", str(cmap), "--params", str(out), "--no-png").stdout
    rms = float(next(ln for ln in replayed.splitlines() if "residual" in ln and "RMS" in ln).split("RMS")[1]
                .split()[0])
    assert rms < 0.02, replayed


def test_a_coulomb_joint_gets_no_stribeck_term(tmp_path):
    csv, cmap, params = spin_test_csv(tmp_path, stribeck=False)
    result = json.loads(run_cli("calibrate", str(csv), "--channels", str(cmap), "--params", str(params),
                                "--json").stdout)
    found = {e["name"] for e in result["effects"]}
    assert "stribeck" not in found and "drag_constant" in found, found


def test_the_estimators_loss_torque_runs_smoothly_through_standstill():
    """The loss torque's sign is tanh(ω/width) near standstill (width 3 × the speed noise); beyond a
    few widths it is the sign; no jump through 0 (a speed reading of exactly 0, at rest: sign(T))."""
    from rollergear_ros.operating_points import evaluate_points

    config = load_config().with_values({"estimator.speed_noise_rad_s": 0.01})
    assert Estimator(config).sign_width_rad_s == pytest.approx(0.03)
    w = np.linspace(-0.3, 0.3, 601)
    t = np.full_like(w, 20.0)
    loss = evaluate_points(config.with_values({"effects.drag_constant.enabled": True,
                                               "effects.drag_constant.c_nm": 0.2}), t, w).loss_torque_nm
    moving = w != 0  # at rest (a speed of exactly 0) the loss opposes the drive torque, as before
    assert np.max(np.abs(np.diff(loss[moving]))) < 0.02  # 1 mrad/s steps: no jump of 2 × 0.2 N·m
    assert loss[~moving][0] > 0.2  # T = 20 N·m > 0 at rest
    far = np.abs(w) > 0.25
    magnitude = np.abs(loss[far])
    np.testing.assert_allclose(loss[far], np.sign(w[far]) * magnitude)
    np.testing.assert_allclose(loss[w == 0.1], magnitude.mean() * np.tanh(0.1 / 0.03), rtol=1e-3)
