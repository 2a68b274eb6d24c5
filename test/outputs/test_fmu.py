"""``rollergear export --fmu``: the calibrated gearbox as an FMI 2.0 unit, run by ``fmpy``.

The unit is run by fmpy (the FMI reference simulator in Python) in a process where this package
cannot be imported, and compared with ``rollergear model`` at points between the table's nodes.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import yaml

from helpers import run_cli

WARMING = ("/**/loss_estimator:\n  ros__parameters:\n    effects:\n      viscosity_temperature: "
           "{enabled: true, B_k: 1100.0, C_k: 95.0, theta_ref_c: 40.0, scale: 1.0}\n"
           "      drag_speed: {enabled: true, c: 2.0e-4, p: 1.4}\n"
           "      torque_offset: {enabled: true, offset_nm: 0.3}\n")
TORQUES = [-73.3, -12.1, -0.7, 0.33, 4.4, 57.9]
SPEEDS = [-250.3, -7.7, 0.9, 33.3, 201.7]

#: runs in a fresh interpreter: fmpy steps the unit at every (temperature, torque, speed) of stdin's JSON;
#: this package is made unimportable first, so the unit must carry what it needs
RUN_UNIT = textwrap.dedent("""
    import json, sys
    sys.modules["rollergear_ros"] = None
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    path, points = sys.argv[1], json.loads(sys.stdin.read())
    md = read_model_description(path)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    unit = FMU2Slave(guid=md.guid, unzipDirectory=extract(path), modelIdentifier=md.coSimulation.modelIdentifier,
                     instanceName="gearbox")
    unit.instantiate(); unit.setupExperiment(startTime=0.0)
    unit.enterInitializationMode(); unit.exitInitializationMode()
    rows = []
    for i, (theta, torque, speed) in enumerate(points):
        unit.setReal([vr["oil_temperature_c"], vr["drive_torque_nm"], vr["drive_speed_rad_s"]], [theta, torque, speed])
        unit.doStep(currentCommunicationPoint=0.01 * i, communicationStepSize=0.01)
        rows.append(unit.getReal([vr["loss_torque_nm"], vr["loss_power_w"], vr["efficiency"]])
                    + [bool(unit.getBoolean([vr["inside_table"]])[0])])
    fixed = unit.getReal([vr["interpolation_error_nm"], vr["interpolation_error_relative"]])
    strings = {n: unit.getString([vr[n]])[0].decode() for n in vr if n.startswith("rollergear_")}
    unit.terminate(); unit.freeInstance()
    print(json.dumps({"rows": rows, "error": fixed, "strings": strings, "description": md.description,
                      "inputs": sorted(v.name for v in md.modelVariables if v.causality == "input"),
                      "outputs": sorted(v.name for v in md.modelVariables if v.causality == "output")}))
    sys.stdout.flush()
