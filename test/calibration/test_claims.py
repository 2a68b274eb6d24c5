"""The claim is the file: every number about a parameter file comes from one forward path.

Walking the effect registry -- every effect alone and every pair, sensor errors beside loads
included, random parameters inside their ranges -- what calibrate says a file leaves of each sample
(:func:`~rollergear_ros.calibration.samples.file_residual`) equals ``replay``'s residual of the
recording with that file, ``predict``'s loss power equals ``replay``'s, and ``model`` at a sample's
true torque equals ``replay``'s loss there, each to 1e-9.  And end to end: the error ``calibrate``
claims after is what its written file, replayed, leaves.
"""

from __future__ import annotations

import itertools
import math
import json

import numpy as np
import pytest

from rollergear_ros import predict
from rollergear_ros.calibration.samples import file_residual, load_samples
from rollergear_ros.calibration.simulate import DeclaredEffect, SimulationOptions, simulate, write_rig_bag
from rollergear_ros.core.effects import EFFECTS, corrected_torque, reading_errors
from rollergear_ros.core.operating_points import evaluate_points
from rollergear_ros.core.params import load_config
from rollergear_ros.replay.run import replay

from helpers import BAGS, run_cli

NAMES = list(EFFECTS)
CASES = [(n,) for n in NAMES] + list(itertools.combinations(NAMES, 2))


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    """A warm-up drive (oil 25 -> 70 degC, both directions, loads) with a drag and a load friction, and its
    samples as calibrate reads them."""
    path = tmp_path_factory.mktemp("claims") / "drive.mcap"
    opts = SimulationOptions(profile="warmup", rate_hz=25.0, seed=11,
                             effects=[DeclaredEffect.parse("drag_speed:c=3e-4,p=1.4"),
                                      DeclaredEffect.parse("load_dependent:c=0.002,q=1.1")])
    write_rig_bag(simulate(load_config(), opts), opts, path)
    return path, load_samples([path], load_config())


def _random_file(names: tuple[str, ...], seed: int):
    """The default file with ``names`` enabled at random values: the coefficient 0.5-1.5x the simulator's
    typical one, a profiled exponent anywhere in its search range."""
    rng = np.random.default_rng(seed)
    values = {}
    for name in names:
        effect = EFFECTS[name]
        values[f"effects.{name}.enabled"] = True
        ranges = effect.profiled_ranges()
        for p in effect.parameters:
            value = p.default if p.simulated is None else p.simulated
            if p.short == effect.coefficient:
                value = value * rng.uniform(0.5, 1.5) if value else rng.uniform(0.01, 0.05)
            elif p.short in ranges:
                lo, hi = ranges[p.short]
                value = rng.uniform(lo, hi)
            values[f"effects.{name}.{p.key}"] = float(value)
    return load_config().with_values(values)


def _by_time(batches, field: str, t_ns: np.ndarray) -> np.ndarray:
    t = np.concatenate([b.t_ns for b in batches])
    v = np.concatenate([getattr(b, field) for b in batches])
    i = np.searchsorted(t, t_ns)
    assert np.array_equal(t[i], t_ns)
    return v[i]


@pytest.mark.parametrize("names", CASES, ids=["+".join(c) for c in CASES])
def test_calibrate_replay_predict_and_model_give_one_answer(drive, names):
    path, data = drive
    config = _random_file(names, seed=len(names) * 100 + NAMES.index(names[0]) * 10 + NAMES.index(names[-1]))
    _summary, batches = replay(path, config, collect=True, show_progress=False)
    # what calibrate says the file leaves of each sample is replay's residual
    claimed = file_residual(data, config)
    replayed = _by_time(batches, "residual_nm", data.t_ns)
    np.testing.assert_array_equal(np.isnan(claimed), np.isnan(replayed))
    np.testing.assert_allclose(claimed, replayed, rtol=0, atol=1e-9, equal_nan=True)
    # predict of the recorded drive is its replay, sample by sample
    got = predict(path, config, collect=True)
    assert got.recorded
    t_all = np.concatenate([b.t_ns for b in batches])
    np.testing.assert_array_equal(got.t_ns, t_all)
    np.testing.assert_allclose(got.loss_power_w, np.concatenate([b.loss_power_w for b in batches]), rtol=1e-12,
                               atol=1e-9)
    # model at a sample's true torque (the reading corrected by the file's sensor errors) is replay's loss
    # there -- for effects without a memory, with the file's coefficients as written and a given speed noise
    if any(EFFECTS[n].state_step is not None for n in names):
        return
    fixed = config.with_values({"estimator.adapt": False, "estimator.speed_noise_rad_s": data.sign_width_rad_s})
    still_summary, still = replay(path, fixed, collect=True, show_progress=False)
    still_counts = still_summary.skipped
    pick = np.linspace(0, len(data.t_ns) - 1, 25).astype(int)
    offset, gain = reading_errors(fixed.effects.active())
    for i in pick:
        t_ns = data.t_ns[i:i + 1]
        loss = _by_time(still, "loss_torque_nm", t_ns)[0]
        true_torque = corrected_torque(data.torque[i], offset, gain)
        theta = float(data.temperature[i]) if np.isfinite(data.temperature[i]) else None
        point = evaluate_points(fixed, [true_torque], [data.speed[i]], theta)
        if math.isnan(loss):  # laws in the load that lock the drive there: no loss in either
            assert math.isnan(point.loss_torque_nm[0]) and still_counts["load_unbalanced"], (names, i)
            continue
        assert point.loss_torque_nm[0] == pytest.approx(loss, rel=1e-9, abs=1e-12), (names, i)


