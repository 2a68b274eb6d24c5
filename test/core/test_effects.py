"""The effect registry: each term is its formula, and a new effect is one entry.

``test_a_registered_toy_effect_flows_through_simulate_calibrate_and_replay`` registers an effect
the package has never heard of and sees it flow through the parameter file, ``simulate``,
``calibrate`` (found, fitted within its interval, written to the YAML) and ``replay`` (the
calibrated estimator removes it from the residual), with no other code touched.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from rollergear_ros.core import effects
from rollergear_ros.calibration.calibrate import calibrate, load_samples
from rollergear_ros.calibration.written import calibrated_yaml
from rollergear_ros.core.effects import _DRAWN_OVER, EFFECTS, Effect, EffectInputs, EffectParameter
from rollergear_ros.core.params import load_config
from rollergear_ros.core.paramspecs import parameter_specs
from rollergear_ros.replay.run import replay
from rollergear_ros.calibration.simulate import DeclaredEffect, SimulationOptions, simulate, write_rig_bag

ROOT = Path(__file__).resolve().parents[2]
X = EffectInputs(abs_torque=np.array([2.0, 40.0]), abs_speed=np.array([10.0, 200.0]), torque=np.array([2.0, -40.0]),
                 rot_sign=np.array([1.0, -1.0]), temperature_c=np.array([20.0, 80.0]), fr_part_nm=np.array([0.1, 0.3]),
                 abs_load=np.array([1.5, 41.0]))


@pytest.mark.parametrize(("name", "params", "expected"), [
    ("drag_constant", {"c": 0.04}, 0.04 + 0.0 * X.abs_speed),
    ("drag_speed", {"c": 3e-4, "p": 1.4}, 3e-4 * X.abs_speed ** 1.4),
    ("load_dependent", {"c": 2e-3, "q": 1.2}, 2e-3 * X.abs_load ** 1.2),
    ("load_speed", {"c": 2e-5, "p": 1.3}, 2e-5 * X.abs_load * X.abs_speed ** 1.3),
    ("backdrive", {"c": 3e-3, "q": 1.1}, 3e-3 * X.abs_load ** 1.1 * (X.torque * X.rot_sign < 0)),
    ("viscosity_temperature", {"B": 700.0, "C": 95.0, "theta_ref": 40.0, "scale": 1.0},
     X.fr_part_nm * (np.exp(700.0 / (X.temperature_c + 95.0) - 700.0 / 135.0) ** 0.66 - 1.0)),
    ("torque_offset", {"b": 0.05}, 0.05 * X.rot_sign),
    ("torque_gain", {"g": 0.01}, 0.01 * X.torque * X.rot_sign),
    ("stribeck", {"c": 0.25, "omega_s": 20.0, "delta": 2.0}, 0.25 * np.exp(-(X.abs_speed / 20.0) ** 2)),
    ("stribeck_direction", {"c": -0.1, "omega_s": 20.0, "delta": 1.5},
     -0.1 * np.exp(-(X.abs_speed / 20.0) ** 1.5) * X.rot_sign),
    ("drag_direction", {"c": -2e-4, "p": 1.2}, -2e-4 * X.abs_speed ** 1.2 * X.rot_sign),
    ("drag_viscous", {"c": 3e-4, "p": 1.5, "a": 0.5, "B": 900.0, "C": 95.0, "theta_ref": 40.0},
     3e-4 * np.exp(900.0 / (X.temperature_c + 95.0) - 900.0 / 135.0) ** 0.5 * X.abs_speed ** 1.5),
    ("dahl", {"c": 0.1, "presliding": 0.01}, 0.1 + 0.0 * X.abs_speed),  # no state: steady motion
])
def test_each_term_is_its_documented_formula(name, params, expected):
    np.testing.assert_allclose(EFFECTS[name].term(X, **params), expected, rtol=1e-12)
    # on Python floats too (the node's per-sample path)
    x0 = EffectInputs(*(float(v[0]) for v in X[:6]), abs_load=float(X.abs_load[0]))
    assert EFFECTS[name].term(x0, **params) == pytest.approx(float(np.asarray(expected)[0]), rel=1e-12)


def test_every_effect_is_declared_consistently():
    specs = {s.name for s in parameter_specs()}
    for name, e in EFFECTS.items():
        shorts = [p.short for p in e.parameters]
        assert e.coefficient in shorts and (e.member is None or e.member in shorts), name
        assert f"effects.{name}.enabled" in specs
        assert all(f"effects.{name}.{p.key}" in specs for p in e.parameters)
        assert all(other in EFFECTS for other in e.separated_from), name
        assert (e.state_step is None) == (e.state_steps is None), name  # memory: a step and its batch
        assert e.plotted_against in _DRAWN_OVER, name  # the report knows how to draw it
        if e.member is not None:
            lo, hi = e.member_bounds
            assert lo <= min(e.member_grid) < max(e.member_grid) <= hi, name
        # the term is linear in its coefficient: term = coefficient x column
        params = e.simulated_defaults()
        np.testing.assert_allclose(e.term(X, **{**params, e.coefficient: 2.5}), 2.5 * e.column(X, params),
                                   rtol=1e-12, atol=1e-300)


@pytest.mark.parametrize("name", [n for n, e in EFFECTS.items() if e.state_step is not None])
def test_a_state_batch_is_its_single_steps_bit_for_bit(name):
    """Replay's batches and calibrate step the state as the node does, sample by sample: the same
    floats, also across samples at rest and repeated times (no step)."""
    e = EFFECTS[name]
    rng = np.random.default_rng(0)
    speed = np.where(rng.random(2000) < 0.1, 0.0, rng.normal(0, 0.05, 2000))
    dt = np.where(rng.random(2000) < 0.05, 0.0, rng.uniform(1e-4, 1e-2, 2000))
    params = e.simulated_defaults()
    z, single = 0.3, []
    for w, d in zip(speed.tolist(), dt.tolist()):
        z = e.state_step(z, w, d, params)
        single.append(z)
    assert e.state_steps(0.3, speed, dt, params).tolist() == single
    assert len(set(np.sign(single[100:]).tolist())) == 2  # the state turned round within the batch


def test_the_dahl_state_follows_its_documented_law():
    """``z → s + (z − s)·exp(−|ω|·dt/presliding)``: a turn of one presliding angle from −1 forwards
    leaves ``1 − 2/e``; at rest nothing changes."""
    from rollergear_ros.core.effects import dahl_step

    p = {"presliding": 0.01}
    assert dahl_step(-1.0, 0.5, 0.02, p) == pytest.approx(1.0 - 2.0 / np.e, rel=1e-12)
    assert dahl_step(-0.4, 0.0, 1.0, p) == -0.4 and dahl_step(-0.4, 3.0, 0.0, p) == -0.4


def test_docs_table_is_the_registry():
    assert (ROOT / "docs" / "effects.md").read_text() == effects.markdown_table(), \
        "regenerate: python -m rollergear_ros.core.effects > docs/effects.md"


def speed_load(x: EffectInputs, c):
    """Speed-root-load friction: ``ΔT = c·|ω|·|T|^0.5`` (a toy effect for the registry test, unlike
    every effect of the registry)."""
    return c * x.abs_speed * x.abs_torque ** 0.5


@pytest.fixture
def toy_effect():
    effect = effects.register(Effect(
        "speed_load", speed_load, True, "add a speed-root-load friction c*|w|*|T|^0.5", "toy",
        (EffectParameter("c", "c", 0.0, "speed-load coefficient", simulated=2e-5),), coefficient="c",
        regressor_scale=lambda params: effects.SPEED_REF_RAD_S * effects.TORQUE_REF_NM ** 0.5))
    try:
        yield effect
    finally:
        effects.unregister("speed_load")


def test_a_registered_toy_effect_flows_through_simulate_calibrate_and_replay(toy_effect, tmp_path):
    config = load_config(ROOT / "config" / "gearbox.yaml")
    assert "effects.speed_load.c" in {s.name for s in parameter_specs()}
    # simulate: a rig with the new effect, declared by its short names
    opts = SimulationOptions(
        profile="rig_map", rate_hz=100.0, seed=3, effects=[DeclaredEffect.parse("speed_load:c=2e-4")]
    )
    bag = tmp_path / "toy.mcap"
    write_rig_bag(simulate(config, opts), opts, bag)
    # calibrate: found (not declared to it), coefficient within its interval
    result = calibrate(load_samples([bag], config), config)
    assert result.verdict == "effects_found", result.log
    found = {e.name: e for e in result.effects}
    assert "speed_load" in found, result.log
    lo, hi = found["speed_load"].ci95["c"]
    assert lo <= 2e-4 <= hi and hi - lo < 0.2 * 2e-4, found["speed_load"]
    assert result.error_after.rmse_nm < 0.2 * result.error_before.rmse_nm
    # the parameter file carries it, and replay with it leaves almost no residual
    yaml_path = tmp_path / "calibrated.yaml"
    yaml_path.write_text(calibrated_yaml(result, [str(bag)]))
    calibrated = load_config(yaml_path)
    assert "speed_load" in calibrated.effects.enabled()
    assert math.isclose(calibrated.effects.params("speed_load")["c"], found["speed_load"].params["c"])

    def residual_rms(cfg) -> float:
        _, batches = replay(bag, cfg, show_progress=False, collect=True)
        r = np.concatenate([b.residual_nm for b in batches])
        return float(np.sqrt(np.nanmean(r[len(r) // 2 :] ** 2)))  # after the RLS has settled

    before, after = residual_rms(config), residual_rms(calibrated)
    assert after < 0.2 * before, (before, after)


def test_interface_doc_names_every_effect_parameter_as_the_registry_does():
    lines = (ROOT / "docs" / "interface.md").read_text().splitlines()
    head = next(i for i, ln in enumerate(lines) if ln.strip().startswith("| effect | JSON / simulate |"))
    rows = {}
    for line in lines[head + 2:]:
        if not line.strip().startswith("|"):
            break
        name, short, keys = (c.strip() for c in line.strip().strip("|").split("|"))
        rows[name.strip("`")] = ([c.strip(" `") for c in short.split(",")], [c.strip(" `") for c in keys.split(",")])
    assert rows == {name: ([p.short for p in e.parameters], [p.key for p in e.parameters])
                    for name, e in EFFECTS.items()}


def zero_drift(x: EffectInputs, b):
    """Torque-sensor zero drift: ``ΔT = b·sgn(ω)`` (a toy sensor error for the registry test)."""
    return b * x.rot_sign


@pytest.fixture
def toy_sensor_error():
    effect = effects.register(Effect(
        "zero_drift", zero_drift, False, "a drifting zero of the torque sensor", "toy",
        (EffectParameter("b", "drift_nm", 0.0, "zero drift", "N*m", simulated=0.07),), coefficient="b",
        reading_error="offset"))
    try:
        yield effect
    finally:
        effects.unregister("zero_drift")


def test_a_toy_sensor_error_corrupts_simulate_s_reading_and_the_estimator_corrects_it(toy_sensor_error):
    """A sensor error is one entry: its descriptor says how it corrupts the reading, and simulate
    and the estimator take it from there (no module outside the registry names it)."""
    from rollergear_ros.core.estimator import Estimator
    from rollergear_ros.core.params import validate

    config = load_config(ROOT / "config" / "gearbox.yaml")
    opts = SimulationOptions(profile="rig_map", rate_hz=50.0, seed=1, torque_noise_nm=0.0,
                             effects=[DeclaredEffect.parse("zero_drift:b=0.07")])
    rig = simulate(config, opts)
    np.testing.assert_allclose(rig.torque_meas_nm - rig.torque_true_nm, 0.07, rtol=0, atol=1e-12)
    # a sensor error is not a loss: the true loss is the model's alone
    np.testing.assert_array_equal(rig.loss_true_nm, simulate(config, SimulationOptions(
        profile="rig_map", rate_hz=50.0, seed=1, torque_noise_nm=0.0)).loss_true_nm)
    enabled = validate(config.to_flat() | {"effects.zero_drift.enabled": True, "effects.zero_drift.drift_nm": 0.07})
    assert effects.reading_errors(enabled.effects.active()) == (0.07, 0.0)
    estimator = Estimator(enabled, "timestamp", 0.001)
    assert estimator.corrected_torque(10.07) == pytest.approx(10.0, abs=1e-12)


def test_no_module_outside_the_registry_names_an_effect():
    """Estimator, calibrate, simulate, params … ask the descriptors (``reading_error``,
    ``viscosity_law``, ``scales_fr``, ``state_step`` …), never an effect's name.  The simulated
    fleet is the one exception: its scenario is which effects its gearboxes develop."""
    import ast

    allowed = {"effects.py", "fleetsim.py"}
    named = []
    for path in sorted((ROOT / "rollergear_ros").glob("*.py")):
        if path.name in allowed:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in EFFECTS:
                named.append(f"{path.name}:{node.lineno} {node.value!r}")
    assert not named, named


def running_in(x: EffectInputs, c, angle):
    """A running-in drag that wears off with the angle turned: ``ΔT = c·(1 − z)``, ``z`` → 1 over
    ``angle`` radians (a toy effect with memory for the registry test; steady state: worn in)."""
    return c * (1.0 - x.state.get("running_in", 1.0))


def running_in_step(z: float, speed_rad_s: float, dt_s: float, params) -> float:
    """``z → 1 − (1 − z)·exp(−|ω|·dt/angle)``."""
    if speed_rad_s == 0.0 or dt_s <= 0.0:
        return z
    return 1.0 - (1.0 - z) * math.exp(-abs(speed_rad_s) * dt_s / params["angle"])


def running_in_steps(z: float, speed_rad_s, dt_s, params):
    """:func:`running_in_step` over a batch, the same float operations in time order."""
    out = []
    for w, dt in zip(np.asarray(speed_rad_s, float).tolist(), np.asarray(dt_s, float).tolist()):
        z = running_in_step(z, w, dt, params)
        out.append(z)
    return np.array(out)


def fr_thinning(x: EffectInputs, k):
    """A toy Fr-scaling effect: ``ΔT = −k·T_Fr`` (an oil that rolls thinner than the model's)."""
    return -k * x.fr_part_nm + 0.0 * x.abs_speed


@pytest.fixture
def toy_memory_and_fr_effects():
    effects.register(Effect(
        "running_in", running_in, True, "a running-in drag wearing off with the angle turned", "toy",
        (EffectParameter("c", "c_nm", 0.0, "initial drag", "N*m"),
         EffectParameter("angle", "angle_rad", 50.0, "running-in angle", "rad", low=1e-3, high=1e6)),
        coefficient="c", adaptive=False, state_step=running_in_step, state_steps=running_in_steps))
    effects.register(Effect(
        "fr_thinning", fr_thinning, True, "scale the model's Fr part by 1 - k", "toy",
        (EffectParameter("k", "k", 0.0, "relative thinning", low=-0.5, high=0.5),), coefficient="k",
        adaptive=False, scales_fr=True))
    try:
        yield
    finally:
        effects.unregister("running_in")
        effects.unregister("fr_thinning")


def test_toy_effects_with_memory_and_on_the_fr_part_are_one_entry_each(toy_memory_and_fr_effects):
    """An effect with memory is stepped by the estimator from its descriptor, the same sample by
    sample (node) as in batches (replay), and wears off as its law says; an Fr-scaling one scales
    the model's Fr part, nothing else."""
    from rollergear_ros.core.estimator import Estimator
    from rollergear_ros.core.model import LossModel
    from rollergear_ros.core.params import validate

    base = load_config(ROOT / "config" / "gearbox.yaml").with_values({"estimator.adapt": False})
    config = validate(base.to_flat() | {"effects.running_in.enabled": True, "effects.running_in.c_nm": 0.2,
                                        "effects.running_in.angle_rad": 5.0})
    rate, n = 100.0, 400
    t_ns = (1_700_000_000 * 10**9 + np.arange(n) * int(1e9 / rate)).astype(np.int64)
    torque, speed = np.full(n, 20.0), np.full(n, 10.0)
    one, many = Estimator(config), Estimator(config)
    streamed = []
    for i in range(n):
        for channel, value in (("motor_torque", torque[i]), ("motor_speed", speed[i])):
            streamed += [e.loss_torque_nm for e in one.push(channel, int(t_ns[i]), float(value))]
    streamed += [e.loss_torque_nm for e in one.finish()]
    batched = []
    for lo in range(0, n, 137):
        hi = min(lo + 137, n)
        b = many.push_many(np.tile(np.array([0, 1], np.int8), hi - lo), np.repeat(t_ns[lo:hi], 2),
                           np.column_stack([torque[lo:hi], speed[lo:hi]]).ravel())
        batched += [] if b is None else b.loss_torque_nm.tolist()
    rest = many.flush()
    batched += [] if rest is None else rest.loss_torque_nm.tolist()
    assert one._states == many._states  # noqa: SLF001 - bit for bit
    np.testing.assert_allclose(streamed, batched, rtol=1e-12, atol=1e-15)
    model = LossModel(config.gearbox).loss_magnitude(torque, speed)
    drag = np.array(batched) - model
    # worn in after 5 rad: at 10 rad/s, the drag falls from 0.2 N·m to e^-1 of it in 0.5 s
    turned = 10.0 * np.arange(len(drag)) / rate
    np.testing.assert_allclose(drag, 0.2 * np.exp(-turned / 5.0), rtol=1e-9, atol=1e-12)
    # an Fr-scaling effect: the model's Fr part times (1 - k)
    thin = validate(base.to_flat() | {"effects.fr_thinning.enabled": True, "effects.fr_thinning.k": 0.1})
    est = Estimator(thin)
    got = est.push_many(np.tile(np.array([0, 1], np.int8), 5), np.repeat(t_ns[:5], 2),
                        np.column_stack([torque[:5], speed[:5]]).ravel())
    rest = est.flush()
    loss = np.concatenate([got.loss_torque_nm if got is not None else [], rest.loss_torque_nm])
    m = LossModel(thin.gearbox)
    np.testing.assert_allclose(loss, m.loss_magnitude(torque[:5], speed[:5]) - 0.1 * m.fr_part(torque[:5], speed[:5]),
                               rtol=1e-12)


def test_the_viscosity_laws_search_holds_every_gear_oil_of_the_data_sheets():
    """Vogel B and C of each gear oil in ``realdata/lubricant_viscosity`` (from ν40, ν100 and ρ15 by
    ASTM D341) inside the search's grids and bounds, clear of the bounds: a refit can reach each."""
    import csv

    from helpers import REALDATA
    from rollergear_ros.core.oil import vogel_from_datasheet

    table = REALDATA / "lubricant_viscosity" / "gear_oil_viscosity_datasheet_values.csv"
    if not table.exists():
        pytest.skip("../shared/realdata is not here")
    effect = EFFECTS["viscosity_temperature"]
    (lo_b, hi_b), (lo_c, hi_c) = effect.member_bounds, effect.second_bounds
    with table.open() as fh:
        oils = list(csv.DictReader(fh))
    assert len(oils) >= 10
    for oil in oils:
        b, c, _eta = vogel_from_datasheet(float(oil["nu40_mm2_s"]), float(oil["nu100_mm2_s"]),
                                          1000.0 * float(oil["density15_kg_per_dm3"]))
        assert min(effect.member_grid) < b < max(effect.member_grid) and 2 * lo_b < b < hi_b / 2, (oil["product"], b)
        assert min(effect.second_grid) < c < max(effect.second_grid) and 2 * lo_c < c < hi_c / 2, (oil["product"], c)
