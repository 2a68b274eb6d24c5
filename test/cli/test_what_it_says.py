"""What the commands say is what is true: the user's file named, not a temporary import of it; a
message count as ``info`` counts; no INTERRUPTED after a whole recording; the alarms' times and what
they mean; the per-sample error beside the block means; a simulated recording dated when it is made;
colour bands that resolve the efficiency a gearbox has."""

from __future__ import annotations

import datetime
import os
import signal
import time

import numpy as np
import pytest

from rollergear_ros.core.params import load_config
from rollergear_ros.outputs.lossmap import efficiency_levels
from rollergear_ros.recordings.baginfo import inspect_bag, read_metadata
from rollergear_ros.replay import run as replay_run
from rollergear_ros.replay.run import replay

from helpers import BAGS, run_cli


def _csv_rig(tmp_path):
    t = np.arange(2000) * 0.01
    torque, speed = 20 + 5 * np.sin(t), 100 + 10 * np.cos(t / 3)
    rows = np.column_stack([t, torque, speed, (torque - 0.3) * 1.5, speed / 1.5])
    csv = tmp_path / "rig.csv"
    np.savetxt(csv, rows, delimiter=",", header="time_s,motor_torque,motor_speed,output_torque,output_speed",
               comments="", fmt="%.9g")
    channels = tmp_path / "rig.yaml"
    channels.write_text("time: {column: time_s, unit: s}\nmotor_torque: {column: motor_torque, unit: N*m}\n"
                        "motor_speed: {column: motor_speed, unit: rad/s}\n"
                        "output_torque: {column: output_torque, unit: N*m}\n"
                        "output_speed: {column: output_speed, unit: rad/s}\n")
    return csv, channels


def test_replay_of_a_csv_names_the_users_file_everywhere(tmp_path):
    csv, channels = _csv_rig(tmp_path)
    out = tmp_path / "est.mcap"
    proc = run_cli("replay", str(csv), "--channels", str(channels), "--out", str(out), "--no-png")
    assert f"bag: {csv}" in proc.stdout and "rollergear_import" not in proc.stdout + proc.stderr
    assert "read for this command" in proc.stderr
    provenance = read_metadata(out, "rollergear_provenance")
    assert provenance["source"] == str(csv.resolve()) and int(provenance["source_bytes"]) == csv.stat().st_size


def test_a_joint_state_recordings_message_count_is_infos():
    bag = BAGS / "drive_cycle_joint_states.mcap"
    summary, _ = replay(bag, load_config(), show_progress=False)
    assert summary.input_messages == inspect_bag(bag).message_count == 13_200
    assert f"input messages: {inspect_bag(bag).message_count:,}" in summary.text()


def test_a_signal_after_the_whole_recording_was_read_is_no_interruption(monkeypatch):
    """Ctrl-C while the summary is being made, after every batch was processed: the outputs are whole,
    so the summary says so (it used to say INTERRUPTED and exit 130)."""
    estimate = replay_run._estimate

    def then_a_signal(*args, **kwargs):
        estimate(*args, **kwargs)
        os.kill(os.getpid(), signal.SIGINT)  # the replay's handler takes it: a stop request
        time.sleep(0.05)

    monkeypatch.setattr(replay_run, "_estimate", then_a_signal)
    summary, _ = replay(BAGS / "rig_map.mcap", load_config(), show_progress=False)
    assert not summary.interrupted and "INTERRUPTED" not in summary.text()
    assert any("after the whole recording was processed" in w for w in summary.warnings)
    assert summary.estimated == inspect_bag(BAGS / "rig_map.mcap").counts["/rollergear/motor/torque"]


def test_an_alarm_is_said_with_its_time_and_whether_the_residual_changed():
    summary, _ = replay(BAGS / "rig_map_drag.mcap", load_config(), show_progress=False)
    assert summary.alarms == 1 and summary.alarm_from_start == [True]
    seconds = (summary.alarm_times_ns[0] - summary.start_ns) * 1e-9
    assert f"change alarms: 1 at {seconds:.1f} s (the residual off from the start: the parameters lack an effect, " \
           "not a change)" in summary.text()


def test_calibrate_says_the_per_sample_error_beside_the_block_means(tmp_path):
    proc = run_cli("calibrate", str(BAGS / "rig_map_drag.mcap"), "--out", str(tmp_path / "c.yaml"))
    line = next(ln for ln in proc.stdout.splitlines() if ln.startswith("held-out error"))
    assert "RMSE of 0.25 s block means" in line and "per sample (sensor noise included)" in line
    assert line.index("per sample") < line.index("MAE")