def _lagged_drive(folder):
    """A drive whose output torque channel is 30 ms late (a DAQ on its own clock)."""
    path = folder / "lagged.mcap"
    opts = SimulationOptions(profile="drive_cycle", rate_hz=200.0, seed=4, output_lag_s=0.03,
                             effects=[DeclaredEffect.parse("drag_speed:c=3e-4,p=1.4")])
    write_rig_bag(simulate(load_config(), opts), opts, path)
    return path


def _offset_under_load(folder):
    """A lossy drive (a load friction half the drive torque) whose torque sensor reads 0.05 N·m high: the
    load friction sees the corrected torque |T - b| in the estimator (calibrate claimed 2.26 N·m per
    sample of the file that leaves 0.03)."""
    path = folder / "offset.mcap"
    opts = SimulationOptions(profile="bidirectional_map", rate_hz=100.0, seed=3,
                             effects=[DeclaredEffect.parse("load_dependent:c=0.5,q=1.0"),
                                      DeclaredEffect.parse("torque_offset:b=0.05")])
    write_rig_bag(simulate(load_config(), opts), opts, path)
    return path


@pytest.mark.parametrize("recording", ["rig_map_drag", "lagged", "offset_under_load"])
def test_the_error_calibrate_claims_after_is_what_its_written_file_leaves(tmp_path, recording):
    """End to end: calibrate writes a file; replayed on the recording, it leaves of the samples calibrate
    analysed exactly the per-sample error calibrate claimed -- also where the selection ran on samples
    aligned by a lag (the file carries it, replay aligns the channel as the selection did)."""
    bag = {"rig_map_drag": lambda: BAGS / "rig_map_drag.mcap", "lagged": lambda: _lagged_drive(tmp_path),
           "offset_under_load": lambda: _offset_under_load(tmp_path)}[recording]()
    out = tmp_path / "cal.yaml"
    result = json.loads(run_cli("calibrate", str(bag), "--out", str(out), "--json").stdout)
    assert result["written"]
    written = load_config(out)
    data = load_samples([bag], load_config())
    _summary, batches = replay(bag, written, collect=True, show_progress=False)
    r = _by_time(batches, "residual_nm", data.t_ns)
    r = r[np.isfinite(r)]
    claimed = result["sample_level_errors"]["after"]["rmse_nm"]
    assert float(np.sqrt(np.mean(r * r))) == pytest.approx(claimed, rel=1e-9)
    if recording == "lagged":  # the file carries the lag the selection aligned: replay aligns it alike
        assert written.estimator.output_torque_lag_s == pytest.approx(0.03, abs=0.002)
        assert any("the written file carries them" in n for n in result["notes"]), result["notes"]
        assert claimed < 0.05  # the lag's 0.26 N·m gone (the noise floor: 0.03)
        said = run_cli("replay", str(bag), "--params", str(out)).stdout
        assert "channel lags (the parameter file's): output_torque 29.8 ms late" in said
        assert "channel lags (the parameter file's): output_torque 29.8 ms late" in run_cli(
            "predict", str(bag), "--params", str(out)).stdout


def test_a_tables_rows_replayed_leave_what_calibrate_claims_for_them(tmp_path):
    """A table of a slow drive's dwell means, rows down to 1 rpm (far below the speed under which a
    recording's loss is its torque balance at the file's ratio, and within any speed noise of 0):
    ``replay`` of the table estimates every row as calibrate does -- an operating point on its own,
    the power balance of its own torques -- and leaves what calibrate claims for the rows, to 1e-9."""
    from rigs import lifting_table

    fit, cmap = lifting_table(tmp_path, (1, 1.5, 2, 3, 4, 6, 8, 12, 20, 30, 50, 80, 120, 200), "fit", seed=0,
                              offset_nm=0.001)
    p = tmp_path / "p.yaml"
    p.write_text("/**/loss_estimator:\n  ros__parameters:\n    estimator: {paper_model: false}\n")
    written = tmp_path / "cal.yaml"
    run_cli("calibrate", str(fit), "--channels", str(cmap), "--params", str(p), "--out", str(written))
    held, _ = lifting_table(tmp_path, (1.2, 1.7, 2.5, 3.5, 5, 7, 10, 14, 25, 40), "held", seed=1, offset_nm=0.001)
    claimed = json.loads(run_cli("calibrate", str(held), "--channels", str(cmap), "--params", str(written),
                                 "--json").stdout)["error_before"]["rmse_nm"]
    out = tmp_path / "rows.csv"
    run_cli("replay", str(held), "--channels", str(cmap), "--params", str(written), "--csv", str(out), "--no-png")
    import csv

    with out.open() as fh:
        rows = list(csv.DictReader(fh))
    residual = np.array([float(r["residual_torque [N*m]"]) for r in rows])
    assert len(rows) == 20 and np.isfinite(residual).all(), residual
    assert np.sqrt(np.mean(residual ** 2)) == pytest.approx(claimed, rel=1e-9, abs=1e-15)
    # predict of the table is its replay, row by row (a file that adapts: rows adapt in neither)
    adapting = tmp_path / "adapting.yaml"
    adapting.write_text(written.read_text().replace("adapt: false", "adapt: true"))
    got = predict(held, adapting, channels=cmap, collect=True)
    _s, batches = replay_table(held, cmap, adapting)
    np.testing.assert_allclose(got.loss_power_w, np.concatenate([b.loss_power_w for b in batches]), rtol=1e-12,
                               atol=1e-15)


