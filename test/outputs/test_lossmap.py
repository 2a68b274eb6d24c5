"""``rollergear map``: VECTO-valid loss maps of the calibrated model.

The written files are checked by :func:`vecto_rules`, written here from VECTO's own reader
(``VectoCSVFile.Read`` + ``TransmissionLossMapReader`` + the ranges of ``GearLossMapEntry``,
vecto-sim) and not from the package, and shown to accept VECTO's published generic maps.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from rollergear_ros.core.model import LossModel

from helpers import BAGS, CONFIG, REALDATA, run_cli

VECTO_GENERIC = REALDATA / "vecto_generic_lossmaps"
_UNIT = re.compile(r"\[.*?\]|<|>")


def vecto_rules(path: Path) -> list[str]:
    """What VECTO's loss-map reader would reject in ``path`` (empty list: accepted).

    VECTO CSV: ``,`` delimiter, ``.`` decimal mark, lines starting with ``#`` are comments, a
    cell is cut at ``#``, one header line whose ``[unit]`` parts are dropped; a loss map has the
    columns Input Speed, Input Torque, Torque Loss, at least four data lines, input speed in
    0…1e6 rpm and torque loss in 0…1e6 N·m; the points are triangulated in (speed,
    ``T_in − T_loss``), so over T_in at each speed ``T_in − T_loss`` must rise.
    """
    problems = []
    lines = [ln for ln in path.read_text(encoding="utf-8").splitlines()
             if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        return ["empty"]
    header = [_UNIT.sub("", c.split("#")[0]).strip() for c in lines[0].split(",")]
    wanted = ["Input Speed", "Input Torque", "Torque Loss"]
    if not all(w in header for w in wanted):
        problems.append(f"header {header} lacks {wanted}")
        return problems
    idx = [header.index(w) for w in wanted]
    rows = []
    for k, ln in enumerate(lines[1:], start=2):
        cells = [c.split("#")[0].strip() for c in ln.split(",")]
        try:
            rows.append([float(cells[i]) for i in idx])
        except (ValueError, IndexError):
            problems.append(f"data line {k}: not numeric: {ln!r}")
    data = np.array(rows, dtype=float).reshape(-1, 3)
    if len(data) < 4:
        problems.append(f"{len(data)} data lines (VECTO needs at least 4)")
    if ((data[:, 0] < 0) | (data[:, 0] > 1e6)).any():
        problems.append("input speed outside 0..1e6 rpm")
    if ((data[:, 2] < 0) | (data[:, 2] > 1e6)).any():
        problems.append("torque loss outside 0..1e6 N·m")
    for n in np.unique(data[:, 0]):
        at = data[data[:, 0] == n]
        at = at[np.argsort(at[:, 1])]
        if (np.diff(at[:, 1] - at[:, 2]) <= 0).any():
            problems.append(f"T_in - T_loss does not rise with T_in at {n:g} rpm")
    if len(np.unique(data[:, 0])) < 2 or len(np.unique(data[:, 1])) < 2:
        problems.append("the points do not span an area (VECTO triangulates them)")
    return problems


def read_map(path: Path) -> np.ndarray:
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    assert lines[0] == "Input Speed [rpm],Input Torque [Nm],Torque Loss [Nm]"
    return np.array([ln.split(",") for ln in lines[1:]], dtype=float)


@pytest.mark.skipif(not VECTO_GENERIC.exists(), reason=f"no shared real data at {VECTO_GENERIC}")
def test_the_vecto_rules_accept_vectos_own_generic_maps():
    maps = sorted(VECTO_GENERIC.rglob("*.vtlm"))
    assert len(maps) >= 10
    for path in maps:
        assert vecto_rules(path) == [], path


def test_the_vecto_rules_reject_what_vecto_rejects(tmp_path):
    header = "Input Speed [rpm],Input Torque [Nm],Torque Loss [Nm]\n"
    good = "0,-10,1\n0,10,1\n1000,-10,1\n1000,10,1\n"
    cases = {
        "negative speed": "-1000,-10,1\n-1000,10,1\n" + good,
        "negative loss": good + "2000,-10,-0.5\n2000,10,1\n",
        "three rows": "0,-10,1\n0,10,1\n1000,10,1\n",
        "folded": good + "2000,-10,1\n2000,10,25\n",
    }
    assert vecto_rules(_write(tmp_path / "good.vtlm", header + good)) == []
    for name, body in cases.items():
        assert vecto_rules(_write(tmp_path / f"{name}.vtlm", header + body)), name


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_map_obeys_vectos_rules_and_reverse_rotation_goes_to_its_own_file(tmp_path, config):
    out = tmp_path / "map.vtlm"
    proc = run_cli("map", "--out", str(out), "--speed-rpm", "0", "2000", "500", "--torque-nm", "-50", "50", "25",
                   "--both-directions")
    reverse = tmp_path / "map_reverse.vtlm"
    assert vecto_rules(out) == [] and vecto_rules(reverse) == []
    text = out.read_text()
    for line in ("# rollergear_ros", "ratio (input/output speed) 1.36842", f"parameters: {CONFIG}",
                 "accepted effects: none", "written 20"):
        assert line in text, line
    assert "REVERSE rotation" in reverse.read_text() and "REVERSE" not in text
    lm = LossModel(config.gearbox)
    forward, backward = read_map(out), read_map(reverse)
    assert len(forward) == len(backward) == 5 * 5
    assert sorted(set(forward[:, 0])) == [0, 500, 1000, 1500, 2000]
    w = forward[:, 0] * 2 * np.pi / 60
    np.testing.assert_allclose(forward[:, 2], lm.loss_magnitude(forward[:, 1], w), rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(backward[:, 2], lm.loss_magnitude(-backward[:, 1], -w), rtol=1e-5, atol=1e-9)
    for png in (tmp_path / "map.png", tmp_path / "map_reverse.png"):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    assert "the paper's model alone: 100 % of this map's loss, summed over its points" in proc.stdout


def test_map_grid_from_the_parameter_file_ends_at_the_rated_speed(tmp_path):
    p = tmp_path / "grid.yaml"
    p.write_text("/**/loss_estimator:\n  ros__parameters:\n    gearbox: {rated_speed_rpm: 1500.0}\n"
                 "    map: {speed_min_rpm: 500.0, speed_step_rpm: 500.0, torque_min_nm: -20.0, "
                 "torque_max_nm: 20.0, torque_step_nm: 10.0, both_directions: true}\n")
    out = tmp_path / "m.vtlm"
    run_cli("map", "--out", str(out), "--params", str(p), "--no-plot")
    for path in (out, tmp_path / "m_reverse.vtlm"):
        data = read_map(path)
        assert sorted(set(data[:, 0])) == [500, 1000, 1500]
        assert sorted(set(data[:, 1])) == [-20, -10, 0, 10, 20]
    bad = tmp_path / "bad.yaml"
    bad.write_text("/**/loss_estimator:\n  ros__parameters:\n    map: {speed_min_rpm: 500.0, speed_max_rpm: 100.0}\n")
    proc = run_cli("map", "--params", str(bad), "--out", str(out), check=False)
    assert proc.returncode == 2 and "map.speed_max_rpm" in proc.stderr


@pytest.mark.parametrize(("grid", "message"), [
    (("--speed-rpm", "-1000", "1000", "500"), "speeds >= 0"),
    (("--torque-nm", "0", "50", "10"), "both torque signs"),
    (("--speed-rpm", "1000", "1000", "100"), "at least two speeds"),
])
def test_map_refuses_grids_vecto_would_not_accept(tmp_path, grid, message):
    out = tmp_path / "m.vtlm"
    proc = run_cli("map", "--out", str(out), "--no-plot", *grid, check=False)
    assert proc.returncode == 2 and message in proc.stderr and proc.stderr.count("\n") == 1
    assert not out.exists()


def test_map_warns_when_a_recording_visited_points_outside_it(tmp_path):
    out = tmp_path / "m.vtlm"
    small = run_cli("map", "--out", str(out), "--no-plot", "--speed-rpm", "0", "500", "100",
                    "--torque-nm", "-5", "5", "5", "--recording", str(BAGS / "rig_map.mcap"))
    assert "rig_map.mcap" in small.stderr and "% of the samples lie outside the map" in small.stderr
    covering = run_cli("map", "--out", str(out), "--no-plot", "--recording", str(BAGS / "rig_map.mcap"))
    assert "warning" not in covering.stderr and "every sample lies inside the map" in covering.stdout


def test_map_of_a_calibrated_parameter_file_equals_replays_estimate_at_the_same_points(tmp_path):
    """The energy manager gets what the estimator computes: a recording that visits the map's
    grid (read by a torque sensor with the accepted offset and gain errors, at the map's oil
    temperature) replays to the losses the map holds."""
    from rollergear_ros.recordings.bagwriter import BagWriter
    from rollergear_ros.recordings.messages import stamp
    from rollergear_ros.base.interface import MessageType
    from rollergear_ros.core.params import config_to_yaml, load_config
    from rollergear_ros.replay.run import replay

    from helpers import CALIBRATED

    config = load_config(CONFIG, CALIBRATED)
    params = tmp_path / "calibrated.yaml"
    params.write_text(config_to_yaml(config))
    out = tmp_path / "map.vtlm"
    run_cli("map", "--params", str(params), "--out", str(out), "--no-plot", "--oil-temperature-c", "70",
            "--speed-rpm", "0", "3000", "250", "--torque-nm", "-100", "100", "10")
    rows = read_map(out)
    assert "accepted effects: drag_speed" in out.read_text()
    # the baseline differs: the map is not the paper's model alone
    bare = LossModel(config.gearbox).loss_magnitude(rows[:, 1], rows[:, 0] * 2 * np.pi / 60)
    assert np.mean(rows[:, 2] - bare > 1e-3) > 0.9

    bag = tmp_path / "grid.mcap"
    offset, gain = CALIBRATED["effects.torque_offset.offset_nm"], CALIBRATED["effects.torque_gain.gain"]
    t_ns = 10**9 + np.arange(len(rows), dtype=np.int64) * 10**6
    with BagWriter(bag) as bw:
        bw.write_float64_series("/rollergear/motor/torque", t_ns, rows[:, 1] * (1 + gain) + offset)
        bw.write_float64_series("/rollergear/motor/speed", t_ns, rows[:, 0] * 2 * np.pi / 60)
        for t in t_ns:
            bw.write_message("/rollergear/oil/temperature", MessageType.TEMPERATURE, int(t),
                             {"header": {"stamp": stamp(int(t)), "frame_id": "oil"}, "temperature": 70.0,
                              "variance": 0.0})
    summary, batches = replay(bag, load_config(params), collect=True, show_progress=False)
    estimated = np.concatenate([np.abs(b.loss_torque_nm) for b in batches])
    assert len(estimated) == len(rows) and not any(summary.skipped.values())
    np.testing.assert_allclose(estimated, rows[:, 2], rtol=1e-5, atol=1e-9)  # the map's 6 significant digits


def test_the_torque_range_comes_from_the_gearbox_rating(tmp_path):
    p = tmp_path / "rated.yaml"
    p.write_text("/**/loss_estimator:\n  ros__parameters:\n"
                 "    gearbox: {rated_speed_rpm: 1000.0, rated_torque_nm: 40.0}\n"
                 "    map: {speed_step_rpm: 500.0, torque_step_nm: 20.0}\n")
    out = tmp_path / "m.vtlm"
    run_cli("map", "--out", str(out), "--params", str(p), "--no-plot")
    assert sorted(set(read_map(out)[:, 1])) == [-40, -20, 0, 20, 40]


def test_the_measured_map_of_a_rig_run_is_each_cells_energy_lost_over_its_angle(tmp_path):
    """``map --recording BAG --measured``: per operating point with enough samples, the loss a rig
    engineer computes from the recording -- Σ(P_in − P_out)·dt over Σ|ω_in|·dt of the samples nearest
    that node -- in VECTO's format beside the model's map, with its uncertainty in the table."""
    import csv

    from bagtools import float_series, read_mcap_ros2

    params = tmp_path / "sensors.yaml"
    params.write_text("/**/loss_estimator:\n  ros__parameters:\n    sensors: {input_torque_full_scale_nm: 200.0, "
                      "input_torque_reading_pct: 0.05, output_torque_full_scale_nm: 500.0, "
                      "output_torque_reading_pct: 0.05}\n")
    bag = BAGS / "rig_map_drag.mcap"
    out = tmp_path / "lossmap.vtlm"
    proc = run_cli("map", "--out", str(out), "--params", str(params), "--recording", str(bag), "--measured",
                   "--no-plot")
    measured = tmp_path / "lossmap_measured_rig_map_drag.vtlm"
    assert "measured map of" in proc.stdout and out.exists()
    for path in (measured, tmp_path / "lossmap_measured_rig_map_drag_reverse.vtlm"):
        assert vecto_rules(path) == [], path
    rows = list(csv.DictReader((tmp_path / "lossmap_measured_rig_map_drag.csv").open()))
    assert len(rows) >= 40 and all(int(r["samples"]) >= 100 for r in rows)
    raw = read_mcap_ros2(bag)
    _, tq = float_series(raw, "/rollergear/motor/torque")
    _, w = float_series(raw, "/rollergear/motor/speed")
    _, tq_out = float_series(raw, "/rollergear/output/torque")
    _, w_out = float_series(raw, "/rollergear/output/speed")
    rpm = w * 30 / np.pi
    forward = read_map(measured)
    for r in rows[::7]:
        n, t = float(r["speed_rpm"]), float(r["torque_nm"])
        mine = (np.rint(rpm / 100) * 100 == n) & (np.rint(tq / 5) * 5 == t)
        mine[0] = False  # the first sample: no step before it
        lost = np.sum(tq[mine] * w[mine] - tq_out[mine] * w_out[mine])  # 10 ms each
        angle = np.sum(np.abs(w[mine]))
        assert float(r["measured_loss_nm"]) == pytest.approx(lost / angle, rel=1e-7)  # the table: 8 digits
        assert 0 < float(r["measured_loss_uncertainty_nm"]) < 0.5 * float(r["measured_loss_nm"])
        assert float(r["measured_loss_nm"]) > float(r["model_loss_nm"])  # the drag the model lacks
        if n > 0:  # VECTO's row: forward rotation as it is
            (row,) = forward[(forward[:, 0] == n) & (forward[:, 1] == t)]
            assert row[2] == pytest.approx(lost / angle, rel=1e-5)
    proc = run_cli("map", "--out", str(out), "--measured", check=False)
    assert proc.returncode == 2 and "--measured needs a --recording" in proc.stderr
    from rollergear_ros.recordings.bagwriter import BagWriter

    drive_only = tmp_path / "drive_only.mcap"  # a drive without an output torque sensor
    with BagWriter(drive_only) as writer:
        t = 10**18 + np.arange(500) * 10_000_000
        writer.write_float64_series("/rollergear/motor/torque", t, np.full(500, 20.0))
        writer.write_float64_series("/rollergear/motor/speed", t, np.full(500, 100.0))
    proc = run_cli("map", "--out", str(tmp_path / "x.vtlm"), "--recording", str(drive_only), "--measured",
                   "--no-plot", check=False)
    assert proc.returncode == 2 and "no measured output torque: no measured loss map" in proc.stderr


@pytest.mark.parametrize("grid", [["--speed-rpm", "0", "19000", "0.01"], ["--speed-rpm", "0", "1000000", "0.5"],
                                  ["--speed-rpm", "0", "1000", "1e-6"],
                                  ["--speed-rpm", "0", "3000", "1", "--torque-nm", "-100", "100", "0.1"]])
def test_a_grid_too_large_is_refused_before_anything_is_allocated(tmp_path, grid):
    """``map --speed-rpm 0 19000 0.01`` took 5.7 GB, a step of 1e-6 a memory traceback: one line, exit 2."""
    proc = run_cli("map", "--out", str(tmp_path / "m.vtlm"), *grid, check=False, timeout=120)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "at most" in proc.stderr, proc.stderr
    assert not list(tmp_path.iterdir())


def test_a_parameter_file_or_a_run_time_change_with_a_grid_too_large_is_refused():
    from rollergear_ros.base.errors import ParameterError
    from rollergear_ros.core.params import MAX_MAP_AXIS_POINTS, load_config

    config = load_config()
    with pytest.raises(ParameterError, match="map.speed_step_rpm.*at most"):
        config.with_values({"map.speed_step_rpm": 0.001})
    with pytest.raises(ParameterError, match="map.torque_step_nm.*cells; at most"):
        config.with_values({"map.speed_step_rpm": 1.0, "map.torque_step_nm": 0.1})
    edge = config.map.last_speed_rpm(config.gearbox) / (MAX_MAP_AXIS_POINTS - 1)
    assert config.with_values({"map.speed_step_rpm": edge, "map.torque_step_nm": 50.0}).map.speed_step_rpm == edge


def test_laws_in_the_load_that_lock_a_back_driven_drive_are_said_by_model_and_refused_by_map(tmp_path):
    """A back-driving friction growing with the cube of the load (c = 0.003, q = 3) locks the drive once the
    output back-drives it with some 7 N·m: no output-side load balances the drive torque there.  ``model``
    says so at such a point (not "outside the plausible range"), ``map`` refuses the grid in one line
    naming the first such point; a grid whose overrun stays below the lock is mapped."""
    p = tmp_path / "locked.yaml"
    p.write_text("/**/loss_estimator:\n  ros__parameters:\n    effects:\n      backdrive: {enabled: true, c: 0.003, "
                 "q: 3.0}\n")
    text = run_cli("model", "--params", str(p), "--torque", "-90", "-5", "90", "--speed", "100").stdout
    rows = {ln.split()[0]: ln for ln in text.splitlines() if ln.strip() and ln.split()[0] in ("-90", "-5", "90")}
    assert "laws in the load lock the drive" in rows["-90"] and "plausible" not in rows["-90"], text
    assert "skipped" not in rows["-5"] and "skipped" not in rows["90"], text
    out = tmp_path / "locked.vtlm"
    proc = run_cli("map", "--params", str(p), "--out", str(out), "--no-plot", "--both-directions", "--torque-nm",
                   "-100", "100", "10", "--speed-rpm", "0", "2000", "500", check=False)
    assert proc.returncode == 2 and not out.exists(), proc.stderr
    [line] = proc.stderr.strip().splitlines()
    assert "laws in the load lock the drive" in line and "T = -100 N·m" in line, line
    run_cli("map", "--params", str(p), "--out", str(out), "--no-plot", "--torque-nm", "-5", "100", "5",
            "--speed-rpm", "0", "2000", "500")
    assert out.exists()
