"""Fleets on a real Dask ``LocalCluster`` (worker processes): the fleet table equals single-process
replay, drifting gearboxes are found with their effect and day, bad recordings are failed rows,
a killed worker's task is retried, a resumed run does no work twice, long recordings run in
time slices that add up to them."""

from __future__ import annotations

import json
import os
import shutil
import threading
import time

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from rollergear_ros.fleet.cluster import dask_client
from rollergear_ros.fleet.logs import discover, time_slices
from rollergear_ros.fleet.run import (FLEET_TABLE, SLICES_TABLE, FleetRun, read_table, run_calibrate, run_replay,
                                      settings_fingerprint)
from rollergear_ros.fleet.tasks import replay_task
from rollergear_ros.fleet.report import drift, write_fleet_report
from rollergear_ros.fleet.simulated import DAY_NS, FleetScenario, simulate_fleet
from rollergear_ros.core.params import load_config
from rollergear_ros.replay.run import replay

from helpers import BAGS, CONFIG
from rostools import wait_for

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    out = tmp_path_factory.mktemp("fleet")
    truth = simulate_fleet(load_config(CONFIG), out, FleetScenario(gearboxes=6, days=6, rate_hz=100.0, seed=3))
    return out, truth


@pytest.fixture(scope="module")
def client():
    with dask_client(workers=2) as c:
        yield c


def test_fleet_replay_equals_single_process_replay_of_each_recording(fleet, client, tmp_path):
    logs, _ = fleet
    recs = discover([str(logs)])
    assert len(recs) == 36 and {r.gearbox_id for r in recs} == {f"gb{g:02d}" for g in range(6)}
    rows, ran = run_replay(recs, tmp_path, FleetRun(client, load_config(CONFIG)))
    assert ran == 36 and len(rows) == 36 and all(r["status"] == "ok" for r in rows)
    by_path = {r["recording"]: r for r in rows}
    config = load_config(CONFIG)
    for rec in recs[::5]:
        s, _ = replay(rec.path, config, show_progress=False)
        row = by_path[rec.path]
        assert (row["samples"], row["estimated"], row["start_ns"]) == (s.samples, s.estimated, s.start_ns)
        assert row["energy_lost_j"] == s.energy_lost_j and row["mean_efficiency"] == s.mean_efficiency
        assert row["residual_rms_nm"] == s.residual_rms_nm and row["gearbox_id"] == rec.gearbox_id
    assert read_table(tmp_path / FLEET_TABLE) == rows  # the table on disk


def test_long_recordings_are_replayed_in_time_slices_that_add_up_to_them(client, tmp_path):
    """Recordings of more than ``slice_messages`` messages are replayed in time slices, a task each;
    each recording's row, made of its slices' rows, equals a single-process replay of it."""
    recs = discover([str(BAGS)])
    slices = {r.path: len(time_slices(r, 20_000)) for r in recs}
    assert sorted(slices.values()) == [1, 3, 3, 5]  # 13 200, 40 824 (x2) and 98 400 messages
    rows, ran = run_replay(recs, tmp_path, FleetRun(client, load_config(CONFIG)), slice_messages=20_000)
    assert ran == len(recs) and len(rows) == len(recs) and all(r["status"] == "ok" for r in rows)
    config = load_config(CONFIG)
    for row in rows:
        s, _ = replay(row["recording"], config, show_progress=False)
        assert row.get("slices") == (slices[row["recording"]] if slices[row["recording"]] > 1 else None)
        assert (row["samples"], row["estimated"], row["skipped"]) == (s.samples, s.estimated, sum(s.skipped.values()))
        assert (row["start_ns"], row["end_ns"], row["duration_s"]) == (s.start_ns, s.end_ns, s.duration_s)
        for field in ("energy_in_j", "energy_lost_j", "mean_efficiency", "mean_loss_nm", "residual_mean_nm",
                      "residual_rms_nm"):
            assert row[field] == pytest.approx(getattr(s, field), rel=1e-9), field
    assert not (tmp_path / SLICES_TABLE).exists()  # every recording complete: no slices kept


