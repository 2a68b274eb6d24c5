"""Samples for calibration: the power-balance check on the measured loss."""

from __future__ import annotations

import numpy as np
import pytest

from rollergear_ros.calibration.samples import SampleData, power_balance_warning

from helpers import run_cli


def samples(torque, speed, loss):
    n = len(torque)
    z = np.zeros(n)
    return SampleData(np.arange(n, dtype=np.int64), np.zeros(n, dtype=np.int64), torque, speed, z, loss, z, z)


@pytest.mark.parametrize("seed", range(3))
def test_a_loss_above_the_input_torque_in_most_loaded_samples_is_said(seed):
    rng = np.random.default_rng(seed)
    torque = rng.uniform(-100, 100, 2000)
    speed = rng.uniform(-300, 300, 2000)
    loss = 0.5 + 0.02 * np.abs(torque) + rng.normal(0, 0.05, 2000)  # a plausible gearbox
    assert power_balance_warning(samples(torque, speed, loss)) is None
    # the output torque in the other sign convention: loss = 2·T·sgn(ω) − L
    flipped = 2 * torque * np.sign(speed) - loss * np.sign(torque * speed)
    line = power_balance_warning(samples(torque, speed, flipped))
    assert line is not None and "in 100 % of the loaded samples" in line
    median = float(line.split("median |loss|/|T| = ")[1].split(")")[0])
    assert 1.9 < median < 2.0  # 2 − L/|T|
    # a light load with a large drag is no reason (only loaded samples count)
    light = np.where(np.abs(torque) < 15, 20.0, loss)
    assert power_balance_warning(samples(torque, speed, light)) is None


def test_calibrate_warns_of_an_output_torque_in_the_other_sign_convention(tmp_path, config):
    """A steady-state CSV whose output torque is a reaction (sign flipped, written with pyarrow):
    without ``scale: -1`` calibrate says so; with it, no warning and the 0.3 N·m drag is found."""
    import json

    import pyarrow as pa
    import pyarrow.csv as pacsv

    from rollergear_ros.core.model import evaluate_reference

    rows = {"n_rpm": [], "T_in": [], "T_out": []}
    ratio = config.gearbox.ratio_effective
    for n in np.arange(200, 3001, 200.0):
        for t in np.concatenate([np.arange(-100, 0, 10.0), np.arange(10, 101, 10.0)]):
            w = n * 2 * np.pi / 60
            loss = abs(evaluate_reference(config.gearbox, t, w)["T_loss"]) + 0.3
            rows["n_rpm"].append(n)
            rows["T_in"].append(t)
            rows["T_out"].append(-(t - loss) * ratio)  # P_loss = T·ω − T_out·ω_out = loss·ω (ω > 0); a reaction torque
    pacsv.write_csv(pa.table(rows), tmp_path / "rig.csv")
    cmap = tmp_path / "map.yaml"
    base = ("format: steady_state\nmotor_torque: {column: T_in, unit: N*m}\nmotor_speed: {column: n_rpm, unit: rpm}\n"
            f"ratio: {ratio!r}\n")
    cmap.write_text(base + "output_torque: {column: T_out, unit: N*m}\n")
    proc = run_cli("calibrate", str(tmp_path / "rig.csv"), "--channels", str(cmap), "--json")
    assert "warning: the measured loss exceeds the input torque in 100 % of the loaded samples" in proc.stderr
    assert "opposite sign convention" in proc.stderr
    cmap.write_text(base + "output_torque: {column: T_out, unit: N*m, scale: -1}\n")
    proc = run_cli("calibrate", str(tmp_path / "rig.csv"), "--channels", str(cmap), "--json")
    assert "warning" not in proc.stderr, proc.stderr
    result = json.loads(proc.stdout)
    assert [e["name"] for e in result["effects"]] == ["drag_constant"]
    assert result["effects"][0]["params"]["c"] == pytest.approx(0.3, rel=0.01)


@pytest.mark.parametrize(("columns", "directions", "reason"), [
    ("output_torque: {column: T_out, unit: N*m}\n", (1.0, -1.0), ""),
    ("output_torque: {column: T_out, unit: N*m}\n", (1.0,), "torque readings in one direction"),
    ("loss_torque: {column: L, unit: N*m}\n", (1.0, -1.0), "rows are losses, not a sensor's readings"),
])
def test_a_tables_sensor_errors_are_tested_where_its_loss_is_its_readings_power_balance(tmp_path, columns, directions,
                                                                                        reason):
    """A table whose loss is the power balance of its drive and output torque readings carries the drive
    torque sensor's errors (where its rows turn both ways: else a zero error is a constant drag there);
    one whose loss is given as a loss column does not."""
    from rollergear_ros.calibration.blocks import testability
    from rollergear_ros.calibration.samples import table_samples
    from rollergear_ros.core.params import load_config
    from rollergear_ros.sources.channelmap import load_channel_map

    w = np.array([d * n for n in (100.0, 300.0, 1000.0) for t in (5.0, 20.0, 50.0) for d in directions])
    t_in = np.array([t * d for n in (100.0, 300.0, 1000.0) for t in (5.0, 20.0, 50.0) for d in directions])
    loss = 0.3 + 0.01 * np.abs(t_in)
    t_out = (t_in - loss * np.sign(w)) * 2.0  # ratio 2
    (tmp_path / "rows.csv").write_text("n,T,T_out,L\n" + "".join(
        f"{a!r},{b!r},{c!r},{d!r}\n" for a, b, c, d in zip(w.tolist(), t_in.tolist(), t_out.tolist(), loss.tolist())))
    (tmp_path / "map.yaml").write_text("format: steady_state\nmotor_torque: {column: T, unit: N*m}\n"
                                       "motor_speed: {column: n, unit: rpm}\nratio: 2\n" + columns)
    data = table_samples([tmp_path / "rows.csv"], load_config(), cmap=load_channel_map(tmp_path / "map.yaml"))
    np.testing.assert_allclose(data.measured_loss, loss, rtol=1e-12)
    why = testability(data)
    assert reason in why["torque_offset"] and (reason != "" or why["torque_offset"] == ""), why["torque_offset"]
    assert reason in why["torque_gain"] and (reason != "" or why["torque_gain"] == ""), why["torque_gain"]
