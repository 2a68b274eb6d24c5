"""``map --oil-temperature-c T1 T2 …``: a VECTO map per oil temperature and the long table of all."""

from __future__ import annotations

import csv
import json

import numpy as np
import pyarrow.parquet as pq
import pytest

from helpers import run_cli
from test_lossmap import read_map, vecto_rules

#: a gearbox whose Fr part follows the oil (Vogel B, C of a gear oil)
WARMING = ("/**/loss_estimator:\n  ros__parameters:\n    effects:\n      viscosity_temperature: "
           "{enabled: true, B_k: 1100.0, C_k: 95.0, theta_ref_c: 40.0, scale: 1.0}\n")
GRID = ("--speed-rpm", "0", "2000", "500", "--torque-nm", "-40", "40", "20")


def _model_at(params, torques, speeds_rpm, temperature_c) -> dict[tuple[float, float], float]:
    """``rollergear model``'s loss magnitude at every (torque, speed) pair, by (speed rpm, torque)."""
    proc = run_cli("model", "--params", str(params), "--oil-temperature-c", f"{temperature_c:g}", "--json",
                   "--torque", *map(str, torques), "--speed", *(str(n * 2 * np.pi / 60) for n in speeds_rpm))
    return {(round(p["speed_rad_s"] * 60 / (2 * np.pi), 6), p["torque_nm"]): abs(p["loss_torque_nm"])
            for p in json.loads(proc.stdout)["points"]}


def test_a_map_per_oil_temperature_equals_model_there_and_cold_oil_costs_most(tmp_path):
    params = tmp_path / "warming.yaml"
    params.write_text(WARMING)
    out = tmp_path / "gb.vtlm"
    proc = run_cli("map", "--out", str(out), "--params", str(params), "--oil-temperature-c", "20", "40", "80",
                   *GRID, "--both-directions", "--no-plot")
    maps = {t: read_map(tmp_path / f"gb_{t}C.vtlm") for t in (20, 40, 80)}
    for t in (20, 40, 80):
        for path in (tmp_path / f"gb_{t}C.vtlm", tmp_path / f"gb_{t}C_reverse.vtlm"):
            assert vecto_rules(path) == [] and f"# oil temperature {t} degC" in path.read_text()
        model = _model_at(params, [-40, -20, 20, 40], [500, 1000, 2000], t)
        rows = {(s, tq): loss for s, tq, loss in maps[t]}
        for key, loss in model.items():
            assert rows[key] == pytest.approx(loss, rel=1e-5), (t, key)
    moving = (maps[20][:, 0] > 0) & (maps[20][:, 1] != 0)  # no loss without torque
    assert (maps[20][moving, 2] > maps[40][moving, 2]).all() and (maps[40][moving, 2] > maps[80][moving, 2]).all()
    assert not out.exists() and "warning" not in proc.stderr

    table = list(csv.DictReader((tmp_path / "gb.csv").open()))
    assert list(table[0]) == ["oil_temperature_c", "reverse", "speed_rpm", "torque_nm", "loss_nm", "loss_power_w",
                              "efficiency"]
    assert len(table) == 3 * 2 * 5 * 5 and f"wrote {tmp_path / 'gb.csv'} (150 rows" in proc.stdout
    for t in (20, 40, 80):
        forward = [r for r in table if float(r["oil_temperature_c"]) == t and r["reverse"] == "0"]
        np.testing.assert_allclose([[float(r[c]) for c in ("speed_rpm", "torque_nm", "loss_nm")] for r in forward],
                                   maps[t], rtol=1e-5)
        for r in forward:
            assert float(r["loss_power_w"]) == pytest.approx(float(r["loss_nm"]) * float(r["speed_rpm"]) * np.pi / 30)
            assert (r["efficiency"] == "") == (float(r["speed_rpm"]) == 0 or r["torque_nm"] == "0")


def test_the_long_table_as_parquet_with_units_and_a_model_without_the_oil_is_said(tmp_path):
    table = tmp_path / "all.parquet"
    proc = run_cli("map", "--out", str(tmp_path / "m.vtlm"), "--oil-temperature-c", "0", "60", *GRID,
                   "--table", str(table), "--no-plot")
    read = pq.read_table(table)
    assert read.num_rows == 2 * 25 and read.schema.field("loss_power_w").metadata == {b"unit": b"W"}
    cols = read.to_pydict()
    assert sorted(set(cols["oil_temperature_c"])) == [0.0, 60.0] and set(cols["reverse"]) == {0}
    assert None in cols["efficiency"] and not any(v != v for v in cols["efficiency"] if v is not None)  # null, not NaN
    # the default parameters follow no oil: both maps are the same, and the command says so
    assert "does not follow the oil temperature" in proc.stderr and proc.stderr.count("\n") == 1
    np.testing.assert_array_equal(read_map(tmp_path / "m_0C.vtlm"), read_map(tmp_path / "m_60C.vtlm"))


@pytest.mark.parametrize(("args", "message"), [
    (("--oil-temperature-c", "20", "20"), "a temperature given twice"),
    (("--oil-temperature-c", "20", "40", "--table", "t.mf4"), "--table t.mf4: a .csv or .parquet file"),
    (("--oil-temperature-c", "20", "900"), "no oil temperature"),
])
def test_bad_temperatures_or_tables_are_one_line_and_nothing_is_written(tmp_path, args, message):
    proc = run_cli("map", "--out", "m.vtlm", *GRID, *args, "--no-plot", check=False, cwd=tmp_path)
    last = proc.stderr.strip().splitlines()[-1]  # argparse's own errors come after its usage lines
    assert proc.returncode == 2 and message in last and "Traceback" not in proc.stderr, proc.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_map_in_oil_the_calibration_never_saw_is_said_and_its_share_says_of_what(tmp_path):
    """A file calibrated in oil at 30 … 70 °C mapped at 0, 50 and 100 °C: the maps at 0 and 100 °C are said to
    lie outside what the calibration saw (the oil's law extrapolated), the one at 50 °C is not; the paper's
    model's share says of what it is a share (it printed "128 % of the loss" at 60 °C, unsaid of what)."""
    params = tmp_path / "warming.yaml"
    params.write_text(WARMING + "    calibration:\n      model_form: '{\"verdict\":\"effects_found\",\"seen\":"
                      "{\"speed_rad_s\":300.0,\"torque_nm\":50.0,\"oil_temperature_c\":[30.0,70.0]}}'\n")
    proc = run_cli("map", "--out", str(tmp_path / "gb.vtlm"), "--params", str(params), "--oil-temperature-c", "0",
                   "50", "100", *GRID, "--no-plot")
    for t in (0, 100):
        assert (f"gb_{t}C.vtlm: oil {t} °C lies outside the oil temperatures the calibration saw (30 … 70 °C): "
                "the oil's law is extrapolated there") in proc.stderr, proc.stderr
    assert "gb_50C.vtlm: oil" not in proc.stderr
    assert ("the paper's model alone at the file's viscosity (gearbox.eta0_pa_s, the oil at 40 °C): "
            in proc.stdout) and "of this map's loss, summed over its points" in proc.stdout, proc.stdout
