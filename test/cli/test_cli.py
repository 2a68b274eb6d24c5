"""CLI: model, figures, map run as subprocesses; outputs checked against the model."""

from __future__ import annotations

import csv
import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rollergear_ros.core.model import BREAKDOWN_KEYS, LossModel

from helpers import BAGS, REALDATA, ROOT, run_cli


def test_model_json_matches_the_library(config):
    proc = run_cli("model", "--torque", "1", "10", "-50", "--speed", "104.72", "-20", "--json")
    points = json.loads(proc.stdout)["points"]
    assert len(points) == 6
    lm = LossModel(config.gearbox, config.estimator.min_torque_for_efficiency_nm,
                   config.estimator.min_speed_for_efficiency_rad_s)
    for p in points:
        res = lm.evaluate(np.array([p["torque_nm"]]), np.array([p["speed_rad_s"]]))
        assert p["loss_torque_nm"] == pytest.approx(res.loss_torque_nm[0], rel=1e-12)
        assert p["loss_power_w"] == pytest.approx(res.loss_power_w[0], rel=1e-12)
        assert p["efficiency"] == pytest.approx(res.efficiency[0], rel=1e-12)
        assert set(p["breakdown_nm"]) == set(BREAKDOWN_KEYS)
        assert sum(p["breakdown_nm"].values()) == pytest.approx(abs(p["loss_torque_nm"]), rel=1e-12)
    first = points[0]
    assert first["torque_nm"] == 1 and round(first["loss_torque_nm"], 5) == 0.02129


def test_model_table_and_csv_input(tmp_path):
    f = tmp_path / "pts.csv"
    f.write_text("torque_nm,speed_rad_s\n10,104.72\n-10,104.72\n0,0\n")
    out = run_cli("model", "--csv", str(f)).stdout
    lines = [ln for ln in out.splitlines() if ln.strip() and not ln.startswith("-")]
    assert len(lines) == 5 and "0.06783" in out and "n/a" in out  # the header, 3 points, the sign's rule
    assert lines[-1].startswith("the loss's sign near standstill")


@pytest.mark.parametrize("args, message", [
    (["model", "--torque", "1"], "give --torque and --speed"),
    (["model", "--torque", "1", "--speed", "1", "--params", "/no/such.yaml"], "does not exist"),
    (["map", "--speed-rpm", "100", "0", "10"], "bad grid"),
])
def test_bad_input_is_one_clear_line(args, message):
    proc = run_cli(*args, check=False)
    assert proc.returncode == 2
    assert message in proc.stderr and "Traceback" not in proc.stderr


def test_bad_csv_rows_rejected(tmp_path):
    f = tmp_path / "bad.csv"
    f.write_text("torque_nm,speed_rad_s\n1,nan\n")
    proc = run_cli("model", "--csv", str(f), check=False)
    assert proc.returncode == 2 and "not finite" in proc.stderr


def test_nan_on_command_line_rejected():
    proc = run_cli("model", "--torque", "nan", "--speed", "1", check=False)
    assert proc.returncode == 2 and "not a finite number" in proc.stderr


def test_bad_params_file_names_the_parameter(tmp_path):
    p = tmp_path / "p.yaml"
    p.write_text("loss_estimator:\n  ros__parameters:\n    gearbox: {f1: 0.4}\n")
    proc = run_cli("model", "--torque", "1", "--speed", "1", "--params", str(p), check=False)
    assert proc.returncode == 2 and "gearbox.f1" in proc.stderr and "> 0.5" in proc.stderr


def test_figures_written(tmp_path):
    run_cli("figures", "--out", str(tmp_path))
    for i in range(6, 12):
        png = tmp_path / f"fig{i:02d}.png"
        assert png.stat().st_size > 10_000
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rows = list(csv.reader((tmp_path / "figures.csv").open()))
    header, data = rows[0], np.array(rows[1:], dtype=float)
    t = data[:, 0]
    eta = data[:, header.index("fig6:default")]
    i100 = int(np.argmin(np.abs(t - 100)))
    assert round(100 * eta[i100], 3) == pytest.approx(99.569, abs=1e-3)


