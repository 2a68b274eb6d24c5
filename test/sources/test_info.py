"""``rollergear info``: what a file holds, for every format import reads (files written by each
format's own library, the bundled recordings, the rosbag2 fixtures, a recording cut short)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from rollergear_ros.recordings.baginfo import inspect_bag
from rollergear_ros.base.errors import InputFileError
from rollergear_ros.sources.info import describe

from bagtools import read_mcap_ros2, read_rosbags
from helpers import BAGS, REALDATA, run_cli

N = 2000  # 2 s at 1 kHz
MAP = ("format: timeseries\n{time}motor_torque: {{column: {p}T_in, unit: N*mm}}\n"
       "motor_speed: {{column: {p}n_in, unit: rpm}}\noutput_torque: {{constant: 0, unit: N*m}}\n")


def columns():
    t = np.arange(N) * 1e-3
    return t, {"T_in": 1e3 * (20 + 5 * np.sin(t)), "n_in": 1000 + 0 * t}


def test_an_mcap_recording_as_its_summary_and_both_readers_count_it(tmp_path):
    bag = BAGS / "rig_map.mcap"
    info = describe(bag)
    for read in (read_rosbags, read_mcap_ros2):
        assert {s.name: s.count for s in info.streams} == {topic: len(t) for topic, (t, _m) in read(bag).items()}
    assert {s.name: s.kind for s in info.streams} == inspect_bag(bag).topics
    torque = next(s for s in info.streams if s.name == "/rollergear/motor/torque")
    assert torque.rate_hz == pytest.approx((torque.count - 1) / info.duration_s)
    assert info.metadata and info.damaged == []
    # the command line: text and JSON say the same
    text = run_cli("info", str(bag)).stdout
    assert "format:    MCAP" in text and f"{torque.count:,}" in text and "damaged:   nothing found" in text
    assert json.loads(run_cli("info", str(bag), "--json").stdout)["streams"][0]["count"] == info.streams[0].count


def test_a_recording_cut_short_says_where_it_is_damaged(tmp_path):
    cut = tmp_path / "cut.mcap"
    data = (BAGS / "rig_map.mcap").read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    info = describe(cut)
    assert info.streams and sum(s.count for s in info.streams) < sum(s.count for s in describe(BAGS / "rig_map.mcap")
                                                                    .streams)
    assert any("no usable summary" in d for d in info.damaged)
    assert any(f"{len(data) // 2:,} unreadable" in d for d in info.damaged), info.damaged


def test_rosbag2_bags_folder_and_sqlite(tmp_path):
    fixtures = REALDATA / "rosbag2_test_fixtures"
    if not fixtures.exists():
        pytest.skip("no ../shared/realdata beside the project")
    talker = describe(fixtures / "rosbag2_py/test/resources/sqlite3/talker")
    assert talker.format == "rosbag2" and {"/topic": 10, "/rosout": 10} == {
        s.name: s.count for s in talker.streams if s.count}
    assert "storage_identifier: sqlite3" in talker.metadata
    folder = tmp_path / "cdr_test"
    shutil.copytree(fixtures / "rosbag2_tests/resources/mcap/cdr_test", folder)
    via_yaml = describe(folder / "metadata.yaml")
    assert {s.name: s.kind for s in via_yaml.streams} == {"/array_topic": "test_msgs/msg/Arrays",
                                                          "/test_topic": "test_msgs/msg/BasicTypes"}
    (folder / "metadata.yaml").write_text("rosbag2_bagfile_information: [")
    proc = run_cli("info", str(folder), check=False)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "rosbag2" in proc.stderr


def test_csv_and_parquet_by_columns_and_by_channel_map(tmp_path):
    import pyarrow as pa
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    t, cols = columns()
    table = pa.table({"t_ms": t * 1e3, **cols})
    pacsv.write_csv(table, tmp_path / "rig.csv")
    pq.write_table(table, tmp_path / "rig.parquet")
    cmap = tmp_path / "map.yaml"
    cmap.write_text(MAP.format(time="time: {column: t_ms, unit: ms}\n", p=""))
    for name in ("rig.csv", "rig.parquet"):
        by_columns = describe(tmp_path / name)
        assert [(s.name, s.count) for s in by_columns.streams] == [(c, N) for c in ("t_ms", "T_in", "n_in")], name
        mapped = describe(tmp_path / name, cmap)
        assert mapped.duration_s == pytest.approx((N - 1) * 1e-3)
        rates = {s.name.split()[0]: s.rate_hz for s in mapped.streams}
        assert rates["motor_torque"] == pytest.approx(1000.0) and rates["motor_speed"] == pytest.approx(1000.0)


def test_mdf4_and_tdms_carry_their_time(tmp_path):
    from asammdf import MDF, Signal
    from nptdms import ChannelObject, TdmsWriter

    t, cols = columns()
    mdf = MDF(version="4.10")
    mdf.append([Signal(cols["T_in"], t, name="T_in", unit="Nmm")])
    mdf.append([Signal(cols["n_in"][::10], t[::10], name="n_in", unit="rpm")])
    mdf.save(tmp_path / "rig.mf4")
    mdf.close()
    info = describe(tmp_path / "rig.mf4")
    by_name = {s.name: s for s in info.streams}
    assert by_name["T_in"].count == N and by_name["n_in"].count == N // 10 and by_name["T_in"].kind == "Nmm"
    assert by_name["T_in"].rate_hz == pytest.approx(1000.0) and by_name["n_in"].rate_hz == pytest.approx(100.0)
    with TdmsWriter(tmp_path / "rig.tdms") as writer:
        writer.write_segment([ChannelObject("rig", name, values, properties={"wf_increment": 1e-3})
                              for name, values in cols.items()])
    info = describe(tmp_path / "rig.tdms")
    assert [(s.name, s.count, s.rate_hz) for s in info.streams] == [("rig/T_in", N, 1000.0), ("rig/n_in", N, 1000.0)]
    cmap = tmp_path / "map.yaml"
    cmap.write_text(MAP.format(time="", p="rig/"))
    assert describe(tmp_path / "rig.tdms", cmap).duration_s == pytest.approx((N - 1) * 1e-3)


def test_a_steady_state_table_and_what_is_no_recording(tmp_path):
    vtlm = tmp_path / "axle.vtlm"
    vtlm.write_text("Input Speed [rpm],Input Torque [Nm],Torque Loss [Nm]\n"
                    "0,-100,5\n0,100,5\n1000,-100,6\n1000,100,6\n")
    info = describe(vtlm)
    assert info.format == "VTLM" and [s.count for s in info.streams] == [4, 4, 4]
    (tmp_path / "notes.xlsx").write_bytes(b"PK")
    with pytest.raises(InputFileError, match="not a recording this package reads"):
        describe(tmp_path / "notes.xlsx")


def test_what_a_file_names_cannot_fake_lines_on_the_terminal(tmp_path):
    """Topic names with escape codes and carriage returns were printed as they are."""
    from rollergear_ros.recordings.bagwriter import BagWriter

    with BagWriter(tmp_path / "fake.mcap") as w:
        w.write_float64_series("/a\x1b[2J\rdamaged:   nothing found\nfake", np.arange(1, 3, dtype=np.int64), np.ones(2))
    proc = run_cli("info", str(tmp_path / "fake.mcap"))
    assert "\x1b" not in proc.stdout and "\r" not in proc.stdout
    assert "/a\\x1b[2J\\rdamaged:   nothing found\\nfake" in proc.stdout
    assert [ln for ln in proc.stdout.splitlines() if ln.startswith("damaged:")] == ["damaged:   nothing found"]


def test_a_tdms_increment_that_is_no_number_is_a_note(tmp_path):
    from nptdms import ChannelObject, TdmsWriter

    with TdmsWriter(tmp_path / "r.tdms") as w:
        w.write_segment([ChannelObject("g", "T", np.ones(10), properties={"wf_increment": "fast"})])
    info = describe(tmp_path / "r.tdms")
    assert info.streams[0].rate_hz is None and any("wf_increment 'fast' is no time step" in n for n in info.notes)


@pytest.mark.skipif(not REALDATA.exists(), reason="needs ../shared/realdata")
def test_a_rosbag2_start_time_beyond_any_date_is_said_not_a_traceback(tmp_path):
    src = REALDATA / "rosbag2_test_fixtures/rosbag2_py/test/resources/sqlite3/talker"
    shutil.copytree(src, tmp_path / "bag")
    meta = tmp_path / "bag" / "metadata.yaml"
    meta.write_text(meta.read_text().replace("nanoseconds_since_epoch: 1585866235112411371",
                                             "nanoseconds_since_epoch: 100000000000000000000000"))
    proc = run_cli("info", str(tmp_path / "bag"))
    assert "beyond the years a date holds" in proc.stdout and "Traceback" not in proc.stderr