""")


def run_unit(path, points) -> dict:
    proc = subprocess.run([sys.executable, "-c", RUN_UNIT, str(path)], input=json.dumps(points), capture_output=True,
                          text=True, timeout=600, check=False)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def model_points(params, temperature_c) -> list[dict]:
    proc = run_cli("model", "--params", str(params), "--oil-temperature-c", f"{temperature_c:g}", "--json",
                   "--torque", *map(str, TORQUES), "--speed", *map(str, SPEEDS))
    return json.loads(proc.stdout)["points"]


@pytest.fixture(scope="module")
def warming_unit(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fmu")
    params = folder / "cal.yaml"
    params.write_text(WARMING)
    out = folder / "gearbox.fmu"
    proc = run_cli("export", "--fmu", str(out), "--params", str(params))
    return params, out, proc


@pytest.mark.parametrize("temperature_c", [-13.0, 7.3, 41.0, 96.6])
def test_the_unit_run_by_fmpy_equals_model_within_its_stated_interpolation_error(warming_unit, temperature_c):
    params, unit, _ = warming_unit
    expected = model_points(params, temperature_c)
    ran = run_unit(unit, [[temperature_c, p["torque_nm"], p["speed_rad_s"]] for p in expected])
    error_nm, error_rel = ran["error"]
    assert 0 < error_nm < 0.1 and 0 < error_rel < 0.05  # what the table states (and that it is small)
    for p, (loss, power, eta, inside) in zip(expected, ran["rows"]):
        exact = abs(p["loss_torque_nm"])
        assert inside
        assert abs(loss - exact) <= error_nm, (p, loss)
        assert power == pytest.approx(loss * abs(p["speed_rad_s"]), rel=1e-12)
        if p["efficiency"] is None:
            assert np.isnan(eta), (p, eta)
        else:  # where eta is defined the relative error of the loss holds too
            assert abs(loss - exact) <= error_rel * exact + 1e-12, (p, loss)
            assert eta == pytest.approx(p["efficiency"], abs=error_rel * (1 - p["efficiency"]) + 1e-12)


def test_the_unit_follows_the_oil_temperature_and_says_where_it_came_from(warming_unit):
    params, unit, proc = warming_unit
    ran = run_unit(unit, [[theta, 50.0, 200.0] for theta in (-10.0, 20.0, 40.0, 90.0)] + [[40.0, 50.0, 900.0]])
    losses = [row[0] for row in ran["rows"]]
    assert losses[0] > 2 * losses[1] > 2 * losses[3] and losses[1] > losses[2] > losses[3]  # cold oil costs most
    beyond = ran["rows"][-1]  # 900 rad/s lies beyond the table: said, and nothing made up there
    assert beyond[3] is False and all(np.isnan(v) for v in beyond[:3])
    assert ran["inputs"] == ["drive_speed_rad_s", "drive_torque_nm", "oil_temperature_c"]
    assert ran["outputs"] == ["efficiency", "inside_calibration", "inside_rating", "inside_table", "loss_power_w",
                              "loss_torque_nm"]
    strings = ran["strings"]
    digest = hashlib.sha256(params.read_bytes()).hexdigest()
    assert strings["rollergear_parameters_file"] == f"cal.yaml (sha256 {digest})"
    assert str(params.parent) not in json.dumps(ran)  # no path of the machine that made it
    assert "viscosity_temperature B=1100" in strings["rollergear_accepted_effects"]
    assert "torque_offset" not in strings["rollergear_accepted_effects"]  # a rig's sensor error, not applied
    written = yaml.safe_load(strings["rollergear_parameters_yaml"])["/**/loss_estimator"]["ros__parameters"]
    assert written["effects"]["drag_speed"]["c"] == 2.0e-4
    assert "interpolation error <=" in ran["description"] and "oil temperatures -20 … 140 degC" in ran["description"]
    assert f"wrote {unit}" in proc.stdout and "interpolation error <=" in proc.stdout


def test_a_model_that_follows_no_oil_ignores_the_temperature_input(tmp_path):
    out = tmp_path / "plain.fmu"
    run_cli("export", "--fmu", str(out))
    node_speed = 1000 * np.pi / 30  # 1000 rpm and 20 N·m: a node of the table (the map.* grid)
    rows = run_unit(out, [[theta, 20.0, node_speed] for theta in (-50.0, 40.0, 300.0)])["rows"]
    assert rows[0] == rows[1] == rows[2] and rows[0][3] is True
    model = json.loads(run_cli("model", "--torque", "20", "--speed", repr(node_speed), "--json").stdout)["points"][0]
    assert rows[0][0] == pytest.approx(abs(model["loss_torque_nm"]), rel=1e-9)


@pytest.mark.parametrize(("args", "message"), [
    (("--fmu", "g.csv"), "an FMU file ends in .fmu"),
    (("--fmu", "g.fmu", "--oil-temperature-c", "80", "20", "5"), "--oil-temperature-c START STOP STEP"),
    (("--fmu", "g.fmu", "--params", "missing.yaml"), "does not exist"),
])
def test_bad_export_options_are_one_line_and_nothing_is_written(tmp_path, args, message):
    proc = run_cli("export", *args, check=False, cwd=tmp_path)
    assert proc.returncode == 2 and message in proc.stderr and proc.stderr.count("\n") == 1, proc.stderr
    assert list(tmp_path.iterdir()) == []


def test_the_oil_axis_covers_the_range_asked_for_and_not_beyond():
    """A range that is no multiple of its step ended one step beyond it (-20 … 141 for 7 °C steps)."""
    from rollergear_ros.outputs.fmutable import _axis

    assert _axis(-20, 140, 5)[[0, -1]].tolist() == [-20, 140] and len(_axis(-20, 140, 5)) == 33
    odd = _axis(-20, 140, 7)
    assert odd[0] == -20 and odd[-1] == 140 and odd[-2] == 134 and np.all(np.diff(odd) > 0)


#: 1000 instantiate / step / free cycles with hostile inputs, in a process that cannot import this package
RUN_HOSTILE = textwrap.dedent("""
    import json, math, sys
    sys.modules["rollergear_ros"] = None
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    path, cycles = sys.argv[1], int(sys.argv[2])
    md = read_model_description(path)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    folder = extract(path)
    hostile = [math.nan, math.inf, -math.inf, 1e308, -1e308, 5e-324, -0.0, 1e6, -1e6]
    fine = [12.5, 80.0, 40.0]
    wrong = []
    for c in range(cycles):
        unit = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                         instanceName=f"g{c}")
        unit.instantiate(); unit.setupExperiment(startTime=0.0)
        unit.enterInitializationMode(); unit.exitInitializationMode()
        for step in range(3):
            inputs = list(fine)
            inputs[(c + step) % 3] = hostile[(c * 3 + step) % len(hostile)]
            unit.setReal([vr["drive_torque_nm"], vr["drive_speed_rad_s"], vr["oil_temperature_c"]], inputs)
            unit.doStep(currentCommunicationPoint=0.01 * step, communicationStepSize=0.01)  # raises on a bad status
            out = unit.getReal([vr["loss_torque_nm"], vr["loss_power_w"], vr["efficiency"]])
            inside = bool(unit.getBoolean([vr["inside_table"]])[0])
            # a non-finite input of any kind (the oil's too, followed or not) is no point of the table
            table_has_it = all(math.isfinite(v) for v in inputs) and abs(inputs[0]) <= 100 and abs(inputs[1]) <= 400
            if inside != table_has_it or (not inside and not all(math.isnan(v) for v in out)) \
                    or (inside and not math.isfinite(out[0])):
                wrong.append([inputs, out, inside])
        unit.terminate(); unit.freeInstance()
    print(json.dumps({"cycles": cycles, "wrong": wrong[:5]}))
    sys.stdout.flush()