def test_time_slices_with_memory_on_the_cluster_add_up_to_one_replay(client, tmp_path):
    """A joint with friction that lags each reversal (LuGre, scipy), the ``dahl`` effect on: a fleet
    replays it in three time slices on the cluster, each slice's state settling in its lead-in;
    the recording's row equals one replay of the whole."""
    from joints import joint_csv, joint_velocity, lugre_friction, memory_config

    from rollergear_ros.sources.importer import import_source

    t, v = joint_velocity(rate=200.0, duration_s=120.0)
    csv, cmap, _ = joint_csv(tmp_path, "joint", lugre_friction(t, v, 30.0, 0.3, 0.0), t, v)
    (tmp_path / "logs").mkdir()
    import_source(csv, tmp_path / "logs" / "joint.mcap", cmap)
    config = memory_config().with_values({"estimator.adapt": False})  # slices would adapt each from the file
    recs = discover([str(tmp_path / "logs")])
    assert len(time_slices(recs[0], 25_000)) == 3
    (row,), ran = run_replay(recs, tmp_path / "out", FleetRun(client, config), slice_messages=25_000)
    assert ran == 1 and row["status"] == "ok" and row["slices"] == 3
    whole, _ = replay(recs[0].path, config, show_progress=False)
    assert (row["samples"], row["estimated"]) == (whole.samples, whole.estimated)
    for field in ("energy_lost_j", "mean_loss_nm", "residual_mean_nm", "residual_rms_nm"):
        assert row[field] == pytest.approx(getattr(whole, field), rel=1e-9), field


def test_a_resumed_run_does_not_redo_the_slices_done(client, tmp_path):
    """A run stopped after two of a recording's five slices: the rerun runs the other three only."""
    (rec,) = discover([str(BAGS / "warmup.mcap")])
    config = load_config(CONFIG)
    windows = time_slices(rec, 20_000)
    assert len(windows) == 5
    done = [replay_task(rec, config, None, w, f"{i}/5") | {"settings": settings_fingerprint(config, None)}
            for i, w in enumerate(windows[:2], 1)]  # as a run with the same settings left them
    done[0]["energy_lost_j"] += 1000.0  # a mark: the slice's row is taken, not recomputed
    pq.write_table(pa.Table.from_pylist(done), tmp_path / SLICES_TABLE)
    notes: list[str] = []
    rows, ran = run_replay([rec], tmp_path, FleetRun(client, config, note=notes.append), slice_messages=20_000)
    assert ran == 1 and "2 time slices already in" in " ".join(notes)
    s, _ = replay(rec.path, config, show_progress=False)
    assert rows[0]["energy_lost_j"] == pytest.approx(s.energy_lost_j + 1000.0, rel=1e-9)
    assert rows[0]["samples"] == s.samples and not (tmp_path / SLICES_TABLE).exists()