def test_a_simulated_recording_is_dated_when_it_is_made_or_at_start(tmp_path):
    before = time.time()
    run_cli("simulate", "--out", str(tmp_path / "now.mcap"), "--duration", "2")
    start = inspect_bag(tmp_path / "now.mcap").start_ns * 1e-9
    assert before - 2 <= start <= time.time()
    run_cli("simulate", "--out", str(tmp_path / "then.mcap"), "--duration", "2", "--start", "2026-03-01T08:00:00Z")
    then = datetime.datetime.fromtimestamp(inspect_bag(tmp_path / "then.mcap").start_ns * 1e-9, datetime.UTC)
    assert then == datetime.datetime(2026, 3, 1, 8, tzinfo=datetime.UTC)
    proc = run_cli("simulate", "--out", str(tmp_path / "x.mcap"), "--start", "yesterday", check=False)
    assert proc.returncode == 2 and "not an ISO 8601" in proc.stderr


@pytest.mark.parametrize(("low", "high"), [(98.1, 99.82), (60.0, 99.5), (99.9, 99.97)])
def test_the_maps_colour_bands_resolve_the_range_the_gearbox_lives_in(low, high):
    eta = np.concatenate([np.linspace(low, high, 500), [20.0, 35.0]])  # a few poor points near zero torque
    levels = efficiency_levels(eta)
    assert len(levels) <= 14 and levels[0] <= np.percentile(eta, 5) and levels[-1] >= high
    assert np.diff(levels).max() <= (high - low) / 4  # at least four bands over the range, not one 2 % band


@pytest.mark.parametrize("command", ["calibrate", "map"])
def test_ctrl_c_while_a_command_reads_its_recording_writes_nothing_and_exits_130(monkeypatch, tmp_path, capsys,
                                                                                command):
    """Calibrate said "interrupted", went on for 9 s with the samples read so far, wrote its file and
    report and exited 0: an interrupted calibrate (and map, which replays its recording) writes nothing."""
    from rollergear_ros.cli.main import main

    batches = replay_run.input_batches

    def then_a_signal(*args, **kwargs):
        for k, batch in enumerate(batches(*args, **kwargs)):
            if k == 0:  # the replay's handler takes it: a stop request after the first batch
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.05)
            yield batch

    monkeypatch.setattr(replay_run, "input_batches", then_a_signal)
    bag = str(BAGS / "rig_map_drag.mcap")
    args = {"calibrate": ["calibrate", bag, "--out", str(tmp_path / "c.yaml"), "--report", str(tmp_path / "rep")],
            "map": ["map", "--out", str(tmp_path / "m.vtlm"), "--recording", bag, "--measured"]}[command]
    assert main(args) == 130
    assert "interrupted" in capsys.readouterr().err
    assert [p for p in tmp_path.rglob("*") if p.is_file()] == []


@pytest.mark.parametrize("trouble", ["lapack_line", "singular"])
def test_calibrate_json_is_one_json_line_whatever_a_library_prints_or_raises(monkeypatch, capfd, trouble):
    """LAPACK's "DLASCL" lines on stdout broke ``--json``; a singular system was a LinAlgError traceback."""
    from rollergear_ros.calibration import calibrate as calibration
    from rollergear_ros.cli.main import main

    fit = calibration.calibrate

    def troubled(*args, **kwargs):
        if trouble == "singular":
            raise np.linalg.LinAlgError("Singular matrix")
        os.write(1, b" ** On entry to DLASCL parameter number  4 had an illegal value\n")
        return fit(*args, **kwargs)

    monkeypatch.setattr(calibration, "calibrate", troubled)
    code = main(["calibrate", str(BAGS / "rig_map_drag.mcap"), "--json"])
    out, err = capfd.readouterr()
    if trouble == "singular":
        assert code == 2 and out == "" and err.count("rollergear: error: ") == 1 and "admit no fit" in err
        return
    assert code == 0 and "DLASCL" in err and out.count("\n") == 1
    import json

    assert json.loads(out)["verdict"] == "effects_found"


def test_an_interrupted_replay_closes_its_files_and_draws_no_picture(monkeypatch, tmp_path):
    """Ctrl-C: the outputs are closed whole and replay ends; drawing the picture took another second."""
    batches = replay_run.input_batches

    def then_a_signal(*args, **kwargs):
        for k, batch in enumerate(batches(*args, **kwargs)):
            yield batch
            if k == 0:  # after the first batch was processed
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.05)

    monkeypatch.setattr(replay_run, "input_batches", then_a_signal)
    summary, _ = replay(BAGS / "rig_map.mcap", load_config(), out_mcap=tmp_path / "o.mcap",
                        summary_png=tmp_path / "o.png", show_progress=False, batch_size=4000)
    assert summary.interrupted and (tmp_path / "o.mcap").exists() and not (tmp_path / "o.png").exists()
    assert any(w.startswith("interrupted: no summary picture") for w in summary.warnings)