""")


def test_fmpy_validates_the_unit_units_and_structure(tmp_path):
    """The model description is what FMI 2.0 asks: fmpy's validation finds no problem, every Real has a
    unit defined in SI base units."""
    out = tmp_path / "g.fmu"
    run_cli("export", "--fmu", str(out))
    check = textwrap.dedent("""
        import json, sys
        sys.modules["rollergear_ros"] = None
        from fmpy import read_model_description
        from fmpy.validation import validate_fmu
        md = read_model_description(sys.argv[1])
        print(json.dumps({"problems": validate_fmu(sys.argv[1]),
                          "units": {u.name: [u.baseUnit.kg, u.baseUnit.m, u.baseUnit.s, u.baseUnit.K, u.baseUnit.rad,
                                             u.baseUnit.offset] for u in md.unitDefinitions},
                          "of": {v.name: v.unit for v in md.modelVariables if v.type == "Real"}}))
    """)
    proc = subprocess.run([sys.executable, "-c", check, str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout)
    assert got["problems"] == []
    assert got["of"] == {"drive_torque_nm": "N.m", "drive_speed_rad_s": "rad/s", "oil_temperature_c": "degC",
                         "loss_torque_nm": "N.m", "loss_power_w": "W", "efficiency": "1",
                         "interpolation_error_nm": "N.m", "interpolation_error_relative": "1"}
    assert got["units"]["N.m"][:3] == [1, 2, -2] and got["units"]["W"][:3] == [1, 2, -3]
    assert got["units"]["degC"][3] == 1 and got["units"]["degC"][5] == 273.15
    cli = subprocess.run([sys.executable, "-m", "fmpy", "validate", str(out)], capture_output=True,
                         text=True, timeout=300)
    assert cli.returncode == 0 and "No problems found" in cli.stdout, cli.stdout + cli.stderr


def test_hostile_inputs_give_nan_and_never_an_error_or_a_crash(tmp_path):
    """NaN, infinite and out-of-range inputs of any kind: NaN outputs with inside_table false, never an error
    status; 1000 instantiate / step / free cycles of them and the host lives on."""
    out = tmp_path / "g.fmu"
    run_cli("export", "--fmu", str(out))
    proc = subprocess.run([sys.executable, "-c", RUN_HOSTILE, str(out), "1000"], capture_output=True, text=True,
                          timeout=900)
    assert proc.returncode == 0, (proc.returncode, proc.stderr[-2000:])
    got = json.loads(proc.stdout)
    assert got == {"cycles": 1000, "wrong": []}


# ------------------------------------------------------------------------------------ the native binary
C_HOSTS = __import__("pathlib").Path(__file__).parent / "c"


@pytest.fixture(scope="module")
def native(tmp_path_factory):
    """The unit of the bundled parameters, unpacked: (unit, folder, GUID, resources URI)."""
    import re
    import zipfile

    folder = tmp_path_factory.mktemp("native")
    unit = folder / "g.fmu"
    run_cli("export", "--fmu", str(unit))
    unpacked = folder / "x"
    with zipfile.ZipFile(unit) as z:
        z.extractall(unpacked)
    guid = re.search(r'guid="([^"]+)"', (unpacked / "modelDescription.xml").read_text())[1]
    return unit, unpacked, guid, (unpacked / "resources").as_uri()


def _cc(*args) -> None:
    proc = subprocess.run(["gcc", "-std=c99", *map(str, args)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr


def test_the_binary_links_no_python_and_rebuilds_from_the_sources_the_unit_ships(native, tmp_path):
    """The unit's binary needs the C library only (no libpython: no interpreter on the host); built again
    from its own ``sources/`` alone, it gives the shipped binary's outputs to the bit."""
    import shutil
    import zipfile

    unit, unpacked, _guid, _uri = native
    binary = unpacked / "binaries" / "linux64" / "rollergear_gearbox.so"
    dynamic = subprocess.run(["readelf", "-d", str(binary)], capture_output=True, text=True, check=True).stdout
    needed = {line.split("[")[1].rstrip("]") for line in dynamic.splitlines() if "(NEEDED)" in line}
    assert needed and needed <= {"libc.so.6", "libm.so.6"}, needed
    with zipfile.ZipFile(unit) as z:
        assert {"sources/rollergear_gearbox.c", "sources/rollergear_table.h", "sources/fmi2Functions.h"} \
            <= set(z.namelist())
    rebuilt_dir = tmp_path / "rebuilt"
    shutil.copytree(unpacked, rebuilt_dir)
    sources = rebuilt_dir / "sources"
    _cc("-shared", "-fPIC", "-O2", "-I", sources, "-o", rebuilt_dir / "binaries" / "linux64" / "rollergear_gearbox.so",
        sources / "rollergear_gearbox.c", "-lm")
    rebuilt = tmp_path / "rebuilt.fmu"
    with zipfile.ZipFile(rebuilt, "w") as z:
        for path in sorted(rebuilt_dir.rglob("*")):
            if path.is_file():
                z.write(path, path.relative_to(rebuilt_dir).as_posix())
    points = [[40.0, t, w] for t in TORQUES for w in SPEEDS]
    assert run_unit(rebuilt, points)["rows"] == run_unit(unit, points)["rows"]


