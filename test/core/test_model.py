"""The loss model: reference values, breakdown, and properties (the equations: test_equations.py)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rollergear_ros.core import model as m
from rollergear_ros.core.params import GearboxParams, validate

W_1000 = 104.72

# model-spec.md, computed independently of the project
REFERENCE = [(1, 0.02129, 97.871), (10, 0.06783, 99.322), (50, 0.21084, 99.578), (100, 0.43082, 99.569)]


def sig4(x: float) -> str:
    return f"{x:.4g}"


@pytest.mark.parametrize("torque, loss, eta_pct", REFERENCE)
def test_reference_values_to_four_significant_figures(torque, loss, eta_pct):
    lm = m.LossModel(GearboxParams())
    res = lm.evaluate(np.array([torque]), np.array([W_1000]))
    assert sig4(res.loss_magnitude_nm[0]) == sig4(loss)
    assert sig4(100 * res.efficiency[0]) == sig4(eta_pct)
    # the literal equation chain gives the same
    assert sig4(m.evaluate_reference(GearboxParams(), torque, W_1000)["T_loss"]) == sig4(loss)


def test_breakdown_sums_to_total_and_names_every_term():
    lm = m.LossModel(replace(GearboxParams(), Fg_n=3.0))  # make Tb and Fg non-zero too
    t = np.linspace(-100, 100, 41)
    w = np.linspace(-300, 300, 41)
    res = lm.evaluate(t, w)
    assert set(res.breakdown_nm) == set(m.BREAKDOWN_KEYS)
    total = sum(res.breakdown_nm.values())
    np.testing.assert_allclose(total, res.loss_magnitude_nm, rtol=1e-12)
    assert all(np.all(v >= 0) for v in res.breakdown_nm.values())
    assert res.breakdown_nm["tb"][0] > 0 and res.breakdown_nm["fg"][0] > 0


@pytest.mark.parametrize("params", [
    GearboxParams(),
    replace(GearboxParams(), dw_m=0.001, Fg_n=10.0, beta_deg=15.0),
    replace(GearboxParams(), dm1_m=0.3, dm2_m=0.41, alpha_deg=35.0, f1=0.52, f2=0.56, internal_ratio=9.0),
    replace(GearboxParams(), eta0_pa_s=1.0, z=12, mu_m=0.2, Y=0.5),
])
def test_fast_model_equals_literal_equation_chain(params):
    lm = m.LossModel(params)
    rng = np.random.default_rng(1)
    for t, w in zip(rng.uniform(-200, 200, 30), rng.uniform(-500, 500, 30)):
        ref = m.evaluate_reference(params, t, w)
        fast = lm.evaluate(np.array([t]), np.array([w]))
        assert fast.loss_magnitude_nm[0] == pytest.approx(ref["T_loss"], rel=1e-12)
        assert lm.loss_magnitude_scalar(t, w) == pytest.approx(ref["T_loss"], rel=1e-12)


def test_efficiency_four_quadrants_and_undefined_points():
    lm = m.LossModel(GearboxParams(), min_torque_for_efficiency_nm=0.2, min_speed_for_efficiency_rad_s=0.5)
    t = np.array([10.0, -10.0, 10.0, -10.0, 0.1, 10.0, 0.0])
    w = np.array([100.0, -100.0, -100.0, 100.0, 100.0, 0.1, 100.0])
    res = lm.evaluate(t, w)
    loss = res.loss_magnitude_nm
    assert res.efficiency[0] == pytest.approx((10 - loss[0]) / 10)  # motoring
    assert res.efficiency[1] == pytest.approx((10 - loss[1]) / 10)  # motoring in reverse
    assert res.efficiency[2] == pytest.approx(10 / (10 + loss[2]))  # regeneration
    assert res.efficiency[3] == pytest.approx(10 / (10 + loss[3]))
    assert np.isnan(res.efficiency[4:]).all()  # below min |T|, below min |w|, zero torque
    assert np.all(np.isfinite(res.loss_torque_nm))
    # signed loss opposes rotation; at standstill it opposes the torque
    assert np.sign(res.loss_torque_nm[:4]).tolist() == [1, -1, -1, 1]
    z = lm.evaluate(np.array([5.0]), np.array([0.0]))
    assert z.loss_torque_nm[0] > 0 and z.loss_power_w[0] == 0.0 and np.isnan(z.efficiency[0])


def test_loss_larger_than_motoring_torque_gives_nan_not_a_negative_efficiency():
    heavy = replace(GearboxParams(), Fg_n=500.0)  # constant loss ~ several N·m
    lm = m.LossModel(heavy)
    res = lm.evaluate(np.array([0.5]), np.array([100.0]))
    assert res.loss_magnitude_nm[0] > 0.5 and np.isnan(res.efficiency[0])


# ---------------------------------------------------------------- properties
torques = st.floats(-500, 500, allow_nan=False)
speeds = st.floats(-600, 600, allow_nan=False)


@st.composite
def gearboxes(draw):
    dw = draw(st.floats(0.001, 0.012))
    dm1 = draw(st.floats(dw * 2, 0.3))
    g = replace(GearboxParams(), dw_m=dw, dm1_m=dm1, dm2_m=dm1 * draw(st.floats(1.05, 2.0)),
                alpha_deg=draw(st.floats(5, 45)), f1=draw(st.floats(0.51, 0.58)), f2=draw(st.floats(0.51, 0.58)),
                eta0_pa_s=draw(st.floats(0.01, 1.0)), z=draw(st.integers(1, 12)), Fg_n=draw(st.floats(0, 5)))
    validate({f"gearbox.{k}": v for k, v in g.__dict__.items()})
    return g


@settings(max_examples=150, deadline=None)
@given(gearboxes(), torques, speeds)
def test_loss_finite_nonnegative_and_symmetric(g, t, w):
    lm = m.LossModel(g)
    res = lm.evaluate(np.array([t, -t, t, -t]), np.array([w, w, -w, -w]))
    mag = res.loss_magnitude_nm
    assert np.all(np.isfinite(mag)) and np.all(mag >= 0)
    # reverse rotation and regeneration: same loss magnitude
    assert np.allclose(mag, mag[0], rtol=1e-12)
    # signed: opposes the rotation (or, at standstill, the torque); with neither there is no
    # direction and the signed loss torque is 0 (the magnitude is the friction that would act)
    direction = (np.array([t, -t, t, -t]) != 0) | (np.array([w, w, -w, -w]) != 0)
    assert np.allclose(np.abs(res.loss_torque_nm), np.where(direction, mag, 0.0))
    eta = res.efficiency
    defined = ~np.isnan(eta)
    assert np.all((eta[defined] > 0) & (eta[defined] <= 1))
    # vectorised and per-sample paths agree
    s = lm.loss_magnitude_scalar(t, w)
    assert s == pytest.approx(mag[0], rel=1e-12, abs=1e-15)
    e_s = lm.efficiency_scalar(t, w, s)
    assert (math.isnan(e_s) and math.isnan(eta[0])) or e_s == pytest.approx(eta[0], rel=1e-12)


@settings(max_examples=150, deadline=None)
@given(gearboxes(), st.floats(0, 400), st.floats(0, 400), st.floats(0, 600), st.floats(0, 600))
def test_loss_rises_with_torque_and_speed(g, t1, t2, w1, w2):
    lm = m.LossModel(g)
    lo_t, hi_t = sorted((t1, t2))
    lo_w, hi_w = sorted((w1, w2))
    assert lm.loss_magnitude_scalar(hi_t, lo_w) >= lm.loss_magnitude_scalar(lo_t, lo_w)
    assert lm.loss_magnitude_scalar(lo_t, hi_w) >= lm.loss_magnitude_scalar(lo_t, lo_w)


def test_efficiency_nan_where_undefined_never_made_up():
    lm = m.LossModel(GearboxParams())
    res = lm.evaluate(np.array([0.0, 1e-9, 5.0]), np.array([100.0, 100.0, 0.0]))
    assert np.isnan(res.efficiency).all()