def test_model_uses_the_accepted_effects_of_the_parameter_file(tmp_path):
    """``model --params calibrated.yaml`` evaluates what the estimator does (the paper's model plus
    the accepted effects) and shows each effect's share."""
    from rollergear_ros.core.params import config_to_yaml, load_config

    params = tmp_path / "calibrated.yaml"
    params.write_text(config_to_yaml(load_config(None, {"effects.drag_speed.enabled": True,
                                                         "effects.drag_speed.c": 2e-4, "effects.drag_speed.p": 1.5})))
    args = ("model", "--torque", "10", "50", "--speed", "100", "--params", str(params))
    points = json.loads(run_cli(*args, "--json").stdout)["points"]
    bare = json.loads(run_cli("model", "--torque", "10", "50", "--speed", "100", "--json").stdout)["points"]
    for p, b in zip(points, bare):
        assert p["effects_nm"]["drag_speed"] == pytest.approx(2e-4 * 100 ** 1.5, rel=1e-12)
        assert p["model_nm"] == pytest.approx(abs(b["loss_torque_nm"]), rel=1e-12)
        assert abs(p["loss_torque_nm"]) == pytest.approx(b["model_nm"] + 0.2, rel=1e-12)
    table = run_cli(*args).stdout
    assert "model [%]" in table and "drag_speed (" in table
    assert "accepted effects of the parameter file: drag_speed" in table


def test_only_the_error_family_becomes_one_line_and_a_programming_error_a_traceback(monkeypatch, capsys):
    """``rollergear: error: …`` with exit status 2 is for what users can fix (RollergearError and
    its subclasses); anything else is a defect and must not be dressed up as bad input."""
    import pytest

    from rollergear_ros.cli import main as cli

    from rollergear_ros.core import model
    from rollergear_ros.base.errors import BagError, InputFileError, ParameterError, RollergearError, UsageError

    assert all(issubclass(e, RollergearError) for e in (BagError, InputFileError, ParameterError, UsageError))
    assert cli.main(["model", "--torque", "10", "--speed", "100", "--params", "/nonexistent.yaml"]) == 2
    assert capsys.readouterr().err.startswith("rollergear: error: ")

    def broken(*args, **kwargs):
        raise ValueError("a defect, not bad input")

    monkeypatch.setattr(model.LossModel, "evaluate", broken)
    with pytest.raises(ValueError, match="a defect"):
        cli.main(["model", "--torque", "10", "--speed", "100"])


@pytest.mark.parametrize("command", [
    ("calibrate", "{bag}", "--out", "{out}"),
    ("replay", "{bag}", "--out", "{out}"),
    ("replay", "{bag}", "--rrd", "{out}"),
])
@pytest.mark.parametrize("same", ["path", "other_path", "hard_link"])
def test_an_output_that_is_an_input_is_refused_before_anything_is_written(tmp_path, command, same):
    """``calibrate x.mcap --out x.mcap`` used to replace the recording with a YAML (exit 0); the
    same file by another path or a hard link is the same recording."""
    import os
    import shutil

    bag = tmp_path / "rec.mcap"
    shutil.copy(BAGS / "rig_map_drag.mcap", bag)
    before = bag.read_bytes()
    out = {"path": bag, "other_path": tmp_path / "." / "sub" / ".." / "rec.mcap",
           "hard_link": tmp_path / "link.mcap"}[same]
    (tmp_path / "sub").mkdir()
    if same == "hard_link":
        os.link(bag, out)
    proc = run_cli(*(a.format(bag=bag, out=out) for a in command), check=False)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith("rollergear: error: ") and "refusing to overwrite" in proc.stderr, proc.stderr
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert bag.read_bytes() == before


def test_version_help_texts_and_an_example_for_every_subcommand():
    from rollergear_ros.cli import main as cli

    assert run_cli("--version").stdout.strip() == f"rollergear {cli.package_version()}"
    parser = cli.build_parser()
    commands = parser._subparsers._group_actions[0].choices
    assert set(commands) == set(cli.EXAMPLES)
    for name, sub in commands.items():
        undocumented = [a.dest for a in sub._actions if not a.help]
        assert undocumented == [], (name, undocumented)
        text = sub.format_help()
        assert f"example:\n  {cli.EXAMPLES[name]}" in text and "docs/interface.md" in text
        # the example parses
        example = cli.EXAMPLES[name].split()[1:]
        assert parser.parse_args(example).command == name


def test_fleet_replay_and_fleet_calibrate_have_their_own_help():
    """Each fleet action lists its own options only, with its own example."""
    replay, calibrate = run_cli("fleet", "replay", "--help").stdout, run_cli("fleet", "calibrate", "--help").stdout
    assert "--slice-messages" in replay and "--window-days" not in replay and "--assume" not in replay
    assert "--window-days" in calibrate and "--assume" in calibrate and "--slice-messages" not in calibrate
    assert "example: rollergear fleet replay" in replay and "example: rollergear fleet calibrate" in calibrate
    for text in (replay, calibrate):
        assert "--out DIR" in text and "--params YAML" in text and "--workers N" in text