def test_a_tables_import_calibrates_as_the_table_and_its_claim_is_what_replay_of_it_leaves(tmp_path):
    """``import`` of a steady-state table makes an MCAP whose samples are the table's rows.  ``calibrate``
    of that MCAP is ``calibrate`` of the table: the same effects and values, the same written file (the
    table's ratio; its torque readings' offset tested), and the claim that ``replay`` of the MCAP
    leaves.  A recording beside it is refused in one line."""
    from rigs import lifting_table

    fit, cmap = lifting_table(tmp_path, (1, 1.5, 2, 3, 4, 6, 8, 12, 20, 30, 50, 80, 120, 200), "fit", seed=0,
                              offset_nm=0.001)
    p = tmp_path / "p.yaml"
    p.write_text("/**/loss_estimator:\n  ros__parameters:\n    estimator: {paper_model: false}\n")
    bag = tmp_path / "fit.mcap"
    run_cli("import", str(fit), "--channels", str(cmap), "--out", str(bag))
    from_table, from_bag = tmp_path / "table.yaml", tmp_path / "bag.yaml"
    table = json.loads(run_cli("calibrate", str(fit), "--channels", str(cmap), "--params", str(p), "--json",
                               "--out", str(from_table)).stdout)
    imported = json.loads(run_cli("calibrate", str(bag), "--params", str(p), "--json", "--out", str(from_bag)).stdout)
    assert [e["name"] for e in imported["effects"]] == [e["name"] for e in table["effects"]]
    assert "torque_offset" in [e["name"] for e in table["effects"]]  # the readings' offset, as in the table
    for mine, theirs in zip(imported["effects"], table["effects"]):
        assert mine["params"] == pytest.approx(theirs["params"], rel=1e-9, abs=1e-15), mine["name"]
    a, b = load_config(from_table).to_flat(), load_config(from_bag).to_flat()
    assert a.keys() == b.keys() and a["gearbox.ratio"] == b["gearbox.ratio"] == 60
    cov_a, cov_b = (json.loads(f.pop("calibration.covariance")) for f in (a, b))
    assert cov_a["keys"] == cov_b["keys"]
    # the rows' losses come back as T − (T − L): rounding the exponents' numerical derivatives magnify
    ca, cb = np.array(cov_a["matrix"]), np.array(cov_b["matrix"])
    scale = np.sqrt(np.outer(np.diag(ca), np.diag(ca)))
    assert np.max(np.abs(ca - cb) / scale) < 1e-7
    for key, value in a.items():  # the model's form is JSON: compared number by number
        mine, theirs = (json.loads(v) if key.startswith("calibration.") else v for v in (b[key], value))
        assert mine == _approx(theirs), key
    claimed = json.loads(run_cli("calibrate", str(bag), "--params", str(from_bag), "--json").stdout)
    _s, batches = replay(bag, load_config(from_bag), collect=True, show_progress=False)
    residual = np.concatenate([b.residual_nm for b in batches])
    assert len(residual) == len(fit.read_text().splitlines()) - 1 and np.isfinite(residual).all()
    assert np.sqrt(np.mean(residual ** 2)) == pytest.approx(claimed["error_before"]["rmse_nm"], rel=1e-9, abs=1e-15)
    mixed = run_cli("calibrate", str(bag), str(BAGS / "rig_map_drag.mcap"), "--params", str(p), check=False)
    assert mixed.returncode == 2 and "not both" in mixed.stderr and len(mixed.stderr.strip().splitlines()) == 1


def _approx(value):
    """``value`` with every float in it compared to 1e-9 (nested lists and dicts, as JSON holds them)."""
    if isinstance(value, float):
        return pytest.approx(value, rel=1e-9, abs=1e-15)
    if isinstance(value, list):
        return [_approx(v) for v in value]
    if isinstance(value, dict):
        return {k: _approx(v) for k, v in value.items()}
    return value


def replay_table(table, cmap, params):
    """``replay`` of a steady-state table as the command line reads it (imported first)."""
    from rollergear_ros.sources.importer import as_mcap

    with as_mcap([table], cmap) as (bag,):
        return replay(bag, load_config(params), collect=True, show_progress=False)
