"""Steady-state tables: reading VECTO loss maps, and closing the loop on them."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from rollergear_ros.sources.channelmap import load_channel_map
from rollergear_ros.base.errors import InputFileError
from rollergear_ros.core.params import load_config
from rollergear_ros.sources.tables import read_table

from helpers import REALDATA, run_cli

VECTO = REALDATA / "vecto_generic_lossmaps"
AXLE_40T = VECTO / "40t_long_haul_truck" / "Axle.vtlm"
needs_realdata = pytest.mark.skipif(not AXLE_40T.exists(), reason=f"no shared real data at {VECTO}")
HEADER = "Input Speed [rpm],Input Torque [Nm],Torque Loss [Nm]\n"
ROWS = "0,-100,2\n0,100,2\n1000,-100,3\n1000,100,3\n"


def test_a_vtlm_is_read_by_vectos_rules(tmp_path):
    path = tmp_path / "m.vtlm"
    path.write_text("# a comment\n" + HEADER.replace("\n", ",Eff [-]\n") + "0,-100,2,0.98\n# in between\n"
                    "0,100,2 # cut at the hash\n1000,-100,3,\n1000,100,3,0.97\n")
    t = read_table(path)
    np.testing.assert_allclose(t.speed_rad_s, np.array([0, 0, 1000, 1000]) * 2 * np.pi / 60)
    np.testing.assert_array_equal(t.torque_nm, [-100, 100, -100, 100])
    np.testing.assert_array_equal(t.loss_nm, [2, 2, 3, 3])
    np.testing.assert_array_equal(t.line, [3, 5, 6, 7])
    # no header: the columns by position, as VECTO falls back to
    bare = tmp_path / "bare.vtlm"
    bare.write_text(ROWS)
    np.testing.assert_array_equal(read_table(bare).loss_nm, [2, 2, 3, 3])


@pytest.mark.parametrize(("text", "message"), [
    ("Input Speed [rpm],Input Torque [Nm]\n" + ROWS, "no column 'Torque Loss'"),
    (HEADER.replace("[rpm]", "[rad/s]") + ROWS, "[rad/s]; a VECTO loss map has it in [rpm]"),
    (HEADER + ROWS + "2000,x,3\n", "line 6: expected numbers"),
    (HEADER + "0,-100,2\n0,100,2\n1000,100,3\n", "3 data rows"),
    (HEADER + ROWS + "-500,10,1\n", "line 6: negative input speed"),
    (HEADER + ROWS + "500,10,-1\n", "line 6: negative torque loss"),
    (HEADER + ROWS + "500,nan,1\n", "line 6: input torque is not finite"),
    ("", "no header and no data"),
])
def test_bad_tables_are_one_line_naming_the_file_and_line(tmp_path, text, message):
    path = tmp_path / "bad.vtlm"
    path.write_text(text)
    with pytest.raises(InputFileError) as err:
        read_table(path)
    assert message in str(err.value) and str(path) in str(err.value)
    proc = run_cli("calibrate", str(path), check=False)
    assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr


def test_recordings_and_tables_are_not_mixed(tmp_path):
    path = tmp_path / "m.vtlm"
    path.write_text(HEADER + ROWS)
    from helpers import BAGS

    proc = run_cli("calibrate", str(path), str(BAGS / "rig_map.mcap"), check=False)
    assert proc.returncode == 2 and "not both" in proc.stderr


def _params(tmp_path, paper_model: bool):
    p = tmp_path / f"axle_{paper_model}.yaml"
    p.write_text("/**/loss_estimator:\n  ros__parameters:\n    estimator: "
                 f"{{paper_model: {str(paper_model).lower()}, max_abs_torque_nm: 40000.0}}\n")
    return p


@needs_realdata
def test_the_40t_axle_map_is_found_to_be_40_plus_0_015_abs_torque(tmp_path):
    """VECTO's generic 40 t axle map is exactly 40 + 0.015·|T| N·m in the input torque T.  The load
    friction takes the output-side load, ``|T| − L`` driving and ``|T| + L`` in overrun, where the same
    map reads ``(40 + 0.015·|T_load|)/(1 ± 0.015)``: with the paper's model switched off, calibrate finds
    drag_constant c ≈ 40 and load_dependent c ≈ 0.015, q = 1 and nothing else, the one law nearest both
    directions (0.3 % of the loss left); the written parameter file gives the energy manager the map
    back within 1 %."""
    cal = tmp_path / "axle_cal.yaml"
    proc = run_cli("calibrate", str(AXLE_40T), "--params", str(_params(tmp_path, False)), "--json", "--out", str(cal))
    result = json.loads(proc.stdout)
    assert result["verdict"] == "effects_found"
    found = {e["name"]: e["params"] for e in result["effects"]}
    assert set(found) == {"drag_constant", "load_dependent"}
    assert found["drag_constant"]["c"] == pytest.approx(40.0, rel=0.03)
    assert found["load_dependent"]["c"] == pytest.approx(0.015, rel=0.07)
    assert found["load_dependent"]["q"] == pytest.approx(1.0, rel=0.01)
    assert result["error_after"]["rel_rmse_pct"] < 0.3 < 50 < result["error_before"]["rel_rmse_pct"]
    assert "rows of the steady-state table" in result["holdout"]
    adequacy = result["adequacy"]
    assert adequacy["paper_model"] is False and adequacy["model_share_pct"] == 0
    assert sum(adequacy["effects_share_pct"].values()) == pytest.approx(100.0, abs=0.1)
    # the calibrated parameter file in the map: the axle's map again
    out = tmp_path / "axle.vtlm"
    run_cli("map", "--params", str(cal), "--out", str(out), "--no-plot", "--speed-rpm", "0", "2000", "250",
            "--torque-nm", "-5000", "35000", "2500")
    rows = np.array([ln.split(",") for ln in out.read_text().splitlines()
                     if not ln.startswith("#")][1:], dtype=float)
    np.testing.assert_allclose(rows[:, 2], 40 + 0.015 * np.abs(rows[:, 1]), rtol=0.03)


@needs_realdata
def test_with_the_papers_model_on_the_axle_no_negative_friction_the_model_switched_off_and_said(tmp_path):
    """The paper's ball-track model with this package's gearbox at 35 kN·m predicts many times the
    axle's loss: the fits with the model on need negative frictions (they used to be accepted:
    load_dependent c = -0.00232 beside two drags).  Calibrate weighs the paper's model switched off
    on the same held-out rows, writes that file and says why; no coefficient is negative."""
    cal = tmp_path / "cal.yaml"
    proc = run_cli("calibrate", str(AXLE_40T), "--params", str(_params(tmp_path, True)), "--json", "--out", str(cal))
    result = json.loads(proc.stdout)
    assert result["verdict"] == "effects_found" and result["written"]
    found = {e["name"]: e["params"] for e in result["effects"]}
    assert set(found) == {"drag_constant", "load_dependent"}
    assert all(v["c"] > 0 for v in found.values())
    assert result["adequacy"]["paper_model"] is False
    assert any("the paper's model over-predicts this gearbox's loss" in n and "estimator.paper_model: false" in n
               for n in result["notes"])
    assert result["error_after"]["rel_rmse_pct"] < 0.3  # a law in the input torque, fitted in the load
    assert load_config(cal).estimator.paper_model is False  # the claim is the file


@needs_realdata
def test_a_map_the_papers_model_cannot_shape_is_written_without_it_and_said(tmp_path):
    """A gear whose loss grows linearly with the torque (VECTO group 54, gear 3): with the paper's
    model on, no fit needs a negative friction, but the residual left follows the torque (the model's
    shape is not this gear's: the file it would write leaves 8.9 % of the loss).  Calibrate weighs
    the model switched off on the same held-out rows and writes that file, saying why; the claim is
    the file."""
    cal = tmp_path / "cal.yaml"
    gear = VECTO / "group54_newer_vecto" / "Gear_3.vtlm"
    on = json.loads(run_cli("calibrate", str(gear), "--params", str(_params(tmp_path, True)), "--json",
                            "--out", str(cal)).stdout)
    off = json.loads(run_cli("calibrate", str(gear), "--params", str(_params(tmp_path, False)), "--json").stdout)
    assert on["written"] and on["adequacy"]["paper_model"] is False
    assert load_config(cal).estimator.paper_model is False
    assert any("does not have the shape of this gearbox's loss" in n and "depends most on torque" in n
               for n in on["notes"])
    assert on["error_after"]["rmse_nm"] == pytest.approx(off["error_after"]["rmse_nm"], rel=1e-9)
    # VECTO's law is in the input torque; in the output-side load the laws take, driving and overrun
    # differ by c/(1 ± c) (c = 0.04 here): 5.5 % of the loss left
    assert on["error_after"]["rel_rmse_pct"] < 6.0


def test_an_undeclared_effect_in_a_table_from_the_full_model_is_found(tmp_path, config):
    """A table made by the whole model plus a speed drag (the way a rig would measure it, not
    through the calibrator's columns): calibrate finds drag_speed with its exponent, nothing else."""
    from rollergear_ros.core.model import evaluate_reference

    speeds = np.arange(100, 3001, 100.0)
    torques = np.arange(-100, 101, 10.0)
    lines = [HEADER.strip()]
    for n in speeds:
        w = n * 2 * np.pi / 60
        for t in torques:
            loss = abs(evaluate_reference(config.gearbox, t, w)["T_loss"]) + 3e-4 * w ** 1.4
            lines.append(f"{n:g},{t:g},{loss:.9g}")
    table = tmp_path / "drag.vtlm"
    table.write_text("\n".join(lines) + "\n")
    report = tmp_path / "report"
    result = json.loads(run_cli("calibrate", str(table), "--json", "--report", str(report)).stdout)
    assert result["verdict"] == "effects_found"
    assert [e["name"] for e in result["effects"]] == ["drag_speed"]
    # the report of a table: the effect's curve, residuals over the inputs, none over time
    plots = {p.name for p in report.glob("*.png")}
    assert {"effect_drag_speed.png", "residual_vs_speed.png", "residual_vs_torque.png"} <= plots
    assert "residual_over_time.png" not in plots
    params = result["effects"][0]["params"]
    assert params["c"] == pytest.approx(3e-4, rel=0.02) and params["p"] == pytest.approx(1.4, abs=0.02)
    assert result["adequacy"]["paper_model"] is True


def test_a_steady_state_csv_with_efficiency_in_percent_and_two_gears(tmp_path, config):
    """A supplier's table: operating points with an efficiency column in %, speeds in rpm, torque in
    kN·m, two gears in a group column; made by the whole model plus a constant drag of 0.3 N·m
    (written with pyarrow).  calibrate finds the drag and nothing else."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    from rollergear_ros.core.model import evaluate_reference

    rows = {"gear": [], "n_rpm": [], "T_knm": [], "eta_pct": []}
    for gear in ("1", "2"):
        for n in np.arange(200, 3001, 200.0):
            for t in np.concatenate([np.arange(-100, 0, 10.0), np.arange(10, 101, 10.0)]):
                w = n * 2 * np.pi / 60
                loss = abs(evaluate_reference(config.gearbox, t, w)["T_loss"]) + 0.3
                eta = (abs(t) - loss) / abs(t) if t > 0 else abs(t) / (abs(t) + loss)
                rows["gear"].append(gear)
                rows["n_rpm"].append(n)
                rows["T_knm"].append(t / 1e3)
                rows["eta_pct"].append(100 * eta)
    pacsv.write_csv(pa.table(rows), tmp_path / "supplier.csv")
    cmap = tmp_path / "supplier.yaml"
    cmap.write_text("format: steady_state\nmotor_torque: {column: T_knm, unit: kN*m}\n"
                    "motor_speed: {column: n_rpm, unit: rpm}\nefficiency: {column: eta_pct, unit: '%'}\n"
                    "group: {column: gear}\n")
    result = json.loads(run_cli("calibrate", str(tmp_path / "supplier.csv"), "--channels", str(cmap),
                                "--json").stdout)
    assert result["verdict"] == "effects_found"
    assert [e["name"] for e in result["effects"]] == ["drag_constant"]
    assert result["effects"][0]["params"]["c"] == pytest.approx(0.3, rel=0.01)
    assert result["samples"] == len(rows["gear"])
    # an efficiency outside (0, 1] after the unit is refused with the row
    cmap.write_text(cmap.read_text().replace("unit: '%'", "unit: '1'"))
    proc = run_cli("calibrate", str(tmp_path / "supplier.csv"), "--channels", str(cmap), check=False)
    assert proc.returncode == 2 and "data row 1: efficiency" in proc.stderr


def test_an_undeclared_load_speed_effect_in_a_table_is_found_and_nothing_else(tmp_path, config):
    """A table from the whole model plus a load-speed friction c·|T|·|ω|^p (both torque signs)."""
    from rollergear_ros.core.model import evaluate_reference

    lines = [HEADER.strip()]
    for n in np.arange(100, 3001, 100.0):
        w = n * 2 * np.pi / 60
        for t in np.arange(-100, 101, 10.0):
            loss = abs(evaluate_reference(config.gearbox, t, w)["T_loss"]) + 2e-5 * abs(t) * w ** 1.2
            lines.append(f"{n:g},{t:g},{loss:.9g}")
    (tmp_path / "ls.vtlm").write_text("\n".join(lines) + "\n")
    result = json.loads(run_cli("calibrate", str(tmp_path / "ls.vtlm"), "--json").stdout)
    assert result["verdict"] == "effects_found"
    assert [e["name"] for e in result["effects"]] == ["load_speed"]
    params = result["effects"][0]["params"]
    assert params["c"] == pytest.approx(2e-5, rel=0.02) and params["p"] == pytest.approx(1.2, abs=0.02)


def test_a_tables_intervals_come_from_its_own_scatter(tmp_path):
    """Rows weigh 1 each (a table says nothing of its noise): the exponents' 95 % ranges come from the
    rows' scatter around the fit, not from a 1 N·m noise floor meant for inverse-variance blocks (which
    made q's range on this table [0.46, 1.66]).  Independent formula, scatter 0.01 N·m, paper's model off."""
    rng = np.random.default_rng(3)
    lines = [HEADER.strip()]
    for n in range(250, 4001, 250):
        w = n * 2 * np.pi / 60
        for load in [*range(-200, 0, 20), *range(20, 201, 20)]:  # the output-side load, referred to the input
            loss = 1.2 + 4e-4 * w ** 1.3 + 0.012 * abs(load) + rng.normal(0, 0.01)
            lines.append(f"{n},{load + loss:.6f},{loss:.6f}")
    (tmp_path / "map.vtlm").write_text("\n".join(lines) + "\n")
    result = json.loads(run_cli("calibrate", str(tmp_path / "map.vtlm"), "--params", str(_params(tmp_path, False)),
                                "--json").stdout)
    found = {e["name"]: e for e in result["effects"]}
    assert set(found) == {"drag_constant", "drag_speed", "load_dependent"}
    for name, member, truth in (("drag_speed", "p", 1.3), ("load_dependent", "q", 1.0)):
        lo, hi = found[name]["ci95"][member]
        assert lo <= truth <= hi and hi - lo < 0.1, (name, lo, hi)
    assert found["drag_constant"]["params"]["c"] == pytest.approx(1.2, abs=0.01)
    assert all(e["at_bound"] == [] for e in result["effects"])


def test_a_speed_law_flatter_than_the_vocabulary_allows_is_not_accepted_at_its_bound_and_said(tmp_path):
    """A churning loss growing like ω^0.1 (below drag_speed's range, p ≥ 0.3): the search goes on past
    the grid's first member to the bound, and an exponent stopped there is no estimate -- the curve is
    never accepted (it used to be written, with a note); where the law's line passes instead, that is
    written (p = 1), and calibrate says why not the curve."""
    lines = [HEADER.strip()]
    for n in range(250, 4001, 250):
        w = n * 2 * np.pi / 60
        for t in [*range(-200, 0, 20), *range(20, 201, 20)]:
            lines.append(f"{n},{t},{0.8 * w ** 0.1 + 0.01 * abs(t):.9g}")
    (tmp_path / "flat.vtlm").write_text("\n".join(lines) + "\n")
    params = str(_params(tmp_path, False))
    result = json.loads(run_cli("calibrate", str(tmp_path / "flat.vtlm"), "--params", params, "--json").stdout)
    speed = {e["name"]: e for e in result["effects"]}.get("drag_speed")
    assert all(not e["at_bound"] for e in result["effects"])
    decision = {d["name"]: d for d in result["decisions"]}["drag_speed"]
    if speed is not None:  # its line
        assert speed["params"]["p"] == 1.0, speed
        assert "its curve's p = 0.3" in decision["note"] and "stopped at the bound of its search [0.3, 3.5]" in \
            decision["note"], decision
    else:
        rejected = {r["name"]: r for r in result["rejected"]}
        assert "stopped at the bound of its search [0.3, 3.5]" in rejected["drag_speed"]["reason"]
    text = run_cli("calibrate", str(tmp_path / "flat.vtlm"), "--params", params).stdout
    assert "stopped at the bound of its search [0.3, 3.5]" in text


def test_an_output_side_efficiency_table_with_a_ratio_column_is_put_on_the_input_shaft(tmp_path, config):
    """NREL ADVISOR's layout -- gear, ratio, output speed, output torque, efficiency (0 where the
    shaft stands or carries nothing) -- read as it is: made by the whole model plus a 0.3 N·m drag
    on the input shaft of two gears (written with pyarrow); calibrate finds the drag and nothing else."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    from rollergear_ros.core.model import evaluate_reference

    rows = {"gear": [], "overall_ratio": [], "w_out": [], "T_out": [], "eta": []}
    for gear, r in (("1", 3.0), ("2", 1.5)):
        for w_in in np.arange(0.0, 301.0, 25.0):
            for t_in in np.concatenate([np.arange(-100, 0, 10.0), [0.0], np.arange(10, 101, 10.0)]):
                if w_in == 0 or t_in == 0:
                    t_out, eta = t_in * r, 0.0  # ADVISOR's cells without power: efficiency 0
                else:
                    loss = abs(evaluate_reference(config.gearbox, t_in, w_in)["T_loss"]) + 0.3
                    t_out = (t_in - loss) * r  # ω > 0: the loss opposes rotation
                    eta = (t_out / r) / t_in if t_in > 0 else t_in / (t_out / r)
                rows["gear"].append(gear)
                rows["overall_ratio"].append(r)
                rows["w_out"].append(w_in / r)
                rows["T_out"].append(t_out)
                rows["eta"].append(eta)
    pacsv.write_csv(pa.table(rows), tmp_path / "advisor.csv")
    cmap = tmp_path / "advisor.yaml"
    cmap.write_text("format: steady_state\noutput_torque: {column: T_out, unit: N*m}\n"
                    "output_speed: {column: w_out, unit: rad/s}\nefficiency: {column: eta, unit: '1'}\n"
                    "ratio: {column: overall_ratio}\ngroup: {column: gear}\n")
    from rollergear_ros.sources.channelmap import load_channel_map

    table = read_table(tmp_path / "advisor.csv", load_channel_map(cmap))
    moving = (np.array(rows["w_out"]) != 0) & (np.array(rows["T_out"]) != 0)
    assert len(table.loss_nm) == moving.sum() and table.dropped == (~moving).sum()
    np.testing.assert_allclose(table.speed_rad_s, (np.array(rows["w_out"]) * np.array(rows["overall_ratio"]))[moving])
    result = json.loads(run_cli("calibrate", str(tmp_path / "advisor.csv"), "--channels", str(cmap),
                                "--json").stdout)
    assert [e["name"] for e in result["effects"]] == ["drag_constant"]
    assert result["effects"][0]["params"]["c"] == pytest.approx(0.3, rel=0.01)


@pytest.mark.parametrize(("text", "message"), [
    ("output_torque: {column: T, unit: N*m}\noutput_speed: {column: w, unit: rad/s}\n",
     "a table of the output side needs output_torque, output_speed, efficiency and ratio (missing: efficiency, ratio)"),
    ("motor_speed: {column: n, unit: rpm}\nloss_torque: {column: L, unit: N*m}\n", "no motor_torque channel"),
    ("motor_torque: {column: T, unit: N*m}\nmotor_speed: {column: n, unit: rpm}\nloss_torque: {column: L, unit: N*m}\n"
     "ratio: {col: r}\n", "ratio: expected a number > 0 or {column: NAME}"),
])
def test_maps_of_output_side_tables_are_checked(tmp_path, text, message):
    from rollergear_ros.sources.channelmap import load_channel_map

    (tmp_path / "m.yaml").write_text("format: steady_state\n" + text)
    with pytest.raises(InputFileError, match=re.escape(message)):
        load_channel_map(tmp_path / "m.yaml")


@needs_realdata
def test_advisors_own_long_csv_is_read_by_its_provenance_feed_rule(tmp_path):
    """The shared ADVISOR export as it is, through a channel map: every row on the input shaft as
    PROVENANCE.md's feed rule says (computed here independently, row by row)."""
    import csv as csvmod

    from rollergear_ros.sources.channelmap import load_channel_map

    src = REALDATA / "advisor_vw_transaxle_effmap" / "tx_vw_eff_map_26_50_5_long.csv"
    (tmp_path / "m.yaml").write_text(
        "format: steady_state\noutput_torque: {column: output_torque_Nm, unit: N*m}\n"
        "output_speed: {column: output_speed_rad_s, unit: rad/s}\nefficiency: {column: efficiency, unit: '1'}\n"
        "ratio: {column: overall_ratio}\ngroup: {column: gear}\n")
    table = read_table(src, load_channel_map(tmp_path / "m.yaml"))
    expect = []
    with src.open() as fh:
        for row in csvmod.DictReader(fh):
            r, w_o, t_o, eta = (float(row[k]) for k in ("overall_ratio", "output_speed_rad_s", "output_torque_Nm",
                                                        "efficiency"))
            if w_o == 0 or t_o == 0 or eta == 0:  # no power through: no input torque (dropped, counted)
                continue
            t_i = t_o / (r * eta) if t_o > 0 else t_o * eta / r
            loss = abs(t_i) * (1 - eta) if t_o > 0 else abs(t_i) * (1 / eta - 1)
            expect.append((w_o * r, t_i, loss, row["gear"]))
    w, t, loss, gear = zip(*expect)
    np.testing.assert_allclose(table.speed_rad_s, w, rtol=1e-12)
    np.testing.assert_allclose(table.torque_nm, t, rtol=1e-12)
    np.testing.assert_allclose(table.loss_nm, loss, rtol=1e-9, atol=1e-12)
    assert list(table.group) == list(gear) and table.dropped == 6500 - len(expect)


def test_a_bench_map_of_input_torque_and_output_speed_is_calibrated_and_its_ratio_reaches_the_map(tmp_path, config):
    """The layout a truck-axle bench hands over -- input torque, output speed, output torque and the
    ratio -- was refused ("no motor_speed channel"); the input speed is output speed x ratio.  A
    table made by the whole model + 0.3 N·m drag in that layout gives drag_constant 0.3 and nothing
    else, and a map of the calibrated file states the table's ratio, not the roller gearbox's."""
    from rollergear_ros.core.model import evaluate_reference

    ratio = 3.7
    lines = ["T_in,n_out,T_out"]
    for n_in in np.arange(300, 3001, 300.0):
        w_in = n_in * 2 * np.pi / 60
        for t in np.arange(10, 101, 10.0):
            loss = abs(evaluate_reference(config.gearbox, t, w_in)["T_loss"]) + 0.3
            lines.append(f"{t:g},{n_in / ratio:.12g},{(t - loss) * ratio:.12g}")
    (tmp_path / "bench.csv").write_text("\n".join(lines) + "\n")
    (tmp_path / "map.yaml").write_text(f"format: steady_state\nmotor_torque: {{column: T_in, unit: N*m}}\n"
                                       f"output_speed: {{column: n_out, unit: rpm}}\n"
                                       f"output_torque: {{column: T_out, unit: N*m}}\nratio: {ratio}\n")
    table = read_table(tmp_path / "bench.csv", load_channel_map(tmp_path / "map.yaml"))
    np.testing.assert_allclose(np.sort(np.unique(np.round(table.speed_rad_s * 60 / (2 * np.pi), 6))),
                               np.arange(300, 3001, 300.0))
    cal = tmp_path / "cal.yaml"
    result = json.loads(run_cli("calibrate", str(tmp_path / "bench.csv"), "--channels", str(tmp_path / "map.yaml"),
                                "--json", "--out", str(cal)).stdout)
    found = {e["name"]: e["params"] for e in result["effects"]}
    assert set(found) == {"drag_constant"} and found["drag_constant"]["c"] == pytest.approx(0.3, rel=0.01)
    run_cli("map", "--params", str(cal), "--out", str(tmp_path / "m.vtlm"), "--no-plot")
    assert f"ratio (input/output speed) {ratio:g}" in (tmp_path / "m.vtlm").read_text()


def test_a_table_mostly_beyond_the_plausible_range_stops_naming_the_limit_to_raise(tmp_path):
    """A 40 t axle's map (up to 35 kN·m) against the default 5 kN·m limit: calibrate analysed the
    remaining quarter of the rows with a confident adequacy line."""
    text = HEADER + "".join(f"{n},{t},{10 + 0.01 * abs(t)}\n" for n in (500, 1000, 1500) for t in
                            (-2000, 1000, 8000, 15000, 25000, 35000))
    (tmp_path / "big.vtlm").write_text(text)
    proc = run_cli("calibrate", str(tmp_path / "big.vtlm"), check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    error = [ln for ln in proc.stderr.splitlines() if "error" in ln]
    assert len(error) == 1 and "12 of 18 rows lie beyond the estimator's plausible range" in error[0]
    assert "estimator.max_abs_torque_nm: 36000" in error[0], error[0]
    # the table's import is that table: the same line, not a calibration of the quarter replay keeps
    bag = tmp_path / "big.mcap"
    run_cli("import", str(tmp_path / "big.vtlm"), "--out", str(bag))
    proc = run_cli("calibrate", str(bag), check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    imported = [ln for ln in proc.stderr.splitlines() if "error" in ln]
    assert [ln.replace(str(bag), "T") for ln in imported] == [ln.replace(str(tmp_path / "big.vtlm"), "T")
                                                              for ln in error]


@needs_realdata
@pytest.mark.slow
@pytest.mark.parametrize("paper_model", [False, True])
def test_no_measured_map_gets_a_negative_friction_or_an_exponent_at_its_bound(tmp_path, paper_model):
    """Every VECTO map and each gear of ADVISOR's transaxle (shared/realdata), the paper's model off
    and on: the accepted laws are losses the gearbox can have -- no negative coefficient of a loss,
    no exponent at the bound of its search -- and the file written is what the errors describe."""
    from rollergear_ros.calibration.calibrate import calibrate
    from rollergear_ros.core.effects import EFFECTS
    from rollergear_ros.calibration.samples import table_samples

    config = load_config(_params(tmp_path, paper_model)).with_values({"estimator.max_abs_torque_nm": 100000.0})
    advisor = tmp_path / "advisor.yaml"
    advisor.write_text(
        "format: steady_state\noutput_torque: {column: output_torque_Nm, unit: N*m}\n"
        "output_speed: {column: output_speed_rad_s, unit: rad/s}\nefficiency: {column: efficiency, unit: '1'}\n"
        "ratio: {column: overall_ratio}\ngroup: {column: gear}\n")
    cases = [(p, None) for p in sorted(VECTO.rglob("*.vtlm"))]
    cases.append((REALDATA / "advisor_vw_transaxle_effmap" / "tx_vw_eff_map_26_50_5_long.csv",
                  load_channel_map(advisor)))
    assert len(cases) >= 8
    for path, cmap in cases:
        res = calibrate(table_samples([path], config, cmap=cmap), config)
        for e in res.effects:
            spec = EFFECTS[e.name]
            if spec.physical and not spec.scales_fr:
                assert e.params[spec.coefficient] > 0, (path.name, e)
            assert e.at_bound == [], (path.name, e)
        assert res.written and res.error_after.rmse_nm < res.error_before.rmse_nm, path.name
