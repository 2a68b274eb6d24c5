"""``rollergear watch``: the period summary (pure) and the command against a live node over DDS."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from rollergear_ros.recordings.messages import encode_float64
from rollergear_ros.core.params import load_config
from rollergear_ros.replay.run import replay
from rollergear_ros.ros.watch import WatchWindow

from helpers import BAGS, CONFIG, run_cli
from rostools import NodeProcess, WatchProcess, play, wait_for

LINE = re.compile(r"(\d+) est/s  loss (\S+) N·m  (\S+) W  η (\S+) % \(min (\S+)\)")


def _window(**series: list[float]) -> WatchWindow:
    w = WatchWindow()
    for channel, values in series.items():
        for raw in encode_float64(np.asarray(values, dtype=float)):
            w.add(channel, raw)
    return w


def test_window_summarises_a_period_and_starts_the_next():
    w = _window(loss_torque=[0.1, 0.3], loss_power=[10.0, 30.0], efficiency=[0.99, float("nan")],
                residual_torque=[0.01, 0.03])
    w.diagnostic = (1, "motor_torque at 500 Hz, expected 1000 Hz")
    line = w.line(0.5, "/rollergear/loss/torque")
    m = LINE.search(line)
    assert m and m.groups() == ("4", "0.2000", "20.00", "99.00", "99.00"), line
    assert "residual +0.0200 N·m" in line and line.endswith("[WARN] motor_torque at 500 Hz, expected 1000 Hz")
    # the next period starts empty; the latest status is kept
    assert w.line(1.0, "/rollergear/loss/torque").startswith(
        "no estimates on /rollergear/loss/torque in the last 1.0 s"
    )


def test_window_without_efficiency_or_residual():
    line = _window(loss_torque=[0.2], loss_power=[0.0], efficiency=[float("nan")]).line(1.0, "/x")
    assert "η —" in line and "residual" not in line and "[" not in line


def test_watch_refuses_a_bad_period():
    proc = run_cli("watch", "--period", "0", check=False)
    assert proc.returncode == 2 and "--period must be > 0" in proc.stderr


@pytest.mark.ros
@pytest.mark.slow
def test_watch_shows_a_running_nodes_estimates_and_status():
    """Node, player and watcher as three processes (the README's terminals): the watcher's lines
    carry estimates within what offline replay computes for the bag, and the node's status."""
    node = NodeProcess()
    watcher = WatchProcess()
    lines = watcher.lines  # the watcher's lines as it prints them (a line a period, flushed)

    def stale_after_the_play() -> bool:  # a line with no estimates and the stale-input status
        return any("no estimates on /rollergear/loss/torque" in line and "[STALE] stale input" in line
                   for line in list(lines))

    try:
        play(BAGS / "rig_map.mcap", "--rate", "5", "--wait-for-subscribers", "20")
        assert wait_for(stale_after_the_play, 300), "\n".join(lines)
    finally:
        returncode = watcher.stop()
        assert node.stop() == 0, node.stderr
    assert returncode == 0 and "Traceback" not in watcher.errors, watcher.errors
    out = "\n".join(lines)
    found = [m for m in map(LINE.search, lines) if m]
    assert len(found) >= 5, out
    _, batches = replay(BAGS / "rig_map.mcap", load_config(CONFIG), show_progress=False, collect=True)
    eff = np.concatenate([b.efficiency for b in batches])
    power = np.concatenate([b.loss_power_w for b in batches])
    for m in found:
        assert np.nanmin(eff) - 1e-6 <= float(m.group(4)) / 100 <= np.nanmax(eff) + 1e-6, m.group(0)
        assert 0 <= float(m.group(3)) <= power.max() + 0.01, m.group(0)
    # the bag plays at 1 kHz; a best-effort watcher sees most of it
    assert max(int(m.group(1)) for m in found) > 500, out
    assert "[OK]" in out or "[WARN]" in out, out
    assert "no estimates on /rollergear/loss/torque" in lines[-1] and "[STALE] stale input" in lines[-1], out


@pytest.mark.ros
def test_watch_count_ends_by_itself_without_a_node():
    count = 2
    proc = run_cli("watch", "--period", "0.5", "--count", str(count), timeout=30)
    lines = proc.stdout.splitlines()
    assert len(lines) == count and all(
        "no estimates on /rollergear/loss/torque in the last 0.5 s" in ln for ln in lines
    ), proc.stdout


def test_a_period_as_the_row_a_logger_takes():
    w = _window(loss_torque=[0.1, 0.3], loss_power=[10.0, 30.0], efficiency=[0.99, 0.97],
                efficiency_measured=[0.95, 0.9804], efficiency_measured_uncertainty=[0.002, 0.0021])
    w.diagnostic = (0, "estimating")
    row = w.take(0.5)
    assert row["estimates_per_s"] == 4 and row["loss_torque_nm"] == pytest.approx(0.2)
    assert row["efficiency_min"] == 0.97 and row["efficiency_measured"] == 0.9804  # the latest window
    assert row["efficiency_measured_uncertainty"] == 0.0021 and row["level"] == "OK"
    assert np.isnan(row["residual_nm"])


@pytest.mark.ros
@pytest.mark.parametrize("fmt", ["--csv", "--json"])
def test_watch_writes_rows_for_a_logger(fmt):
    import csv
    import io

    proc = run_cli("watch", "--period", "0.5", "--count", "2", fmt, timeout=30)
    if fmt == "--json":
        rows = [json.loads(line) for line in proc.stdout.splitlines()]
        assert all(r["efficiency_measured"] is None for r in rows)  # NaN as null: valid JSON
    else:
        rows = list(csv.DictReader(io.StringIO(proc.stdout)))
    assert len(rows) == 2 and all(float(r["estimates_per_s"]) == 0 and r["time_utc"].endswith("Z") for r in rows)
    assert {"loss_torque_nm", "efficiency", "efficiency_measured", "efficiency_measured_uncertainty", "level",
            "message", "traced", "status_age_s"} <= set(rows[0])
    # to the millisecond (a logger's rows a period apart never share a stamp); no value: null / an empty field
    assert all(re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z", r["time_utc"]) for r in rows), rows
    assert rows[0]["time_utc"] != rows[1]["time_utc"]
    assert all(r["loss_torque_nm"] in (None, "") for r in rows), rows


def test_a_node_that_stopped_speaking_is_silent_not_idle():
    """The node's last status said STALE (an idle rig); /diagnostics then stops (the node ended or was
    killed): after three seconds without a status the row says SILENT, how long, and the last status --
    never the frozen STALE; a watcher that never heard a node says so too."""
    w = WatchWindow()
    w.add_status(3, "stale input: motor_torque silent for 1.44 s: idle", {})
    assert w.take(1.0, now=w.status_at + 1.0)["level"] == "STALE"
    row = w.take(1.0, now=w.status_at + 5.2)
    assert row["level"] == "SILENT" and row["status_age_s"] == pytest.approx(5.2), row
    assert row["message"].startswith("no status from the node for 5 s") and "[STALE] stale input" in row["message"]
    assert "[SILENT] no status from the node for 5 s" in _line(w, w.status_at + 5.2)
    never = WatchWindow()
    assert never.take(1.0, now=never.started + 1.0)["level"] == ""
    assert never.take(1.0, now=never.started + 4.0)["message"].startswith("no status from a node in 4 s")


def _line(w: WatchWindow, now: float) -> str:
    import time

    real = time.monotonic
    try:  # the line of a period ending at ``now`` (its clock is the watcher's)
        time.monotonic = lambda: now
        return w.line(1.0, "/x")
    finally:
        time.monotonic = real


@pytest.mark.ros
def test_watch_ends_when_the_node_stays_silent_and_says_a_full_device_in_one_line(tmp_path):
    """``--until-silent S``: a logger's watchdog ends with status 3 once /diagnostics said nothing for S
    seconds (here no node at all); standard output on a full device: one error line, status 2."""
    proc = run_cli("watch", "--period", "0.5", "--until-silent", "3", "--json", check=False, timeout=60)
    assert proc.returncode == 3 and "no status from the node for" in proc.stderr, proc.stderr
    assert json.loads(proc.stdout.splitlines()[-1])["level"] == "SILENT"
    import subprocess
    import sys

    from helpers import ROOT

    for fmt in ([], ["--csv"], ["--json"]):
        with open("/dev/full", "w") as full:
            done = subprocess.run([sys.executable, "-m", "rollergear_ros", "watch", "--period", "0.3", "--count", "2",
                                   *fmt], stdout=full, stderr=subprocess.PIPE, text=True, cwd=ROOT, timeout=60)
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
        assert lines[-1] == "rollergear: error: standard output: No space left on device", lines


def test_a_line_says_the_measured_efficiency_once_and_keeps_the_latest_window_across_periods():
    """One line showed two measured efficiencies (its column's window and the status text's, a report
    apart), and a period whose second brought no window showed none (null in --json)."""
    w = _window(loss_torque=[0.1], loss_power=[10.0], efficiency=[0.99],
                efficiency_measured=[0.9876], efficiency_measured_uncertainty=[0.0034])
    w.diagnostic = (1, "the residual changed; measured efficiency 99.10 ± 0.37 % over 10 s")
    line = w.line(1.0, "/x")
    assert "η measured 98.76 ± 0.34 %" in line and "99.10" not in line and line.endswith("[WARN] the residual changed")
    for raw in encode_float64(np.array([0.2])):
        w.add("loss_torque", raw)
    row = w.take(1.0)  # no new window this period: the latest still
    assert row["efficiency_measured"] == 0.9876 and row["efficiency_measured_uncertainty"] == 0.0034


def test_a_row_has_the_measured_efficiency_from_the_first_status_before_any_window_message():
    """A watcher that joined after the node's last window message printed an OK row with no measured
    efficiency although the status it printed states one."""
    w = _window(loss_torque=[0.1], loss_power=[10.0], efficiency=[0.99])
    w.add_status(0, "estimating; measured efficiency 99.50 ± 0.10 % over 2 s",
                 {"measured efficiency": repr(0.9949564436664599), "measured efficiency uncertainty": "0.001"})
    row = w.take(0.5)
    assert row["level"] == "OK" and row["efficiency_measured"] == 0.9949564436664599
    assert row["efficiency_measured_uncertainty"] == 0.001
    # a later window message is the latest; a status without output torque leaves it
    for raw in encode_float64(np.array([0.9876])):
        w.add("efficiency_measured", raw)
    w.add_status(0, "estimating", {"measured efficiency": "none (no measured output torque)"})
    assert w.take(0.5)["efficiency_measured"] == 0.9876
    w.add_status(0, "estimating", {"measured efficiency": "0.97", "measured efficiency uncertainty":
                                   "not stated (sensors.*)"})
    row = w.take(0.5)
    assert row["efficiency_measured"] == 0.97 and row["efficiency_measured_uncertainty"] == 0.0