def test_the_nodes_help_prints_usage_and_every_parameter_without_starting_ros():
    import subprocess
    import sys

    from rollergear_ros.core.paramspecs import parameter_specs

    proc = subprocess.run([sys.executable, "-m", "rollergear_ros.ros.node", "--help"], capture_output=True, text=True,
                          timeout=120, env={**os.environ, "ROS_DOMAIN_ID": "231"})
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    text = proc.stdout
    assert text.startswith("usage: loss_estimator") and "ros2 launch rollergear_ros loss_estimator.launch.py" in text
    for spec in parameter_specs():  # each with its range
        assert f"    {spec.name} (" in text and spec.allowed_text() in " ".join(text.split()), spec.name
    # the contract it names is a file that exists here
    where = text.rstrip().splitlines()[-1].split(": ", 1)[1]
    assert Path(where).is_file() and Path(where).name == "interface.md"


def test_the_docs_and_layouts_are_installed_with_the_package(monkeypatch):
    """``setup.py`` installs docs/*.md and the Foxglove/PlotJuggler layouts beside config/ and launch/
    (``share/rollergear_ros/docs``, ``…/layouts``): its data files, as setuptools is handed them."""
    import runpy

    import setuptools

    handed = {}
    monkeypatch.setattr(setuptools, "setup", lambda **kwargs: handed.update(kwargs))
    monkeypatch.chdir(ROOT)
    runpy.run_path(str(ROOT / "setup.py"))
    data = {folder: sorted(Path(f).name for f in files) for folder, files in handed["data_files"]}
    assert data["share/rollergear_ros/docs"] == sorted(p.name for p in (ROOT / "docs").glob("*.md"))
    assert "interface.md" in data["share/rollergear_ros/docs"]
    assert data["share/rollergear_ros/layouts"] == ["foxglove_rollergear.json", "plotjuggler_rollergear.xml"]
    epilog = " ".join(run_cli("--help").stdout.split()).rsplit("channel maps: ", 1)[1]
    assert Path(epilog).is_file() and Path(epilog).name == "interface.md"


def test_play_names_the_format_it_was_given_and_takes_no_progress(tmp_path):
    csv = tmp_path / "rig.csv"
    csv.write_text("t,T,w\n0,1,2\n")
    proc = run_cli("play", str(csv), "--no-progress", check=False)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert f"{csv} is a CSV file" in proc.stderr and f"rollergear import {csv}" in proc.stderr
    fake = tmp_path / "fake.mcap"
    fake.write_bytes(b"not an mcap at all")
    proc = run_cli("play", str(fake), "--no-progress", check=False)
    assert proc.returncode == 2 and "is not an MCAP file" in proc.stderr and "db3" not in proc.stderr


