"""The fleet report's files: a gearbox id from a recording's metadata never names a file outside the
output folder, and two ids never share one file."""

from __future__ import annotations

import pytest

from rollergear_ros.fleet.report import _write_map, safe_file_name

from helpers import CONFIG

HOSTILE = ["../../ESCAPED", "/tmp/ABSOLUTE", "..", ".", "", ".hidden", "a/b", "a\\b", "line\nbreak", "x" * 300,
           "gb 07", "gb_07~0", "\x1b[2J", "ü"]


def test_safe_ids_are_kept_and_others_become_distinct_names_inside_the_folder():
    assert safe_file_name("gb07") == "gb07" and safe_file_name("rig-3.left_A") == "rig-3.left_A"
    names = [safe_file_name(g) for g in HOSTILE + ["gb07", "gb_07"]]
    assert len(set(names)) == len(names)  # two ids never map to one name
    for name in names:
        assert name and "/" not in name and "\\" not in name and not name.startswith(".") and len(name) <= 120
        assert name.isprintable() and name not in (".", "..")


@pytest.mark.parametrize("gearbox_id", ["../../ESCAPED", "/tmp/rollergear-ABSOLUTE", "maps/../../x"])
def test_a_gearbox_id_that_is_a_path_writes_its_map_inside_the_output_folder(tmp_path, gearbox_id):
    out = tmp_path / "deep" / "out"
    out.mkdir(parents=True)
    relative = _write_map(out, gearbox_id, CONFIG.read_text())
    assert relative is not None
    written = [p for p in tmp_path.rglob("*") if p.is_file()]
    assert written == [out / relative] and (out / relative).parent == out / "maps"
    assert repr(gearbox_id) in (out / relative).read_text()


@pytest.mark.parametrize(("args", "message"), [
    (["--scheduler", "not a url"], "is not a scheduler address (tcp://HOST:PORT)"),
    (["--scheduler", "tcp://127.0.0.1:1"], "no Dask scheduler answered within 10 s"),
])
def test_a_scheduler_that_is_no_address_or_does_not_answer_is_one_line(tmp_path, args, message):
    """A traceback after 30 s before; now one line, within the connection timeout."""
    from helpers import BAGS, run_cli

    proc = run_cli("fleet", "replay", str(BAGS / "rig_map.mcap"), "--out", str(tmp_path / "out"), *args,
                   check=False, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("rollergear: error: ")]
    assert len(errors) == 1 and message in errors[0], proc.stderr


@pytest.mark.parametrize("url", ["s3://bucket/logs", "http://127.0.0.1:1/logs"])
def test_a_url_whose_file_system_package_is_missing_is_one_line(tmp_path, url):
    import importlib.util

    from helpers import run_cli

    needs = {"s3": "s3fs", "http": "aiohttp"}[url.split(":")[0]]
    if importlib.util.find_spec(needs) is not None:
        pytest.skip(f"{needs} is installed here")
    proc = run_cli("fleet", "replay", url, "--out", str(tmp_path / "out"), check=False, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and proc.stderr.count("\n") == 1, proc.stderr
    assert url in proc.stderr and "pip install" in proc.stderr


def test_more_workers_than_cores_are_capped_and_said():
    """``--workers 10000``: "Too many open files" tracebacks and no result after 180 s."""
    import os

    from rollergear_ros.fleet.cluster import dask_client

    said = []
    with dask_client(None, 10_000, said.append) as client:
        assert len(client.scheduler_info()["workers"]) == (os.cpu_count() or 1)
    assert any(f"--workers 10000: this machine has {os.cpu_count()} cores" in s for s in said)


def test_one_file_under_two_names_is_one_recording(tmp_path, monkeypatch):
    """``day00.mcap`` and ``./day00.mcap`` (and the folder holding it) were counted twice."""
    import shutil

    from rollergear_ros.fleet.logs import discover

    from helpers import BAGS

    (tmp_path / "logs").mkdir()
    shutil.copy(BAGS / "rig_map.mcap", tmp_path / "logs" / "day00.mcap")
    (tmp_path / "logs" / "link.mcap").symlink_to(tmp_path / "logs" / "day00.mcap")
    monkeypatch.chdir(tmp_path)
    recs = discover(["logs/day00.mcap", "./logs/day00.mcap", "logs", str(tmp_path / "logs" / "link.mcap")])
    assert len(recs) == 1 and recs[0].path.endswith("logs/day00.mcap")


def test_ctrl_c_to_the_group_of_a_fleet_run_is_quiet(tmp_path):
    """Ctrl-C in a terminal signals the whole process group: Dask's worker processes printed a
    KeyboardInterrupt traceback each.  Now they start with it ignored; the command ends them."""
    import os
    import shutil
    import signal
    import subprocess
    import sys

    from helpers import BAGS, ROOT

    (tmp_path / "logs").mkdir()
    for k in range(12):
        shutil.copy(BAGS / "rig_map_drag.mcap", tmp_path / "logs" / f"day{k:02d}.mcap")
    proc = subprocess.Popen([sys.executable, "-m", "rollergear_ros", "fleet", "replay", str(tmp_path / "logs"),
                             "--out", str(tmp_path / "out")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=ROOT, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # as a terminal starts it
    said = []
    for line in proc.stderr:  # the cluster is up (its workers started): from here Ctrl-C is handled
        said.append(line)
        if line.startswith("running on a local Dask cluster"):
            break
    os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    err = "".join(said) + err
    assert proc.returncode == 130 and "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert err.rstrip().endswith("rollergear: interrupted")