def test_the_lifecycle_in_any_order_the_standard_allows_under_address_and_undefined_behaviour_sanitizers(
        native, tmp_path):
    """The unit's own sources built with a host under ``-fsanitize=address,undefined``: an instance whose
    calls were refused (a step before initialization, setting an output, a calculated parameter, a string)
    is freed after 0 … 500 other instances came and went, each through a random part of its lifecycle
    (hostile inputs: NaN outputs exactly where not inside the table; reset; terminate; freed in random
    order); bad instantiations (model exchange, another GUID, no resources) give NULL.  No memory error, no
    undefined behaviour, no leak."""
    import os

    _unit, unpacked, guid, uri = native
    host = tmp_path / "lifecycle"
    _cc("-g", "-O1", "-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-I", unpacked / "sources",
        "-o", host, C_HOSTS / "fmu_lifecycle.c", unpacked / "sources" / "rollergear_gearbox.c", "-lm")
    env = os.environ | {"ASAN_OPTIONS": "abort_on_error=0:halt_on_error=1:detect_leaks=1",
                        "UBSAN_OPTIONS": "halt_on_error=1:print_stacktrace=1"}
    for seed, others in ((1, 0), (2, 5), (3, 6), (4, 64), (5, 500)):
        proc = subprocess.run([str(host), guid, uri, str(seed), str(others)], capture_output=True, text=True,
                              timeout=600, env=env)
        assert proc.returncode == 0 and proc.stdout.startswith("ok"), (seed, others, proc.stderr[-3000:])