def test_play_of_a_rosbag2_bag_whose_message_types_this_ros_lacks_is_one_line():
    """ros2/rosbag2's cdr_test bag (test_msgs types, not installed here): copied, then refused in one
    line naming the types, before anything is published."""
    bag = REALDATA / "rosbag2_test_fixtures/rosbag2_tests/resources/mcap/cdr_test"
    if not bag.exists():
        pytest.skip(f"no shared real data at {bag}")
    proc = run_cli("play", str(bag), "--no-progress", "--no-wait", check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert "no message type of the bag is available" in proc.stderr
    assert "test_msgs/msg/Arrays" in proc.stderr and "test_msgs/msg/BasicTypes" in proc.stderr


@pytest.mark.parametrize(("args", "message"), [
    (["replay", "{bag}", "--out", "{dir}"], "--out {dir} is a folder; give a file name"),
    (["replay", "{bag}", "--out", "/proc/rollergear.mcap"], "cannot write in /proc"),
    (["replay", "{bag}", "--rrd", "/proc/rollergear.rrd"], "cannot write in /proc"),
    (["calibrate", "{bag}", "--out", "/proc/rollergear.yaml"], "cannot write in /proc"),  # before the analysis
    (["calibrate", "{bag}", "--report", "{file}"], "--report {file} is a file; give a folder"),
    (["figures", "--out", "{file}"], "--out {file} is a file; give a folder"),
    (["model", "--csv", "{dir}"], "--csv {dir} is a folder; give a file"),
    (["map", "--out", "{dir}"], "--out {dir} is a folder; give a file name"),
    (["simulate", "--out", "/proc/sim.mcap"], "cannot write in /proc"),
    (["simulate", "--fleet", "2", "--days", "1", "--out", "{file}"], "--out {file} is a file; give a folder"),
    (["fleet", "replay", "{bag}", "--out", "{file}"], "--out {file} is a file; give a folder"),
    (["model", "--torque", "1", "--speed", "1", "--params", "{dir}"], "is not a regular file"),
])
def test_an_output_that_cannot_be_written_is_one_line_before_any_work(tmp_path, args, message):
    """File-system errors used to be tracebacks, calibrate's after the whole analysis (its result lost)."""
    names = {"bag": str(BAGS / "rig_map_drag.mcap"), "dir": str(tmp_path), "file": str(tmp_path / "a_file")}
    (tmp_path / "a_file").write_text("x")
    proc = run_cli(*[a.format(**names) for a in args], check=False, timeout=300)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert proc.stderr.count("\n") == 1 and message.format(**names) in proc.stderr, proc.stderr


@pytest.mark.parametrize("name", ["rig.csv", "map.vtlm", "rig.mcap"])
@pytest.mark.parametrize("command", ["replay", "calibrate", "import"])
def test_a_fifo_as_input_is_refused_not_waited_on(tmp_path, name, command):
    """A FIFO (or a device) given as a recording or table used to block for ever."""
    import os

    fifo = tmp_path / name
    os.mkfifo(fifo)
    cmap = tmp_path / "m.yaml"
    cmap.write_text("format: timeseries\ntime: {column: t, unit: s}\nmotor_torque: {column: a, unit: N*m}\n"
                    "motor_speed: {column: b, unit: rad/s}\n")
    args = [command, str(fifo)] + (["--channels", str(cmap)] if name.endswith(".csv") else [])
    args += ["--out", str(tmp_path / "o.mcap")] if command == "import" else []
    proc = run_cli(*args, check=False, timeout=120)
    assert proc.returncode == 2 and "is not a regular file" in proc.stderr and "Traceback" not in proc.stderr, \
        proc.stderr


@pytest.mark.parametrize(("action", "args", "message"), [
    ("calibrate", ["--window-days", "inf"], "--window-days must be a number of days in (0, 100,000], not inf"),
    ("calibrate", ["--window-days", "nan"], "--window-days must be a number of days"),
    ("calibrate", ["--window", "0"], "--window must be a number of hours in (0, 2,400,000], not 0"),
    ("replay", ["--slice-messages", "1"], "--slice-messages must be at least 10,000"),
])
def test_fleet_limits_are_one_line(tmp_path, action, args, message):
    """``--window-days inf`` was an OverflowError traceback; ``--slice-messages 1`` ran for ever."""
    proc = run_cli("fleet", action, str(BAGS / "rig_map.mcap"), "--out", str(tmp_path / "o"), *args,
                   check=False, timeout=120)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and message in proc.stderr, proc.stderr


def test_model_over_a_grid_is_model_point_by_point_and_says_its_sign_rule():
    """The grid that went wrong (from ~50 points on, the speed noise was learned from the list and the
    sign of the slow points smoothed): each row is the point alone, and the text says the sign's rule."""
    torques, speeds = ["-90", "-60", "-30", "-10", "10", "30", "60", "90"], ["-300", "-200", "-100", "-10", "10",
                                                                            "100", "200", "300"]
    grid = json.loads(run_cli("model", "--torque", *torques, "--speed", *speeds, "--json").stdout)["points"]
    alone = json.loads(run_cli("model", "--torque", "90", "--speed", "-10", "--json").stdout)["points"][0]
    [row] = [p for p in grid if p["torque_nm"] == 90 and p["speed_rad_s"] == -10]
    assert row["loss_torque_nm"] == alone["loss_torque_nm"] < -0.2
    assert "the plain sign of each point's speed" in run_cli("model", "--torque", "10", "--speed", "5").stdout


@pytest.mark.parametrize("command", [("model", "--torque", "1", "10", "--speed", "104.72", "--json"),
                                     ("info", str(BAGS / "rig_map.mcap"), "--json"),
                                     ("predict", str(BAGS / "rig_map.mcap"), "--json")])
def test_standard_output_on_a_full_device_or_closed_is_one_line(command):
    """``> /dev/full`` and ``>&-``: one error line naming standard output, exit 2 -- no traceback, and
    not a run with its output going nowhere."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with open("/dev/full", "w") as full:
        proc = subprocess.run([sys.executable, "-m", "rollergear_ros", *command], stdout=full, stderr=subprocess.PIPE,
                              text=True, env=env, timeout=300)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip() == "rollergear: error: standard output: No space left on device", proc.stderr
    closed = subprocess.run(f"{shlex.quote(sys.executable)} -m rollergear_ros {shlex.join(command)} >&-", shell=True,
                            stderr=subprocess.PIPE, text=True, env=env, timeout=300)
    assert closed.returncode == 2 and closed.stderr.strip() == "rollergear: error: standard output is closed", \
        closed.stderr


def test_the_readmes_rig_parameters_are_shipped_as_they_are_shown():
    """The README's three terminals start the node with ``config/rig.yaml``: shipped, valid, and the
    sensors it states are those the README shows."""
    from rollergear_ros.core.params import load_config

    readme = (ROOT / "README.md").read_text()
    assert "--params-file config/rig.yaml" in readme
    shipped = (ROOT / "config" / "rig.yaml").read_text()
    sensors = next(line.strip() for line in shipped.splitlines() if line.strip().startswith("sensors:"))
    assert sensors in readme
    assert load_config(ROOT / "config" / "rig.yaml").sensors.stated