def test_drifting_gearboxes_are_found_with_their_effect_and_day_and_no_healthy_one(fleet, client, tmp_path):
    logs, truth = fleet
    rows, _ = run_calibrate(discover([str(logs)]), tmp_path, FleetRun(client, load_config(CONFIG)), DAY_NS)
    assert len(rows) == 36 and all(r["status"] == "ok" for r in rows)
    # each window as a date people read, the same instant as its nanoseconds
    from datetime import UTC, datetime

    for r in rows:
        for end in ("start", "end"):
            stamp = datetime.strptime(r[f"window_{end}"], "%Y-%m-%dT%H:%M:%SZ").replace(tzinfo=UTC)
            assert int(stamp.timestamp()) * 10**9 == r[f"window_{end}_ns"] // 10**9 * 10**9
    found = {g.gearbox_id: g for g in drift(rows) if g.drifts}
    assert set(found) == set(truth["gearboxes"]), (sorted(found), truth["gearboxes"])
    for gid, t in truth["gearboxes"].items():
        (d,) = found[gid].drifts
        assert d.effect == t["effect"]
        assert abs((d.since_ns - truth["start_ns"]) // DAY_NS - t["from_day"]) <= 1
    report = write_fleet_report(tmp_path).read_text()
    for gid in truth["gearboxes"]:
        assert f"| {gid} |" in report and (tmp_path / "maps" / f"{gid}.vtlm").exists()
    assert (tmp_path / "drift.png").stat().st_size > 10_000


def test_fleet_calibrate_takes_what_the_user_assumes(client, tmp_path):
    """A gearbox driven forward only, with a seal drag: inconclusive (drag / torque offset) without
    ``assume``; with it the drag is accepted -- and the rows made without it are done again."""
    from rollergear_ros.calibration.simulate import DeclaredEffect, SimulationOptions, simulate, write_rig_bag

    config = load_config(CONFIG)
    (tmp_path / "logs" / "gb07").mkdir(parents=True)
    opts = SimulationOptions(profile="rig_map", rate_hz=100.0, seed=5,
                             effects=[DeclaredEffect.parse("drag_constant:c=0.08")])
    write_rig_bag(simulate(config, opts), opts, tmp_path / "logs" / "gb07" / "day00.mcap")
    recs = discover([str(tmp_path / "logs")])
    (row,), _ = run_calibrate(recs, tmp_path / "out", FleetRun(client, config), DAY_NS)
    assert row["verdict"] == "inconclusive" and json.loads(row["effects"]) == []
    (row,), ran = run_calibrate(recs, tmp_path / "out", FleetRun(client, config), DAY_NS, assume=["drag_constant"])
    assert ran == 1 and row["verdict"] == "effects_found"
    (effect,) = json.loads(row["effects"])
    assert effect["name"] == "drag_constant" and effect["params"]["c"] == pytest.approx(0.08, rel=0.1)
    assert row["drag_constant.c"] == effect["params"]["c"]


def test_a_window_whose_output_torque_is_in_the_other_sign_convention_is_warned_of(client, tmp_path, capsys):
    """As ``calibrate`` warns on its command line: a gearbox logged with its output torque negated (power
    out counted negative) gets its window's warning in the table, the command's output and the report;
    its correctly logged twin gets none."""
    import dataclasses

    from rollergear_ros.calibration.simulate import SimulationOptions, simulate, write_rig_bag
    from rollergear_ros.cli.main import main

    config = load_config(CONFIG)
    opts = SimulationOptions(profile="rig_map", rate_hz=50.0, seed=7)
    rig = simulate(config, opts)
    for gearbox, logged in (("gb_ok", rig), ("gb_flipped", dataclasses.replace(
            rig, out_torque_meas_nm=-rig.out_torque_meas_nm))):
        (tmp_path / "logs" / gearbox).mkdir(parents=True)
        write_rig_bag(logged, opts, tmp_path / "logs" / gearbox / "day00.mcap")
    out = tmp_path / "out"
    assert main(["fleet", "calibrate", str(tmp_path / "logs"), "--params", str(CONFIG), "--out", str(out),
                 "--scheduler", client.scheduler.address]) == 0
    rows = {r["gearbox_id"]: r for r in read_table(out / "fleet_calibrate.parquet")}
    assert rows["gb_ok"]["warning"] == ""
    assert "opposite sign convention" in rows["gb_flipped"]["warning"]
    printed = capsys.readouterr().out
    assert f"warning: gb_flipped window {rows['gb_flipped']['window']}: the measured loss exceeds" in printed
    assert "gb_ok window" not in printed
    assert "## Warnings" in (out / "report.md").read_text() and "gb_flipped, window" in (out / "report.md").read_text()


def test_bad_recordings_are_failed_rows_and_the_rest_go_on(fleet, client, tmp_path):
    logs, _ = fleet
    mixed = tmp_path / "logs" / "gb99"
    mixed.mkdir(parents=True)
    shutil.copy(logs / "gb00" / "day00.mcap", mixed / "good.mcap")
    data = (logs / "gb00" / "day01.mcap").read_bytes()
    (mixed / "truncated.mcap").write_bytes(data[: len(data) // 3])
    (mixed / "foreign.mcap").write_text("not a recording\n")
    rows, _ = run_replay(discover([str(tmp_path / "logs")]), tmp_path / "out", FleetRun(client, load_config(CONFIG)))
    status = {os.path.basename(r["recording"]): (r["status"], r["reason"]) for r in rows}
    assert status["good.mcap"] == ("ok", "")
    assert status["foreign.mcap"][0] == "failed" and "MCAP" in status["foreign.mcap"][1]
    # a truncated recording replays as far as it is readable (replay warns); its row says how much
    truncated = next(r for r in rows if r["recording"].endswith("truncated.mcap"))
    assert truncated["status"] == "ok" and 0 < truncated["samples"] < 10080


def test_a_resumed_run_does_no_work_twice(fleet, client, tmp_path):
    logs, _ = fleet
    recs = discover([str(logs / "gb01")])
    rows, ran = run_replay(recs[:3], tmp_path, FleetRun(client, load_config(CONFIG)))
    assert ran == 3
    rows, ran = run_replay(recs, tmp_path, FleetRun(client, load_config(CONFIG)))
    assert ran == len(recs) - 3 and len(rows) == len(recs)
    assert len({r["key"] for r in rows}) == len(recs)
    rows, ran = run_replay(recs, tmp_path, FleetRun(client, load_config(CONFIG)))
    assert ran == 0 and len(rows) == len(recs)


def test_a_run_with_other_parameters_does_the_rows_again(fleet, client, tmp_path):
    """The tables hold what they were made with (``settings``): a run with another parameter file
    replaces the rows made with the first instead of returning them as its own (it did: keyed by
    the recordings alone), and says so; the same settings again do no work."""
    from dataclasses import replace

    logs, _ = fleet
    recs = discover([str(logs / "gb02")])[:3]
    config = load_config(CONFIG)
    notes = []
    rows_a, ran = run_replay(recs, tmp_path, FleetRun(client, config))
    assert ran == 3
    other = replace(config, estimator=replace(config.estimator, paper_model=False))
    rows_b, ran = run_replay(recs, tmp_path, FleetRun(client, other, note=notes.append))
    assert ran == 3 and len(rows_b) == 3
    assert any("3 rows" in n and "other parameters" in n for n in notes), notes
    assert {r["settings"] for r in rows_a}.isdisjoint({r["settings"] for r in rows_b})
    by_key = {r["key"]: r for r in rows_a}
    assert all(r["mean_loss_nm"] != by_key[r["key"]]["mean_loss_nm"] for r in rows_b)
    assert read_table(tmp_path / FLEET_TABLE) == rows_b
    _, ran = run_replay(recs, tmp_path, FleetRun(client, other))
    assert ran == 0


def test_a_killed_workers_task_is_retried_and_the_table_is_complete(fleet, tmp_path):
    """A worker process is killed while it runs a task (seen running on it first): the task runs
    again elsewhere and every recording has its row."""
    logs, _ = fleet
    recs = discover([str(logs)])
    result: dict = {}
    with dask_client(workers=2) as c:
        run = threading.Thread(target=lambda: result.update(
            rows=run_replay(recs, tmp_path, FleetRun(c, load_config(CONFIG)))[0]))
        run.start()
        busy: dict = {}

        def some_worker_busy() -> bool:
            busy.update({w: ks for w, ks in c.processing().items() if ks})
            return bool(busy)

        assert wait_for(some_worker_busy, 60), "no task ever ran"
        victim = next(iter(busy))
        pid = c.run(os.getpid, workers=[victim])[victim]
        os.kill(pid, 9)
        run.join(300)
        assert not run.is_alive()
        deadline = time.monotonic() + 60
        while victim in c.scheduler_info()["workers"] and time.monotonic() < deadline:
            time.sleep(0.1)
        assert victim not in c.scheduler_info()["workers"]
    rows = result["rows"]
    assert len(rows) == len(recs) and all(r["status"] == "ok" for r in rows)
    assert {r["key"] for r in rows} == {r.key for r in recs}
    assert json.loads(json.dumps(rows[0]))  # plain values, JSON-able


def test_workers_keep_glibc_s_own_memory_trimming(client):
    """Dask's nanny sets MALLOC_TRIM_THRESHOLD_=65536 for its workers, which made every numpy batch of
    a replay map and unmap its memory: tasks ran 1.6-1.9x slower than in a plain process (measured
    with the variable set by hand).  The fleet's workers run without it."""
    import os

    assert set(client.run(os.environ.get, "MALLOC_TRIM_THRESHOLD_").values()) == {None}


def test_a_fifo_a_symlink_loop_and_the_fleets_own_output_among_the_logs_are_no_hang_and_no_abort(
        client, tmp_path):
    """A FIFO among the logs hung ``fleet replay`` (no output after 400 s), a symlink loop aborted the
    run, and an --out inside the logs folder had the fleet's own tables read as recordings."""
    logs = tmp_path / "logs"
    (logs / "gb01").mkdir(parents=True)
    shutil.copy(BAGS / "rig_map.mcap", logs / "gb01" / "day1.mcap")
    os.mkfifo(logs / "gb01" / "day2.mcap")
    (logs / "gb01" / "loop").symlink_to(logs / "gb01", target_is_directory=True)  # a folder loop
    (logs / "gb01" / "self.mcap").symlink_to(logs / "gb01" / "self.mcap")  # a file loop
    out = logs / "out"
    recs = discover([str(logs)], exclude=out)
    assert sorted(os.path.basename(r.path) for r in recs) == ["day1.mcap", "day2.mcap", "self.mcap"]
    rows, _ = run_replay(recs, out, FleetRun(client, load_config(CONFIG)))
    by_name = {os.path.basename(r["recording"]): r for r in rows}
    assert by_name["day1.mcap"]["status"] == "ok"
    assert by_name["day2.mcap"]["status"] == "failed" and "is a FIFO" in by_name["day2.mcap"]["reason"]
    assert by_name["self.mcap"]["status"] == "failed" and "cannot be read" in by_name["self.mcap"]["reason"]
    assert (out / FLEET_TABLE).exists()
    again = discover([str(logs)], exclude=out)  # the table written into the logs folder is left out
    assert [r.path for r in again] == [r.path for r in recs]


def test_a_task_whose_worker_keeps_dying_is_a_failed_row_and_the_rest_finish(tmp_path):
    """A task that kills its worker every time ended the run with a ``KilledWorker`` traceback and no table."""
    import dask

    from rollergear_ros.fleet.run import FleetTable, _run

    rec = discover([str(BAGS / "rig_map.mcap")])[0]
    units = [("dies", [("dies", os._exit, (3,))]),
             (rec.key, [(rec.key, replay_task, (rec, load_config(CONFIG), None))])]
    # two workers: the dying task takes one down (and again, until the scheduler gives up on it); the
    # other task waits in the scheduler's queue for a free worker, never on the one that dies
    with dask.config.set({"distributed.scheduler.allowed-failures": 2}), dask_client(workers=2) as client:
        rows, ran = _run(FleetRun(client, load_config(CONFIG)), FleetTable(tmp_path / FLEET_TABLE, "recordings", "s"),
                         units)
    assert ran == 2 and len(rows) == 2
    by_key = {r["key"]: r for r in rows}
    assert by_key["dies"]["status"] == "failed" and "KilledWorker" in by_key["dies"]["reason"]
    assert by_key[rec.key]["status"] == "ok" and by_key[rec.key]["estimated"] > 0
    assert {r["key"]: r["status"] for r in read_table(tmp_path / FLEET_TABLE)} == {"dies": "failed", rec.key: "ok"}


def test_a_long_log_is_split_between_windows_and_drift_inside_it_is_found(client, tmp_path):
    """One 200 s log of a gearbox whose seal drag appears at 100 s, calibrated in 50 s windows: four rows,
    each reading only its part of the log (its samples those of the whole log's replay in that part, its
    true span named), the drag found in the last two windows and not in the first two, and the drift dated
    at the third -- as drift across daily logs is."""
    import numpy as np

    from rollergear_ros.calibration.samples import load_samples
    from rollergear_ros.calibration.simulate import DeclaredEffect, SimulationOptions, write_simulation

    config = load_config(CONFIG)
    window_ns = 50 * 10**9
    start_ns = 1_700_000_000 * 10**9  # a multiple of the window: the passes of the profile fill the windows
    (tmp_path / "logs" / "gb01").mkdir(parents=True)
    log = tmp_path / "logs" / "gb01" / "long.mcap"
    opts = SimulationOptions(profile="bidirectional_map", rate_hz=100.0, seed=2, start_ns=start_ns,
                             effects=[DeclaredEffect.parse("drag_constant:c=0.08")], step_change_at_s=100.0)
    write_simulation(config, opts, log, 199.9)
    rows, ran = run_calibrate(discover([str(tmp_path / "logs")]), tmp_path / "out", FleetRun(client, config),
                              window_ns)
    rows = sorted(rows, key=lambda r: r["window"])
    assert ran == 4 and [r["window"] - rows[0]["window"] for r in rows] == [0, 1, 2, 3], rows
    assert all(r["status"] == "ok" for r in rows), [r["reason"] for r in rows]
    whole = load_samples([log], config)
    for r in rows:
        lo, hi = r["window_start_ns"], r["window_end_ns"]
        assert lo <= r["data_start_ns"] < r["data_start_ns"] + 45 * 10**9 < r["data_end_ns"] < hi, r
        assert r["samples"] == np.count_nonzero((whole.t_ns >= lo) & (whole.t_ns < hi)), r
        assert r["recordings_in_part"] == 1
    found = [{e["name"]: e["params"] for e in json.loads(r["effects"])} for r in rows]
    assert ["drag_constant" in f for f in found] == [False, False, True, True], found
    assert all(f["drag_constant"]["c"] == pytest.approx(0.08, rel=0.1) for f in found[2:])
    (gearbox,) = [g for g in drift(rows) if g.drifts]
    (d,) = gearbox.drifts
    assert d.effect == "drag_constant" and d.since_ns == rows[2]["window_start_ns"], d


def test_a_window_of_a_log_reads_the_samples_the_whole_log_has_there():
    """``load_samples`` of a time slice: the samples a replay of the whole recording has in it, to the bit."""
    import numpy as np

    from rollergear_ros.calibration.samples import load_samples

    bag, config = BAGS / "rig_map_drag.mcap", load_config(CONFIG)
    whole = load_samples([bag], config)
    lo, hi = int(whole.t_ns[0]) + 30 * 10**9, int(whole.t_ns[0]) + 60 * 10**9
    part = load_samples([bag], config, windows=[(lo, hi)])
    inside = (whole.t_ns >= lo) & (whole.t_ns < hi)
    np.testing.assert_array_equal(part.t_ns, whole.t_ns[inside])
    np.testing.assert_array_equal(part.measured_loss, whole.measured_loss[inside])


def test_a_fleet_runs_on_a_scheduler_and_workers_started_apart(fleet, tmp_path):
    """``dask scheduler`` and two ``dask worker`` processes started on their own, as on a cluster of machines
    (over TCP on loopback here), and ``fleet replay --scheduler``: every recording's row equals the one a
    single process replays, and both workers took tasks."""
    import subprocess
    import sys
    from pathlib import Path

    from dask.distributed import Client, get_task_stream

    from helpers import ROOT, run_cli

    logs, _ = fleet
    dask_cli = str(Path(sys.executable).parent / "dask")
    address_file = tmp_path / "scheduler.json"
    procs = [subprocess.Popen([dask_cli, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(address_file)], cwd=ROOT,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        assert wait_for(lambda: address_file.exists() and address_file.stat().st_size > 0, 120), "no scheduler"
        address = json.loads(address_file.read_text())["address"]
        for _ in range(2):
            procs.append(subprocess.Popen([dask_cli, "worker", address, "--nthreads", "1", "--no-dashboard"],
                                          cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        with Client(address, timeout=120) as c:
            c.wait_for_workers(2, timeout=300)
            with get_task_stream(client=c) as stream:  # what the scheduler ran, and where
                run_cli("fleet", "replay", str(logs), "--scheduler", address, "--out", str(tmp_path / "out"),
                        timeout=900)
            workers = {t["worker"] for t in stream.data}
        assert len(workers) == 2, workers
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            p.wait(timeout=60)
    rows = read_table(tmp_path / "out" / FLEET_TABLE)
    recs = discover([str(logs)])
    assert len(rows) == len(recs) and all(r["status"] == "ok" for r in rows)
    by_path = {r["recording"]: r for r in rows}
    config = load_config()
    for rec in recs[::7]:
        s, _ = replay(rec.path, config, show_progress=False)
        row = by_path[rec.path]
        assert (row["samples"], row["estimated"], row["energy_lost_j"]) == (s.samples, s.estimated, s.energy_lost_j)