def test_ten_thousand_short_host_processes_load_run_and_exit_without_an_abort(native, tmp_path):
    """10 000 host processes each load the unit (``dlopen``), instantiate, step, terminate, free, unload and
    exit through the C library's whole teardown: all exit 0 (the Python unit aborted 17 of 118 at exit)."""
    _unit, unpacked, guid, uri = native
    hosts = tmp_path / "hosts"
    _cc("-O2", "-D_POSIX_C_SOURCE=200809L", "-I", unpacked / "sources", "-o", hosts, C_HOSTS / "fmu_hosts.c", "-ldl")
    binary = unpacked / "binaries" / "linux64" / "rollergear_gearbox.so"
    proc = subprocess.run([str(hosts), str(binary), guid, uri, "10000"], capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["10000", "0", "0"], proc.stdout


def test_the_unit_over_a_recorded_warm_up_equals_predict_within_its_stated_error(tmp_path):
    """The recorded warm-up (oil 20 -> 85 degC) stepped through the unit sample by sample equals ``predict`` of
    the recording, sample by sample, within the unit's stated interpolation error times the speed, and its
    energy within the error's share of it."""
    import csv

    from helpers import BAGS

    from rollergear_ros.core.params import load_config
    from rollergear_ros.replay.run import replay

    params = tmp_path / "oil.yaml"  # the warming file without its torque-sensor error: the unit's torque is true
    params.write_text(WARMING.replace("      torque_offset: {enabled: true, offset_nm: 0.3}\n", ""))
    unit = tmp_path / "g.fmu"
    run_cli("export", "--fmu", str(unit), "--params", str(params))
    bag = BAGS / "warmup.mcap"
    run_cli("predict", str(bag), "--params", str(params), "--no-adapt", "--csv", str(tmp_path / "p.csv"))
    with open(tmp_path / "p.csv") as fh:
        predicted = np.array([float(r["loss_power_w"]) for r in csv.DictReader(fh)])
    _summary, batches = replay(bag, load_config(params).with_values({"estimator.adapt": False}), collect=True,
                               show_progress=False)
    columns = {k: np.concatenate([getattr(b, k) for b in batches]) for k in ("temperature_c", "torque_nm",
                                                                             "speed_rad_s", "t_ns")}
    assert len(columns["t_ns"]) == len(predicted) > 20_000
    every = slice(None, None, 3)
    points = np.column_stack([columns["temperature_c"], columns["torque_nm"], columns["speed_rad_s"]])[every]
    ran = run_unit(unit, points.tolist())
    power = np.array([row[1] for row in ran["rows"]])
    inside = np.array([row[3] for row in ran["rows"]])
    assert inside.all()
    error_nm = ran["error"][0]
    speed = np.abs(points[:, 2])
    np.testing.assert_array_less(np.abs(power - predicted[every]), error_nm * speed + 1e-9)
    dt = np.diff(columns["t_ns"][every]) * 1e-9
    energy_unit, energy_predict = np.sum(power[:-1] * dt), np.sum(predicted[every][:-1] * dt)
    assert abs(energy_unit - energy_predict) <= 0.01 * energy_predict, (energy_unit, energy_predict)


def _step_booleans(unit, points) -> tuple[list[tuple[float, bool, bool, bool]], dict[str, str]]:
    """The unit stepped by fmpy at each (oil temperature, torque, speed): (loss, inside_table, inside_calibration,
    inside_rating) per point, and its two range strings."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(unit))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(unit)), modelIdentifier="rollergear_gearbox",
                      instanceName="ranges")
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    rows = []
    for i, (theta, torque, speed) in enumerate(points):
        slave.setReal([vr["oil_temperature_c"], vr["drive_torque_nm"], vr["drive_speed_rad_s"]], [theta, torque, speed])
        slave.doStep(currentCommunicationPoint=0.01 * i, communicationStepSize=0.01)
        flags = slave.getBoolean([vr["inside_table"], vr["inside_calibration"], vr["inside_rating"]])
        rows.append((slave.getReal([vr["loss_torque_nm"]])[0], *map(bool, flags)))
    strings = {n: slave.getString([vr[n]])[0].decode() for n in ("rollergear_calibrated_range",
                                                                   "rollergear_rated_range")}
    slave.terminate()
    slave.freeInstance()
    return rows, strings


def test_the_table_covers_what_the_calibration_saw_and_each_step_says_where_it_is_known(tmp_path):
    """A file calibrated up to 500 rad/s and 150 N·m (beyond the 3000 rpm / 100 N·m rating), oil 20 … 80 °C:
    the table reaches past both (it stopped at the rating: NaN at 480 rad/s), and each step says whether
    the point lies within what the calibration saw (the oil's span too) and within the rating; the unit names
    both ranges.  ``--speed-max-rpm`` and ``--torque-max-nm`` widen it further; beyond the table, NaN."""
    form = ('{"verdict":"effects_found","seen":{"speed_rad_s":500.0,"torque_nm":150.0,'
            '"oil_temperature_c":[20.0,80.0]}}')
    params = tmp_path / "cal.yaml"
    params.write_text(WARMING + f"    calibration:\n      model_form: '{form}'\n")
    unit = tmp_path / "g.fmu"
    said = run_cli("export", "--fmu", str(unit), "--params", str(params)).stdout
    assert "calibrated: |w| <= 500 rad/s, |T| <= 150 N*m, oil 20 ... 80 degC" in said, said
    rows, strings = _step_booleans(unit, [[40.0, 50.0, 200.0], [40.0, 120.0, 480.0], [-10.0, 50.0, 200.0],
                                          [40.0, 50.0, 700.0]])
    assert rows[0][1:] == (True, True, True) and np.isfinite(rows[0][0])
    assert rows[1][1:] == (True, True, False) and np.isfinite(rows[1][0])  # calibrated beyond the rating
    assert rows[2][1:] == (True, False, True)  # the oil colder than any the calibration saw
    assert rows[3][1:] == (False, False, False) and np.isnan(rows[3][0])  # beyond the table
    assert strings["rollergear_calibrated_range"] == "|w| <= 500 rad/s, |T| <= 150 N*m, oil 20 ... 80 degC"
    assert strings["rollergear_rated_range"] == "|w| <= 314.159 rad/s, |T| <= 100 N*m"
    wide = tmp_path / "wide.fmu"
    run_cli("export", "--fmu", str(wide), "--speed-max-rpm", "9000", "--torque-max-nm", "300")
    rows, strings = _step_booleans(wide, [[40.0, 250.0, 900.0], [40.0, 50.0, 200.0]])
    assert rows[0][1:] == (True, False, False) and np.isfinite(rows[0][0])
    assert rows[1][1:] == (True, False, True)  # no calibrated range stated: nothing is known to be calibrated
    assert strings["rollergear_calibrated_range"].startswith("not stated")


def test_without_a_c_compiler_export_is_one_line_and_writes_nothing(tmp_path):
    """No ``$CC`` and no ``cc`` or ``gcc`` on the PATH: one error line naming what to install, exit 2."""
    out = tmp_path / "g.fmu"
    proc = run_cli("export", "--fmu", str(out), env={"PATH": str(tmp_path), "CC": ""}, check=False)
    assert proc.returncode == 2 and not out.exists(), proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("rollergear: error: export --fmu builds the unit's binary "
                                                           "with the machine's C compiler and found none"), proc.stderr
