"""Every output of a command is checked against every other, every input and its kind before
anything is written (paths.check_outputs)."""

from __future__ import annotations

import os
import stat

import pytest

from helpers import BAGS, run_cli

BAG = str(BAGS / "rig_map_drag.mcap")


@pytest.mark.parametrize(("args", "message"), [
    (["replay", BAG, "--out", "{d}/p.mcap", "--png", "{d}/p.mcap"], "--png {d}/p.mcap: --png writes a PNG picture"),
    (["replay", BAG, "--out", "{d}/o.mcap", "--rrd", "{d}/o.mcap"], "--rrd {d}/o.mcap: --rrd writes a rerun"),
    (["replay", BAG, "--out", "{d}/o", "--rrd", "{d}/o"], "--out {d}/o and --rrd {d}/o are the same path"),
    (["replay", BAG, "--out", "{d}/r.png"], "--out {d}/r.png: --out writes an MCAP recording (.mcap), not a .png"),
    (["replay", BAG, "--rrd", "{d}/x.rrd", "--png", "{d}/sub/../x.rrd"], "writes a PNG picture"),
    (["replay", BAG, "--out", "{d}/a", "--png", "{d}/sub/../a"], "are the same path"),
    (["map", "--out", "{d}/mm.png"], "--out {d}/mm.png: --out writes a VECTO loss map (.vtlm or .csv), not a .png"),
    (["map", "--out", "{d}/m", "--both-directions"], None),  # m, m.png, m_reverse, m_reverse.png: all apart
    (["calibrate", BAG, "--out", "{d}/c.yaml", "--report", "{d}/c.yaml"], "are the same path"),
    (["calibrate", BAG, "--out", "{d}/c.mcap"], "--out writes a parameter file (.yaml or .yml), not a .mcap"),
    (["import", BAG, "--out", "{d}/i.yaml"], "--out writes an MCAP recording"),
])
def test_outputs_of_one_command_on_one_path_or_of_the_wrong_kind_are_refused_before_anything_is_written(
        tmp_path, args, message):
    """Each used to write one output over the other (a PNG left where the MCAP was, an MCAP the
    reader rejects, a map overwritten by its picture), or a PNG under an .mcap name."""
    (tmp_path / "sub").mkdir()
    proc = run_cli(*[a.format(d=tmp_path) for a in args], check=False, timeout=300)
    if message is None:  # the control: a valid set of outputs runs
        assert proc.returncode == 0, proc.stderr
        assert {p.name for p in tmp_path.iterdir()} == {"sub", "m", "m.png", "m_reverse", "m_reverse.png"}
        return
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.count("\n") == 1 and message.format(d=tmp_path) in proc.stderr, proc.stderr
    assert [p.name for p in tmp_path.iterdir()] == ["sub"] and not any((tmp_path / "sub").iterdir())


@pytest.mark.parametrize("args", [
    ["replay", BAG, "--png", "{dev}"],
    ["replay", BAG, "--out", "{dev}"],
    ["map", "--out", "{dev}"],
    ["calibrate", BAG, "--out", "{dev}"],
])
def test_a_device_given_as_an_output_stays_a_device(args):
    """``replay … --png /dev/null`` and ``map --out /dev/null`` replaced the device by a regular file
    (as root: a broken machine)."""
    dev = "/dev/null"
    proc = run_cli(*[a.format(dev=dev) for a in args], check=False, timeout=120)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert f"{dev} is a character device; give a regular file" in proc.stderr
    assert stat.S_ISCHR(os.stat(dev).st_mode)


@pytest.mark.parametrize(("option", "name"), [("--out", "o.mcap"), ("--rrd", "o.rrd"), ("--png", "o.png")])
def test_a_fifo_or_a_folder_given_as_an_output_is_refused_without_waiting(tmp_path, option, name):
    fifo = tmp_path / name
    os.mkfifo(fifo)
    proc = run_cli("replay", BAG, option, str(fifo), check=False, timeout=120)  # never opened: no hang
    assert proc.returncode == 2 and f"{fifo} is a FIFO; give a regular file" in proc.stderr, proc.stderr
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    folder = tmp_path / ("d" + name)
    folder.mkdir()
    proc = run_cli("replay", BAG, option, str(folder), check=False, timeout=120)
    assert proc.returncode == 2 and f"{folder} is a folder; give a file name" in proc.stderr, proc.stderr


def test_check_outputs_accepts_distinct_outputs_and_a_suffix_of_no_known_kind(tmp_path):
    from rollergear_ros.base.errors import UsageError
    from rollergear_ros.sources.paths import Output, check_outputs

    check_outputs([], [Output("--out", tmp_path / "a.mcap", "mcap"), Output("--rrd", tmp_path / "a.rrd", "rrd"),
                       Output("--png", tmp_path / "a.bin", "png"), Output("--report", tmp_path / "r", "folder")])
    (tmp_path / "hard").write_text("x")
    os.link(tmp_path / "hard", tmp_path / "link")
    with pytest.raises(UsageError, match="are the same path"):  # a hard link is the same file
        check_outputs([], [Output("--out", tmp_path / "hard", "mcap"), Output("--rrd", tmp_path / "link", "rrd")])


@pytest.mark.parametrize(("args", "message"), [
    (["replay", "{b}", "--out", "{b}/bag_0.mcap"], "--out {b}/bag_0.mcap is a file of the input {b}/bag_0.mcap"),
    (["replay", "{b}", "--csv", "{b}/bag_1"], "--csv {b}/bag_1 is a file of the input"),
    (["import", "{b}", "--out", "{b}/bag_0.mcap"], "is a file of the input"),
    (["calibrate", "{b}", "--out", "{b}/metadata.yaml"], "--out {b}/metadata.yaml is a file of the input"),
    (["calibrate", "{b}/bag_0.mcap", "--channels", "{d}/rep/report.md", "--report", "{d}/rep"],
     "--report {d}/rep would replace the input {d}/rep/report.md"),
    (["calibrate", "{b}/bag_0.mcap", "--params", "{d}/rep/residual_vs_speed.png", "--report", "{d}/rep"],
     "would replace the input {d}/rep/residual_vs_speed.png"),
    (["figures", "--params", "{d}/rep/fig06.png", "--out", "{d}/rep"], "would replace the input {d}/rep/fig06.png"),
])
def test_an_output_never_replaces_a_file_inside_a_folder_input_or_an_input_inside_an_output_folder(
        tmp_path, args, message):
    """A rosbag2 folder's storage files (with or without a suffix, a split bag's parts) and its
    ``metadata.yaml`` are inputs; the files a report or figures folder gets are outputs: each such
    pair is refused with one line, and every file is left as it was."""
    import shutil

    bag = tmp_path / "bag"
    bag.mkdir()
    shutil.copy(BAG, bag / "bag_0.mcap")
    shutil.copy(BAG, bag / "bag_1")
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    (tmp_path / "rep").mkdir()
    for name in ("report.md", "residual_vs_speed.png", "fig06.png"):
        (tmp_path / "rep" / name).write_text("the user's")
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    proc = run_cli(*[a.format(d=tmp_path, b=bag) for a in args], check=False, timeout=300)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.count("\n") == 1 and message.format(d=tmp_path, b=bag) in proc.stderr, proc.stderr
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before
