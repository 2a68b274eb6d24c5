"""Data in: CSV, Parquet, MDF4 and TDMS (written by each format's own library) and rosbag2 bags
(written by rosbags) -> import -> MCAP read back with mcap and with rosbags."""

from __future__ import annotations

import json
import re
from contextlib import closing

import numpy as np
import pytest

from rollergear_ros.base.errors import InputFileError
from rollergear_ros.sources.importer import import_source

from bagtools import float_series, read_mcap_ros2, read_rosbags
from helpers import BAGS, REALDATA, ROOT, run_cli

RPM = 2 * np.pi / 60
N = 3000  # 3 s at 1 kHz


@pytest.fixture(scope="module")
def signals():
    """A rig's channels in SI (the truth) and the file units they are written in."""
    t = np.arange(N) * 1e-3
    torque = 40 + 20 * np.sin(2 * np.pi * 0.7 * t)  # N·m
    speed = 150 + 30 * np.cos(2 * np.pi * 0.3 * t)  # rad/s
    out_torque = -(torque - 0.3) * 1.368  # a reaction torque, sign flipped by the sensor mounting
    out_speed = speed / 1.368
    temperature = 40 + 5 * t  # °C
    return {"t": t, "torque": torque, "speed": speed, "out_torque": out_torque, "out_speed": out_speed,
            "temperature": temperature}


def write_map(path, own_time: bool = False, **extra):
    """``own_time``: no time entry (MDF4 and TDMS channels carry their own)."""
    lines = ["format: timeseries"] + ([] if own_time else ["time: {column: t_ms, unit: ms}"]) + [
             "motor_torque: {column: T_in, unit: N*mm}", "motor_speed: {column: n_in, unit: rpm}",
             "output_torque: {column: T_out, unit: N*m, scale: -1}", "output_speed: {column: w_out, unit: rad/s}",
             "oil_temperature: {column: T_oil, unit: degF}"]
    lines += [f"{k}: {v}" for k, v in extra.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


def file_columns(s):
    """The channels in the file's units (N·mm, rpm, °F, ms, output torque sign flipped)."""
    return {"t_ms": s["t"] * 1e3, "T_in": s["torque"] * 1e3, "n_in": s["speed"] / RPM, "T_out": -s["out_torque"],
            "w_out": s["out_speed"], "T_oil": s["temperature"] * 9 / 5 + 32}


def check_round_trip(mcap_path, s, resampled_speed: bool = False):
    """Both readers see the SI values at the torque's times."""
    for messages in (read_mcap_ros2(mcap_path), read_rosbags(mcap_path)):
        t, torque = float_series(messages, "/rollergear/motor/torque")
        np.testing.assert_array_equal(t, np.round(s["t"] * 1e9).astype(np.int64))
        np.testing.assert_allclose(torque, s["torque"], rtol=1e-12)
        _, speed = float_series(messages, "/rollergear/motor/speed")
        np.testing.assert_allclose(speed, s["speed"], rtol=1e-3 if resampled_speed else 1e-12)
        _, out_torque = float_series(messages, "/rollergear/output/torque")
        np.testing.assert_allclose(out_torque, s["out_torque"], rtol=1e-12)
        _, out_speed = float_series(messages, "/rollergear/output/speed")
        np.testing.assert_allclose(out_speed, s["out_speed"], rtol=1e-12)
        tt, temps = messages["/rollergear/oil/temperature"]
        theta = np.array([m.temperature for m in temps])
        assert len(theta) == 3  # 3 s at (at most) 1 Hz
        np.testing.assert_allclose(theta, 40 + 5 * tt * 1e-9, rtol=1e-9)


def test_csv_round_trip(tmp_path, signals):
    import pyarrow as pa
    import pyarrow.csv as pacsv

    src = tmp_path / "rig.csv"
    pacsv.write_csv(pa.table(file_columns(signals)), src)
    summary = import_source(src, tmp_path / "rig.mcap", write_map(tmp_path / "map.yaml"))
    assert summary.kind == "CSV" and summary.samples == N and summary.resampled == []
    check_round_trip(tmp_path / "rig.mcap", signals)


@pytest.mark.parametrize("delimiter", [";", "\t"])
def test_a_windows_export_with_decimal_commas_and_a_units_row_round_trips(tmp_path, signals, delimiter):
    """A German DAQ's export (Python's csv writer): ``;`` or tab separated, decimal commas, a row of
    units under the names, Windows-1252 text -- the same values as the plain CSV."""
    import csv

    cols = file_columns(signals)
    names = {"t_ms": "Zeit", "T_in": "Moment ein", "n_in": "Drehzahl", "T_out": "Moment aus", "w_out": "w aus",
             "T_oil": "Öltemperatur"}
    units = ["ms", "N·mm", "1/min", "[Nm]", "rad/s", "°F"]
    with (tmp_path / "rig.csv").open("w", newline="", encoding="cp1252") as fh:
        w = csv.writer(fh, delimiter=delimiter)
        w.writerow(names.values())
        w.writerow(units)
        w.writerows([[repr(float(v)).replace(".", ",") for v in row] for row in zip(*cols.values())])
    cmap = write_map(tmp_path / "map.yaml")
    text = cmap.read_text()
    for old, new in names.items():
        text = text.replace(f"column: {old}", f"column: {new}")
    cmap.write_text(text)
    summary = import_source(tmp_path / "rig.csv", tmp_path / "rig.mcap", cmap)
    assert summary.samples == N
    check_round_trip(tmp_path / "rig.mcap", signals)
    # a units row that contradicts the map is one line naming the file and channel
    cmap.write_text(text.replace("unit: N*mm", "unit: N*m"))
    proc = run_cli("import", str(tmp_path / "rig.csv"), "--channels", str(cmap), "--out", str(tmp_path / "o.mcap"),
                   check=False)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert "motor_torque (Moment ein): the file's units row says 'N·mm', the channel map says N*m" in proc.stderr


def test_the_maps_ratio_gives_the_output_speed_a_replay_of_the_import_measures_with(tmp_path, signals):
    """A rig without an output speed channel: the map's ``ratio`` (not the gearbox's 1.368) makes the
    measured loss; the import writes the output speed it implies and says so."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    from rollergear_ros.core.params import load_config
    from rollergear_ros.calibration.samples import load_samples

    ratio = 5.875
    cols = file_columns(signals)
    del cols["w_out"]
    cols["T_out"] = (signals["torque"] - 0.3) * ratio  # a loss of 0.3 N·m, input-referred
    pacsv.write_csv(pa.table(cols), tmp_path / "rig.csv")
    cmap = write_map(tmp_path / "map.yaml", ratio=ratio)
    cmap.write_text(cmap.read_text().replace("output_speed: {column: w_out, unit: rad/s}\n", "")
                    .replace(", scale: -1}", "}"))
    summary = import_source(tmp_path / "rig.csv", tmp_path / "rig.mcap", cmap)
    assert summary.ratio == ratio and "output speed = motor speed / 5.875" in summary.text()
    for messages in (read_mcap_ros2(tmp_path / "rig.mcap"), read_rosbags(tmp_path / "rig.mcap")):
        _, out_speed = float_series(messages, "/rollergear/output/speed")
        np.testing.assert_allclose(out_speed, signals["speed"] / ratio, rtol=1e-12)
    data = load_samples([tmp_path / "rig.mcap"], load_config())
    assert len(data.measured_loss) > 0.9 * N
    np.testing.assert_allclose(data.measured_loss, 0.3, atol=1e-9)


def test_clock_times_past_midnight_and_a_preamble_are_read(tmp_path):
    """``unit: datetime`` also takes clock times ``HH:MM:SS,fff`` (a DAQ's export), a recording past
    midnight going on into the next day; the lines before the header are the DAQ's preamble."""
    rows = ["# DAQ export", "", "Zeit;T;n;T_out"]
    t0 = 23 * 3600 + 59 * 60 + 59  # 23:59:59
    times = t0 + np.arange(2000) * 1e-3
    for t in times:
        h, rest = divmod(t % 86400, 3600)
        m, sec = divmod(rest, 60)
        rows.append(f"{int(h):02d}:{int(m):02d}:{sec:06.3f}".replace(".", ",") + ";40;1500;54")
    (tmp_path / "rig.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "map.yaml").write_text("time: {column: Zeit, unit: datetime}\nmotor_torque: {column: T, unit: N*m}\n"
                                       "motor_speed: {column: n, unit: rpm}\n"
                                       "output_torque: {column: T_out, unit: N*m}\n")
    import_source(tmp_path / "rig.csv", tmp_path / "rig.mcap", tmp_path / "map.yaml")
    for messages in (read_mcap_ros2(tmp_path / "rig.mcap"), read_rosbags(tmp_path / "rig.mcap")):
        t, torque = float_series(messages, "/rollergear/motor/torque")
        np.testing.assert_array_equal(t, np.round(times * 1e9).astype(np.int64))
        assert (torque == 40).all()


@pytest.mark.parametrize(("text", "message"), [
    ("", "rig.csv: the file is empty"),
    ("t_ms,T_in,n_in\n", "rig.csv: no data rows (only the column names)"),
    ("t_ms,T_in,n_in\n0,1,2\n1,x1,2\n", "rig.csv: motor_torque (T_in): data row 2: 'x1' is not a number"),
    ("t_ms;T_in;n_in\n0;1;2\n1;2,5;2\n2;;3,0\n", None),  # a decimal comma and an empty cell: read
])
def test_empty_files_and_cells_that_are_not_numbers_are_one_line(tmp_path, text, message):
    (tmp_path / "rig.csv").write_text(text)
    (tmp_path / "map.yaml").write_text("time: {column: t_ms, unit: ms}\nmotor_torque: {column: T_in, unit: N*m}\n"
                                       "motor_speed: {column: n_in, unit: rpm}\n")
    proc = run_cli("import", str(tmp_path / "rig.csv"), "--channels", str(tmp_path / "map.yaml"), "--out",
                   str(tmp_path / "o.mcap"), check=False)
    if message is None:
        assert proc.returncode == 0, proc.stderr
        _, torque = float_series(read_mcap_ros2(tmp_path / "o.mcap"), "/rollergear/motor/torque")
        np.testing.assert_array_equal(torque, [1.0, 2.5])  # the row without a torque is no sample
    else:
        assert proc.returncode == 2 and message in proc.stderr and proc.stderr.count("\n") == 1, proc.stderr


def test_parquet_round_trip(tmp_path, signals):
    import pyarrow as pa
    import pyarrow.parquet as pq

    src = tmp_path / "rig.parquet"
    pq.write_table(pa.table(file_columns(signals)), src)
    import_source(src, tmp_path / "rig.mcap", write_map(tmp_path / "map.yaml"))
    check_round_trip(tmp_path / "rig.mcap", signals)


def test_mdf4_with_channels_at_different_rates(tmp_path, signals):
    """A 1 kHz torque beside a 100 Hz speed (CAN) and a 10 Hz temperature, each in its own group."""
    from asammdf import MDF, Signal

    s, cols = signals, file_columns(signals)
    t = s["t"]
    slow = slice(None, None, 10)
    mdf = MDF(version="4.10")
    mdf.append([Signal(cols["T_in"], t, name="T_in", unit="Nmm"), Signal(cols["T_out"], t, name="T_out", unit="Nm"),
                Signal(cols["w_out"], t, name="w_out", unit="rad/s")])
    mdf.append([Signal(cols["n_in"][slow], t[slow], name="n_in", unit="rpm")])
    mdf.append([Signal(cols["T_oil"][::100], t[::100], name="T_oil", unit="°F")])
    src = tmp_path / "rig.mf4"
    mdf.save(src, overwrite=True)
    summary = import_source(src, tmp_path / "rig.mcap", write_map(tmp_path / "map.yaml", own_time=True))
    assert summary.kind == "MDF4" and summary.resampled == ["motor_speed"]
    messages = read_mcap_ros2(tmp_path / "rig.mcap")
    _, speed = float_series(messages, "/rollergear/motor/speed")
    # linear interpolation of the 100 Hz samples, NaN after the last one (no extrapolation)
    last = t[slow][-1]
    inside = t <= last + 1e-12
    expect = np.interp(t[inside], t[slow], s["speed"][slow])
    np.testing.assert_allclose(speed[inside], expect, rtol=1e-12)
    assert np.isnan(speed[~inside]).all() and (~inside).sum() == 9
    np.testing.assert_allclose(speed[inside], s["speed"][inside], rtol=1e-3)  # the cosine itself
    # the unit in the file's metadata is checked against the map
    bad = MDF(version="4.10")
    bad.append([Signal(cols["T_in"], t, name="T_in", unit="Nmm"), Signal(cols["n_in"], t, name="n_in", unit="rad/s")])
    bad.save(tmp_path / "bad.mf4", overwrite=True)
    with pytest.raises(InputFileError, match=r"motor_speed \(n_in\) is in 'rad/s' by the file's metadata"):
        import_source(tmp_path / "bad.mf4", tmp_path / "bad.mcap", tmp_path / "map.yaml")


def test_mdf4_channels_of_one_name_in_several_groups_are_chosen_by_group(tmp_path, signals):
    """A vehicle logger's MDF4 often has one name in several groups (the speed from CAN and from the
    DAQ): ambiguous is one line naming the groups; ``name@G`` picks by the group's number or
    acquisition name; a text channel or a missing one is one line (the latter lists the channels)."""
    from asammdf import MDF, Signal

    s, cols = signals, file_columns(signals)
    t, slow = s["t"], slice(None, None, 10)
    mdf = MDF(version="4.10")
    mdf.append([Signal(cols["T_in"], t, name="T_in", unit="Nmm"), Signal(cols["n_in"] * 0, t, name="n_in", unit="rpm")],
               acq_name="DAQ")
    mdf.append([Signal(cols["n_in"][slow], t[slow], name="n_in", unit="U/min")], acq_name="CAN speed")
    mdf.append([Signal(np.array([b"drive"] * 300), t[slow], name="mode", encoding="latin-1")], acq_name="state")
    src = tmp_path / "rig.mf4"
    mdf.save(src, overwrite=True)
    base = "motor_torque: {column: T_in, unit: N*mm}\n"
    cmap = tmp_path / "map.yaml"
    for column, message in (
            ("n_in", "motor_speed: channel 'n_in' is in 2 data groups (0 'DAQ', 1 'CAN speed'): name one as "
                     "'n_in@0' or 'n_in@1'"),
            ("n_in@5", "motor_speed: no single channel 'n_in' in data group '5' (it is in 0 'DAQ', 1 'CAN speed')"),
            ("mode", "motor_speed (mode): not numbers (samples of type |S5)"),
            ("n", "no channel 'n' for motor_speed (the file has: T_in, mode, n_in)")):
        cmap.write_text(base + f"motor_speed: {{column: {column}, unit: rpm}}\n")
        proc = run_cli("import", str(src), "--channels", str(cmap), "--out", str(tmp_path / "o.mcap"), check=False)
        assert proc.returncode == 2 and message in proc.stderr and proc.stderr.count("\n") == 1, proc.stderr
    for column in ("n_in@1", "n_in@CAN speed"):
        cmap.write_text(base + f"motor_speed: {{column: '{column}', unit: rpm}}\n")
        summary = import_source(src, tmp_path / "rig.mcap", cmap)
        assert summary.resampled == ["motor_speed"]
        _, speed = float_series(read_mcap_ros2(tmp_path / "rig.mcap"), "/rollergear/motor/speed")
        inside = t <= t[slow][-1] + 1e-12
        np.testing.assert_allclose(speed[inside], np.interp(t[inside], t[slow], s["speed"][slow]), rtol=1e-12)


def test_tdms_round_trip(tmp_path, signals):
    from nptdms import ChannelObject, TdmsWriter

    cols = file_columns(signals)
    units = {"T_in": "Nmm", "n_in": "rpm", "T_out": "Nm", "w_out": "rad/s", "T_oil": "degF"}
    src = tmp_path / "rig.tdms"
    with TdmsWriter(src) as writer:
        writer.write_segment([ChannelObject("rig", name, cols[name],
                                            properties={"unit_string": unit, "wf_increment": 1e-3,
                                                        "wf_start_offset": 0.0}) for name, unit in units.items()])
    cmap = tmp_path / "map.yaml"
    cmap.write_text(write_map(tmp_path / "m0.yaml", own_time=True).read_text().replace("column: ", "column: rig/"))
    summary = import_source(src, tmp_path / "rig.mcap", cmap)
    assert summary.kind == "TDMS"
    check_round_trip(tmp_path / "rig.mcap", signals)
    # a missing channel lists the file's; a text channel is not numbers
    with TdmsWriter(src, mode="a") as writer:
        writer.write_segment([ChannelObject("rig", "mode", np.array(["drive"] * N))])
    for old, new, message in (("rig/n_in", "rig/n", "no channel 'rig/n' for motor_speed (TDMS channels are named "
                                                     "group/channel; the file has: rig/T_in, rig/n_in, rig/T_out"),
                              ("rig/n_in", "rig/mode", "motor_speed (rig/mode): not numbers")):
        (tmp_path / "bad.yaml").write_text(cmap.read_text().replace(old, new))
        with pytest.raises(InputFileError, match=re.escape(message)):
            import_source(src, tmp_path / "bad.mcap", tmp_path / "bad.yaml")


@pytest.mark.parametrize(("mutate", "message"), [
    (lambda m: m.replace("unit: rpm", "unit: furlongs"), "unknown unit 'furlongs'"),
    (lambda m: m.replace("column: n_in", "column: n_missing"), "no column 'n_missing' for motor_speed"),
    (lambda m: m.replace("motor_speed: {column: n_in, unit: rpm}\n", ""), "no motor_speed channel"),
    (lambda m: m.replace("format: timeseries", "format: sometimes"), "not one of timeseries, steady_state"),
    (lambda m: m + "speed_of_light: 3\n", "unknown key(s) speed_of_light"),
    (lambda m: m.replace("{column: T_oil, unit: degF}", "[T_oil]"), "expected {column: NAME, unit: UNIT}"),
])
def test_bad_channel_maps_are_one_line(tmp_path, signals, mutate, message):
    import pyarrow as pa
    import pyarrow.csv as pacsv

    src = tmp_path / "rig.csv"
    pacsv.write_csv(pa.table(file_columns(signals)), src)
    cmap = write_map(tmp_path / "map.yaml")
    cmap.write_text(mutate(cmap.read_text()))
    proc = run_cli("import", str(src), "--channels", str(cmap), "--out", str(tmp_path / "o.mcap"), check=False)
    assert proc.returncode == 2 and message in proc.stderr and proc.stderr.count("\n") == 1, proc.stderr
    assert not (tmp_path / "o.mcap").exists()


def test_time_that_runs_backwards_is_refused(tmp_path, signals):
    import pyarrow as pa
    import pyarrow.csv as pacsv

    cols = file_columns(signals)
    cols["t_ms"] = cols["t_ms"].copy()
    cols["t_ms"][100] = cols["t_ms"][50]
    pacsv.write_csv(pa.table(cols), tmp_path / "rig.csv")
    proc = run_cli("import", str(tmp_path / "rig.csv"), "--channels", str(write_map(tmp_path / "m.yaml")),
                   "--out", str(tmp_path / "o.mcap"), check=False)
    assert proc.returncode == 2 and "time (t_ms) runs backwards after data row 100" in proc.stderr


@pytest.mark.parametrize(("value", "shown"), [(float("inf"), "inf"), (-1e30, "-1e+30")])
def test_a_time_that_is_not_a_finite_time_is_refused(tmp_path, signals, value, shown):
    """An infinite or out-of-range time is refused: it used to become an arbitrary int64.

    (numpy's invalid cast; ``nan`` is one of pyarrow's null spellings: an empty cell, a row
    without a sample.)
    """
    import pyarrow as pa
    import pyarrow.csv as pacsv

    cols = file_columns(signals)
    cols["t_ms"] = cols["t_ms"].copy()
    cols["t_ms"][7] = value
    pacsv.write_csv(pa.table(cols), tmp_path / "rig.csv")
    proc = run_cli("import", str(tmp_path / "rig.csv"), "--channels", str(write_map(tmp_path / "m.yaml")),
                   "--out", str(tmp_path / "o.mcap"), check=False)
    assert proc.returncode == 2 and f"time (t_ms) is not a finite time at data row 8 ({shown} ms)" in proc.stderr, \
        proc.stderr


def test_a_csv_header_in_neither_utf8_nor_windows_1252_is_one_line(tmp_path):
    (tmp_path / "rig.csv").write_bytes(b"t_ms,T_\x81in\n1,2\n")
    proc = run_cli("import", str(tmp_path / "rig.csv"), "--channels", str(write_map(tmp_path / "m.yaml")),
                   "--out", str(tmp_path / "o.mcap"), check=False)
    assert proc.returncode == 2 and "the header is neither UTF-8 nor Windows-1252 text (byte 0x81" in proc.stderr
    assert proc.stderr.count("\n") == 1, proc.stderr
    (tmp_path / "rig.csv").write_bytes(b"t_ms,T_\xe9in\n1,2\n")  # Windows-1252: the names are read
    proc = run_cli("import", str(tmp_path / "rig.csv"), "--channels", str(write_map(tmp_path / "m.yaml")),
                   "--out", str(tmp_path / "o.mcap"), check=False)
    assert proc.returncode == 2 and "no column 'T_in' for motor_torque (the file has: t_ms, T_\u00e9in)" in proc.stderr


def _rosbag2(tmp_path, storage: str):
    """The bundled drag recording rewritten as a rosbag2 bag by rosbags' own writer."""
    from mcap.reader import make_reader
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    out = tmp_path / f"bag_{storage}"
    plugin = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}[storage]
    store = get_typestore(Stores.ROS2_JAZZY)
    with Writer(out, version=8, storage_plugin=plugin) as writer, (BAGS / "rig_map_drag.mcap").open("rb") as fh:
        conns = {}
        for schema, channel, message in make_reader(fh).iter_messages(log_time_order=False):
            if channel.topic not in conns:
                conns[channel.topic] = writer.add_connection(channel.topic, schema.name, typestore=store)
            writer.write(conns[channel.topic], message.log_time, message.data)
    return out


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_rosbag2_replays_like_the_mcap_it_was_made_from(tmp_path, storage):
    bag = _rosbag2(tmp_path, storage)
    a = run_cli("calibrate", str(BAGS / "rig_map_drag.mcap"), "--json").stdout
    b = run_cli("calibrate", str(bag), "--json").stdout
    assert json.loads(a) == json.loads(b)
    run_cli("import", str(bag), "--out", str(tmp_path / "imported.mcap"))
    original, imported = read_mcap_ros2(BAGS / "rig_map_drag.mcap"), read_rosbags(tmp_path / "imported.mcap")
    for topic in ("/rollergear/motor/torque", "/rollergear/output/torque"):
        t0, v0 = float_series(original, topic)
        t1, v1 = float_series(imported, topic)
        np.testing.assert_array_equal(t0, t1)
        np.testing.assert_array_equal(v0, v1)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_rosbag2_bag_whose_metadata_qos_differs_from_its_storage_is_imported_whole(tmp_path, storage):
    """rosbag2 of 2020 wrote one QoS text to metadata.yaml and another to the storage; rosbags then
    finds none of the topics' messages (shown here), and the import reads every one of them."""
    import yaml
    from rosbags.highlevel import AnyReader

    from rollergear_ros.recordings.bagwriter import offered_qos_yaml

    bag = _rosbag2(tmp_path, storage)
    meta = bag / "metadata.yaml"
    doc = yaml.safe_load(meta.read_text())
    for topic in doc["rosbag2_bagfile_information"]["topics_with_message_count"]:
        topic["topic_metadata"]["offered_qos_profiles"] = offered_qos_yaml(reliable=False, depth=7)
    meta.write_text(yaml.safe_dump(doc))
    with AnyReader([bag]) as reader:
        assert reader.message_count > 0 and next(reader.messages(), None) is None  # the trap
    run_cli("import", str(bag), "--out", str(tmp_path / "imported.mcap"))
    original, imported = read_mcap_ros2(BAGS / "rig_map_drag.mcap"), read_rosbags(tmp_path / "imported.mcap")
    for topic in ("/rollergear/motor/torque", "/rollergear/motor/speed", "/rollergear/output/torque"):
        t0, v0 = float_series(original, topic)
        t1, v1 = float_series(imported, topic)
        np.testing.assert_array_equal(t0, t1)
        np.testing.assert_array_equal(v0, v1)


@pytest.mark.skipif(not REALDATA.exists(), reason=f"no shared real data at {REALDATA}")
@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_every_topic_of_a_rosbag2_bag_is_copied_for_play(tmp_path, storage):
    """``copy_rosbag2`` (what ``play`` publishes a rosbag2 bag from): every topic and message of
    ros2/rosbag2's talker bag, whose metadata and storage QoS differ, against the storage read by
    its own library (SQLite) or the mcap reader."""
    from rollergear_ros.recordings.baginfo import inspect_bag
    from rollergear_ros.sources.importer import copy_rosbag2

    src = REALDATA / f"rosbag2_test_fixtures/rosbag2_py/test/resources/{storage}/talker"
    expected: dict[str, list[tuple[int, bytes]]] = {}
    if storage == "sqlite3":
        import sqlite3

        with closing(sqlite3.connect(src / "talker.db3")) as db:
            for topic, t_ns, data in db.execute("SELECT topics.name, timestamp, data FROM messages JOIN topics "
                                                "ON messages.topic_id = topics.id ORDER BY timestamp"):
                expected.setdefault(topic, []).append((t_ns, bytes(data)))
    else:
        from mcap.reader import make_reader

        with (src / "talker.mcap").open("rb") as fh:
            for _, channel, message in make_reader(fh).iter_messages(log_time_order=True):
                expected.setdefault(channel.topic, []).append((message.log_time, message.data))
    out = tmp_path / "copy.mcap"
    counts = copy_rosbag2(src, out)
    assert counts == {"/topic": 10, "/rosout": 10, "/parameter_events": 0}
    assert {t: len(m) for t, m in expected.items()} == {"/topic": 10, "/rosout": 10}
    got: dict[str, list[tuple[int, bytes]]] = {}
    for topic, t_ns, data in _raw_messages(out):
        got.setdefault(topic, []).append((t_ns, data))
    assert got == expected
    assert inspect_bag(out).topics == {"/topic": "std_msgs/msg/String", "/rosout": "rcl_interfaces/msg/Log",
                                       "/parameter_events": "rcl_interfaces/msg/ParameterEvent"}


def _raw_messages(path):
    """(topic, log time, bytes) of an MCAP in log-time order, by the mcap library."""
    from mcap.reader import make_reader

    with path.open("rb") as fh:
        return [(c.topic, m.log_time, m.data) for _, c, m in make_reader(fh).iter_messages(log_time_order=True)]


FIXTURES = REALDATA / "rosbag2_test_fixtures"


@pytest.mark.skipif(not FIXTURES.exists(), reason=f"no shared real data at {FIXTURES}")
@pytest.mark.parametrize(("bag", "topic"), [
    ("rosbag2_py/test/resources/sqlite3/talker", "/topic (std_msgs/msg/String)"),
    ("rosbag2_py/test/resources/sqlite3/talker/talker.db3", "/rosout (rcl_interfaces/msg/Log)"),
    ("rosbag2_py/test/resources/mcap/talker/metadata.yaml", "/topic (std_msgs/msg/String)"),
    ("rosbag2_py/test/resources/mcap/reindex_test_bags/multiple_files", "/chatter"),
])
def test_rosbag2_fixtures_without_input_topics_say_which_topics_they_have(bag, topic):
    """ros2/rosbag2's own test bags (SQLite, MCAP, a split bag without metadata): read by both
    storage plugins, and refused in one line naming the topics they do have."""
    proc = run_cli("replay", str(FIXTURES / bag), check=False)
    assert proc.returncode == 2 and "no input topics" in proc.stderr and topic in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr and proc.stderr.count("\n") == 1, proc.stderr


def test_calibrate_on_a_channel_mapped_csv_finds_what_the_mcap_gives(tmp_path):
    """The bundled drag recording exported to a rig-DAQ style CSV (rpm, N·mm, seconds) is
    calibrated through its channel map to the effect the MCAP gives."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    messages = read_mcap_ros2(BAGS / "rig_map_drag.mcap")
    t, torque = float_series(messages, "/rollergear/motor/torque")
    cols = {"time_s": (t - t[0]) * 1e-9, "torque_nmm": torque * 1e3}
    for topic, name in (("/rollergear/motor/speed", "speed_rpm"), ("/rollergear/output/torque", "out_torque_nm"),
                        ("/rollergear/output/speed", "out_speed_rpm")):
        tt, v = float_series(messages, topic)
        np.testing.assert_array_equal(tt, t)  # the recording logs the four channels at the same times
        cols[name] = v / RPM if name.endswith("rpm") else v
    pacsv.write_csv(pa.table(cols), tmp_path / "daq.csv")
    cmap = tmp_path / "daq.yaml"
    cmap.write_text("time: {column: time_s, unit: s}\nmotor_torque: {column: torque_nmm, unit: N*mm}\n"
                    "motor_speed: {column: speed_rpm, unit: rpm}\noutput_torque: {column: out_torque_nm, unit: N*m}\n"
                    "output_speed: {column: out_speed_rpm, unit: rpm}\n")
    from_csv = json.loads(run_cli("calibrate", str(tmp_path / "daq.csv"), "--channels", str(cmap), "--json").stdout)
    from_mcap = json.loads(run_cli("calibrate", str(BAGS / "rig_map_drag.mcap"), "--json").stdout)
    assert from_csv["verdict"] == from_mcap["verdict"] == "effects_found"
    assert [e["name"] for e in from_csv["effects"]] == [e["name"] for e in from_mcap["effects"]]
    for a, b in zip(from_csv["effects"], from_mcap["effects"]):
        for k in a["params"]:
            assert a["params"][k] == pytest.approx(b["params"][k], rel=1e-6)
    # and replay reads it too
    out = run_cli("replay", str(tmp_path / "daq.csv"), "--channels", str(cmap), "--no-progress")
    assert "imported" in out.stderr and f"{len(t):,}" in out.stdout


# ------------------------------------------------------------------------------------ steady-state tables
VTLM_HEADER = "Input Speed [rpm],Input Torque [Nm],Torque Loss [Nm]\n"


def table_rows(reverse: bool = True):
    """Operating points (rpm, N·m) driving, in overrun, at standstill and (``reverse``) turning the
    other way (a VECTO map has no negative speeds), with a loss the model does not make."""
    rows = []
    for rpm in (0.0, 500.0, 1500.0, -1000.0 if reverse else 2500.0):
        for torque in (-60.0, 5.0, 40.0, 80.0):
            rows.append((rpm, torque, 0.3 + 0.01 * abs(torque) + 1e-4 * abs(rpm)))
    return np.array(rows)


def check_table_recording(path, rows):
    """Both readers: one sample per moving row, 1 s apart, whose power balance gives the row's loss."""
    moving = rows[rows[:, 0] != 0]
    for messages in (read_mcap_ros2(path), read_rosbags(path)):
        t, torque = float_series(messages, "/rollergear/motor/torque")
        np.testing.assert_array_equal(np.diff(t), np.full(len(moving) - 1, 1_000_000_000))
        np.testing.assert_array_equal(torque, moving[:, 1])
        t_w, speed = float_series(messages, "/rollergear/motor/speed")
        np.testing.assert_array_equal(t_w, t)
        np.testing.assert_allclose(speed, moving[:, 0] * RPM, rtol=1e-15)
        _, out_torque = float_series(messages, "/rollergear/output/torque")
        _, out_speed = float_series(messages, "/rollergear/output/speed")
        loss = (torque * speed - out_torque * out_speed) / np.abs(speed)
        np.testing.assert_allclose(loss, moving[:, 2], rtol=1e-12)
    return messages


def test_a_vtlm_is_imported_one_sample_per_row_its_loss_in_the_power_balance(tmp_path):
    rows = table_rows(reverse=False)
    src = tmp_path / "gearbox.vtlm"
    src.write_text("# a loss map\n" + VTLM_HEADER + "".join(f"{r[0]:g},{r[1]:g},{r[2]:.6f}\n" for r in rows))
    out = tmp_path / "gearbox.mcap"
    proc = run_cli("import", str(src), "--out", str(out))
    assert "12 samples" in proc.stdout and "4 rows at standstill left out" in proc.stdout, proc.stdout
    check_table_recording(out, np.round(rows, 6))


def test_a_steady_state_csv_by_efficiency_is_imported_with_its_temperatures(tmp_path):
    """A channel-mapped CSV of efficiencies (driving and regenerating) and oil temperatures."""
    rows = table_rows()
    rpm, torque, loss = rows.T
    driving = torque * rpm > 0
    eta = np.where(driving, 1 - loss / np.abs(torque), np.abs(torque) / (np.abs(torque) + loss))
    theta = np.linspace(40.0, 80.0, len(rows))
    src = tmp_path / "map.csv"
    src.write_text("n,T,eta_pct,oil_K\n" + "".join(
        f"{a!r},{b!r},{100 * c!r},{d + 273.15!r}\n" for a, b, c, d in zip(*map(np.ndarray.tolist,
                                                                             (rpm, torque, eta, theta)))))
    cmap = tmp_path / "map.yaml"
    cmap.write_text("format: steady_state\nmotor_speed: {column: n, unit: rpm}\nmotor_torque: {column: T, unit: N*m}\n"
                    "efficiency: {column: eta_pct, unit: '%'}\noil_temperature: {column: oil_K, unit: K}\n")
    out = tmp_path / "map.mcap"
    summary = import_source(src, out, cmap)
    assert summary.samples == 12 and summary.left_out == 4
    messages = check_table_recording(out, rows)
    t_temp, temps = messages["/rollergear/oil/temperature"]
    np.testing.assert_allclose([m.temperature for m in temps], theta[rpm != 0], rtol=1e-12)
    np.testing.assert_array_equal(t_temp, float_series(messages, "/rollergear/motor/torque")[0])


def test_replay_of_a_table_is_replay_of_its_import_and_its_residual_is_the_tables_loss_minus_the_model(tmp_path):
    from rollergear_ros.core.model import LossModel
    from rollergear_ros.core.params import load_config
    from rollergear_ros.replay.run import replay

    rows = table_rows(reverse=False)
    src = tmp_path / "gearbox.vtlm"
    src.write_text(VTLM_HEADER + "".join(f"{r[0]:g},{r[1]:g},{r[2]:.6f}\n" for r in rows))
    out = tmp_path / "estimates.mcap"
    run_cli("replay", str(src), "--out", str(out), "--no-png")
    imported = tmp_path / "imported.mcap"
    import_source(src, imported)
    config = load_config()
    _, batches = replay(imported, config, show_progress=False, collect=True)
    residual = np.concatenate([b.residual_nm for b in batches])
    moving = np.round(rows[rows[:, 0] != 0], 6)
    model = LossModel(config.gearbox).loss_magnitude(moving[:, 1], moving[:, 0] * RPM)
    np.testing.assert_allclose(residual, moving[:, 2] - model, rtol=1e-9, atol=1e-12)
    _, published = float_series(read_rosbags(out), "/rollergear/residual/torque")
    np.testing.assert_array_equal(published, residual)


def test_a_table_of_several_gearbox_states_is_refused_in_one_line(tmp_path):
    src = tmp_path / "states.csv"
    src.write_text("gear,n,T,L\n" + "".join(f"{g},{n},{t},0.5\n" for g in (1, 2) for n in (500, 1000)
                                             for t in (10, 20)))
    cmap = tmp_path / "m.yaml"
    cmap.write_text("format: steady_state\nmotor_speed: {column: n, unit: rpm}\nmotor_torque: {column: T, unit: N*m}\n"
                    "loss_torque: {column: L, unit: N*m}\ngroup: {column: gear}\n")
    proc = run_cli("import", str(src), "--channels", str(cmap), "--out", str(tmp_path / "o.mcap"), check=False)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "2 gearbox states" in proc.stderr, proc.stderr
    assert not (tmp_path / "o.mcap").exists()


def test_temperature_payloads_are_what_the_typestore_serialises():
    """The importer's oil temperatures are a template patched with numpy: byte for byte what the
    typestore's own serializer gives for each stamp and value; a stamp beyond int32 seconds is one
    clear error."""
    from rollergear_ros.recordings.messages import encoder_for, temperature_payloads
    from rollergear_ros.base.errors import BagError
    from rollergear_ros.base.interface import MessageType

    encode = encoder_for(MessageType.TEMPERATURE)
    t = np.array([0, 1, 999_999_999, 1_700_000_000_123_456_789, -1_500_000_000], dtype=np.int64)
    theta = np.array([20.0, -40.5, 1e-300, 85.25, np.nan])
    rows = temperature_payloads(t, theta, variance=0.25, frame_id="oil")
    for row, tt, v in zip(rows, t.tolist(), theta.tolist()):
        sec, nanosec = divmod(tt, 1_000_000_000)
        assert row.tobytes() == encode({"header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": "oil"},
                                        "temperature": v, "variance": 0.25})
    with pytest.raises(BagError, match="int32 seconds"):
        temperature_payloads(np.array([2**31 * 1_000_000_000], dtype=np.int64), np.array([20.0]))


def _tdms(path, props: dict, n: int = 200) -> None:
    from nptdms import ChannelObject, TdmsWriter

    with TdmsWriter(path) as w:
        w.write_segment([ChannelObject("g", "T", np.full(n, 5.0), properties=props),
                         ChannelObject("g", "w", np.full(n, 10.0), properties=props)])


TDMS_MAP = "motor_torque: {column: g/T, unit: N*m}\nmotor_speed: {column: g/w, unit: rad/s}\n"


@pytest.mark.parametrize(("props", "start_ns", "step_ns"), [
    ({"wf_increment": 1e-3}, 0, 1_000_000),  # no wf_start_offset: 0, as NI's readers take it (was a KeyError)
    ({"wf_increment": 2e-3, "wf_start_offset": 0.5}, 500_000_000, 2_000_000),
    ({"wf_increment": 1e-3, "wf_start_time": np.datetime64("2026-11-24T08:30:00", "us")},
     int(np.datetime64("2026-11-24T08:30:00", "ns").astype(np.int64)), 1_000_000),  # the file's own date
])
def test_tdms_waveforms_carry_their_own_time(tmp_path, props, start_ns, step_ns):
    src = tmp_path / "rig.tdms"
    _tdms(src, props)
    (tmp_path / "map.yaml").write_text(TDMS_MAP)  # no time entry: the contract says none is needed
    import_source(src, tmp_path / "o.mcap", tmp_path / "map.yaml")
    for messages in (read_mcap_ros2(tmp_path / "o.mcap"), read_rosbags(tmp_path / "o.mcap")):
        t, torque = float_series(messages, "/rollergear/motor/torque")
        np.testing.assert_array_equal(t, start_ns + step_ns * np.arange(200))
        assert (torque == 5.0).all()


def test_mdf4_time_is_the_files_own_or_the_channel_the_map_names(tmp_path):
    """MDF4 channels carry their own time (from the measurement's start in the header); a map that
    names a time channel used to be ignored."""
    import datetime

    from asammdf import MDF, Signal

    t = np.arange(100) * 0.01
    mdf = MDF(version="4.10")
    mdf.header.start_time = datetime.datetime(2026, 11, 24, 8, 30, tzinfo=datetime.UTC)
    mdf.append([Signal(np.full(100, 5.0), t, name="T", unit="Nm"), Signal(np.full(100, 10.0), t, name="w"),
                Signal(1000.0 * t + 250.0, t, name="t_daq", unit="ms")])
    src = tmp_path / "rig.mf4"
    mdf.save(src, overwrite=True)
    start = int(np.datetime64("2026-11-24T08:30:00", "ns").astype(np.int64))
    cmap = tmp_path / "map.yaml"
    cmap.write_text("motor_torque: {column: T, unit: N*m}\nmotor_speed: {column: w, unit: rad/s}\n")
    import_source(src, tmp_path / "o.mcap", cmap)
    got, _ = float_series(read_rosbags(tmp_path / "o.mcap"), "/rollergear/motor/torque")
    np.testing.assert_array_equal(got, start + np.round(t * 1e9).astype(np.int64))
    cmap.write_text(cmap.read_text() + "time: {column: t_daq, unit: ms}\n")
    import_source(src, tmp_path / "o.mcap", cmap)
    got, _ = float_series(read_rosbags(tmp_path / "o.mcap"), "/rollergear/motor/torque")
    np.testing.assert_array_equal(got, start + np.round((t + 0.25) * 1e9).astype(np.int64))


def test_a_csv_time_that_starts_below_zero_is_shifted_and_said(tmp_path):
    """Negative times (a DAQ's pre-trigger) were a struct.error and an invalid MCAP left at --out."""
    (tmp_path / "rig.csv").write_text("t,T,w\n-1.0,1,10\n-0.5,2,10\n0,3,10\n0.5,4,10\n")
    (tmp_path / "map.yaml").write_text("time: {column: t, unit: s}\nmotor_torque: {column: T, unit: N*m}\n"
                                       "motor_speed: {column: w, unit: rad/s}\n")
    proc = run_cli("import", str(tmp_path / "rig.csv"), "--channels", str(tmp_path / "map.yaml"), "--out",
                   str(tmp_path / "o.mcap"))
    assert "time started at -1 s: shifted by 1 s to start at 0" in proc.stdout
    t, torque = float_series(read_mcap_ros2(tmp_path / "o.mcap"), "/rollergear/motor/torque")
    np.testing.assert_array_equal(t, [0, 500_000_000, 1_000_000_000, 1_500_000_000])
    np.testing.assert_array_equal(torque, [1, 2, 3, 4])


def _damaged_db3(tmp_path):
    src = REALDATA / "rosbag2_test_fixtures/rosbag2_py/test/resources/sqlite3/talker/talker.db3"
    (tmp_path / "d.db3").write_bytes(src.read_bytes()[:3000])
    return tmp_path / "d.db3", "database disk image is malformed"


def _damaged_metadata(tmp_path):
    import shutil

    shutil.copytree(REALDATA / "rosbag2_test_fixtures/rosbag2_py/test/resources/sqlite3/talker", tmp_path / "bag")
    (tmp_path / "bag" / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: [\n")
    return tmp_path / "bag", "a damaged rosbag2 metadata.yaml (not valid YAML"


def _bad_tdms(value):
    def make(tmp_path):
        _tdms(tmp_path / "r.tdms", {"wf_increment": value, "wf_start_offset": 0.0})
        (tmp_path / "map.yaml").write_text(TDMS_MAP)
        return tmp_path / "r.tdms", f"wf_increment = {value!r} s"
    return make


def _truncated_mf4(tmp_path):
    from asammdf import MDF, Signal

    mdf = MDF(version="4.10")
    mdf.append([Signal(np.ones(10), np.arange(10) * 0.1, name="T", unit="Nm")])
    mdf.save(tmp_path / "a.mf4", overwrite=True)
    (tmp_path / "r.mf4").write_bytes((tmp_path / "a.mf4").read_bytes()[:300])
    (tmp_path / "map.yaml").write_text("motor_torque: {column: T, unit: N*m}\nmotor_speed: {column: T, unit: rad/s}\n"
                                       .replace("column: T, unit: rad/s", "column: W, unit: rad/s"))
    return tmp_path / "r.mf4", "not an MDF file asammdf can read"


def _map_problem(text, message):
    def make(tmp_path):
        (tmp_path / "r.csv").write_text("t,T,w\n0,1,10\n1,1,10\n")
        (tmp_path / "map.yaml").write_text(text)
        return tmp_path / "r.csv", message
    return make


def _time_problem(times, extra, message):
    def make(tmp_path):
        (tmp_path / "r.csv").write_text("t,T,w\n" + "".join(f"{t},1,10\n" for t in times))
        (tmp_path / "map.yaml").write_text(BASE_MAP.replace("unit: s}", "unit: datetime}") + extra)
        return tmp_path / "r.csv", message
    return make


BASE_MAP = "time: {column: t, unit: s}\nmotor_torque: {column: T, unit: N*m}\nmotor_speed: {column: w, unit: rad/s}\n"


@pytest.mark.skipif(not REALDATA.exists(), reason="needs ../shared/realdata")
@pytest.mark.parametrize("make", [
    _damaged_db3, _damaged_metadata, _bad_tdms(float("nan")), _bad_tdms(float("inf")), _bad_tdms(-0.001),
    _truncated_mf4,
    _map_problem(BASE_MAP + "motor_speed: {column: w, unit: rpm}\n", "the key 'motor_speed' is given twice"),
    _map_problem(BASE_MAP + "output_torque: {column: T, unit: N*m}\n", "column 'T' is mapped to both motor_torque "
                 "and output_torque"),
    _map_problem(BASE_MAP + "ratio: .inf\n", "ratio must be a number in [0.0001, 10000]"),
    _map_problem(BASE_MAP + "ratio: 1.0e-300\n", "ratio must be a number in [0.0001, 10000]"),
    _map_problem(BASE_MAP + "output_torque: {constant: null, unit: N*m}\n", "constant must be a finite number"),
    _map_problem(BASE_MAP + f"output_torque: {{constant: {'9' * 400}, unit: N*m}}\n",
                 "constant must be a finite number"),
    _map_problem(BASE_MAP + f"output_torque: {{column: T, unit: N*m, scale: {'9' * 400}}}\n",
                 "scale must be a finite non-zero number"),
    *(_time_problem(times, extra, "is not ISO 8601 date-times of one kind") for times, extra in (
        (["1500-01-01T00:00:00", "1500-01-01T00:00:01"], ""), (["2300-01-01T00:00:00", "2300-01-01T00:00:01"], ""),
        (["3170843-01-01T00:00:00", "3170843-01-01T00:00:01"], ""),
        (["2024-13-01T00:00:00", "2024-13-01T00:00:01"], ""),
        (["2024-01-01T00:00:00", "2024-01-01T00:00:01+01:00"], ""),
        (["2024-01-01T00:00:00+25:00", "2024-01-01T00:00:01+25:00"], ""))),
    _time_problem(["23:59:59", "00:00:01"], "date: 9999-12-31\n", "outside the years 1678-2261"),
    _time_problem(["25:61:61", "25:61:62"], "date: 2024-01-01\n", "'25:61:61' is not a clock time"),
])
def test_imports_that_were_tracebacks_are_one_line_and_leave_no_file(tmp_path, make):
    src, message = make(tmp_path)
    args = ["import", str(src), "--out", str(tmp_path / "o.mcap")]
    if (tmp_path / "map.yaml").exists():
        args += ["--channels", str(tmp_path / "map.yaml")]
    proc = run_cli(*args, check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and "Exception ignored" not in proc.stderr
    assert proc.stderr.count("\n") == 1 and message in proc.stderr, proc.stderr
    assert not (tmp_path / "o.mcap").exists() and not list(tmp_path.glob("*.partial"))


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
@pytest.mark.parametrize("batch_rows,lag_ms", [(7, 0.0), (64, 0.0), (1000, 0.0), (7, 7.3), (64, 23.5), (1000, -4.2)])
def test_reading_in_batches_gives_the_values_of_reading_the_file_whole(tmp_path, signals, suffix, batch_rows, lag_ms):
    """CSV and Parquet are imported in bounded batches; a channel with empty cells is interpolated
    across batch boundaries and the temperature thinned over the whole file, exactly as
    ``align(read_series(...))`` of the whole file does -- also with the output torque read ``lag_ms``
    later than the drive torque (the map's ``lag_s``: its samples belong that much earlier)."""
    import pyarrow as pa
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    from rollergear_ros.sources.arrowstream import aligned_batches
    from rollergear_ros.sources.channelmap import load_channel_map
    from rollergear_ros.sources.timeseries import align, read_series

    cols = {k: pa.array(v) for k, v in file_columns(signals).items()}
    n = len(signals["t"])
    rng = np.random.default_rng(1)
    for name, every in (("n_in", 10), ("w_out", 3), ("T_oil", 50)):  # slower channels: empty cells between
        mask = np.ones(n, bool)
        mask[::every] = False
        mask[rng.integers(0, n, 40)] = True
        cols[name] = pa.array(np.asarray(file_columns(signals)[name]), mask=mask)
    cols["T_in"] = pa.array(np.asarray(file_columns(signals)["T_in"]), mask=np.isin(np.arange(n), [5, 6, 700]))
    src = tmp_path / f"rig{suffix}"
    if suffix == ".csv":
        pacsv.write_csv(pa.table(cols), src)
    else:
        pq.write_table(pa.table(cols), src)
    path = write_map(tmp_path / "map.yaml")
    if lag_ms:
        path.write_text(path.read_text().replace("scale: -1}", f"scale: -1, lag_s: {lag_ms / 1e3}}}"))
    cmap = load_channel_map(path)
    assert cmap.channels["output_torque"].lag_s == lag_ms / 1e3
    whole = align(read_series(src, cmap))
    parts = list(aligned_batches(src, cmap, batch_rows=batch_rows))
    assert len(parts) > 1 or batch_rows >= n
    np.testing.assert_array_equal(np.concatenate([p.t_ns for p in parts]), whole.t_ns)
    for name, values in whole.values.items():
        np.testing.assert_array_equal(np.concatenate([p.values[name] for p in parts]), values, err_msg=name)
    np.testing.assert_array_equal(np.concatenate([p.temperature.t_ns for p in parts if p.temperature]),
                                  whole.temperature.t_ns)
    assert parts[-1].resampled == whole.resampled, (parts[-1].resampled, whole.resampled)


@pytest.mark.slow
def test_a_parquet_file_of_millions_of_rows_is_imported_within_bounded_memory(tmp_path):
    """An 817 KB Parquet file of 30 M rows took more than 3.5 GB in 8 s.  Six million rows (a
    few megabytes on disk) read whole take about 1.6 GB; in batches the import stays far below the
    1 GB the README promises (the child process's peak resident memory)."""
    import subprocess
    import sys

    import pyarrow as pa
    import pyarrow.parquet as pq

    n = 6_000_000
    t = np.arange(n, dtype=np.int64)  # ms
    pq.write_table(pa.table({"t_ms": t, "T_in": np.full(n, 40e3), "n_in": np.full(n, 1000.0),
                             "T_out": np.full(n, 54.0), "w_out": np.full(n, 76.0)}), tmp_path / "big.parquet",
                   row_group_size=1_000_000)
    (tmp_path / "map.yaml").write_text(write_map(tmp_path / "m.yaml").read_text().replace(
        "oil_temperature: {column: T_oil, unit: degF}\n", ""))
    # the peak of the child's own memory (VmHWM): ru_maxrss would carry over the forking pytest's
    # resident size (Linux keeps it across fork and exec), large after a whole suite
    script = ("import sys; from rollergear_ros.cli.main import main; rc = main(sys.argv[1:]); "
              "hwm = next(line for line in open('/proc/self/status') if line.startswith('VmHWM:')); "
              "print('peak_kib', hwm.split()[1], file=sys.stderr); sys.exit(rc)")
    proc = subprocess.run([sys.executable, "-c", script, "import", str(tmp_path / "big.parquet"), "--channels",
                           str(tmp_path / "map.yaml"), "--out", str(tmp_path / "big.mcap")],
                          capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    peak_kib = int(proc.stderr.split("peak_kib")[1].split()[0])  # this process's own peak, not another test's
    assert "6,000,000 samples, 24,000,000 messages" in proc.stdout
    assert peak_kib < 1_000_000, f"peak {peak_kib / 1024:.0f} MiB"
    from rollergear_ros.recordings.baginfo import inspect_bag

    info = inspect_bag(tmp_path / "big.mcap")
    assert info.counts["/rollergear/motor/torque"] == n


def _one_torque_time(tmp_path, text: str, map_extra: str, time_unit: str = "datetime") -> tuple[int, str, dict]:
    (tmp_path / "rig.csv").write_text(text, encoding="utf-8")
    (tmp_path / "map.yaml").write_text(f"time: {{column: Zeit, unit: {time_unit}}}\nmotor_torque: {{column: M, unit: "
                                       f"N*m}}\nmotor_speed: {{column: n, unit: rpm}}\n{map_extra}")
    proc = run_cli("import", str(tmp_path / "rig.csv"), "--channels", str(tmp_path / "map.yaml"), "--out",
                   str(tmp_path / "o.mcap"))
    t, _ = float_series(read_rosbags(tmp_path / "o.mcap"), "/rollergear/motor/torque")
    from rollergear_ros.recordings.baginfo import read_metadata

    return int(t[0]), proc.stdout, read_metadata(tmp_path / "o.mcap", "rollergear_import")


def _utc_ns(text: str) -> int:
    return int(np.datetime64(text, "ns").astype(np.int64))


@pytest.mark.parametrize(("extra", "expected", "said"), [
    ("", "2026-11-24T08:00:00", "date-times without a zone taken as UTC"),
    ("timezone: Europe/Berlin\n", "2026-11-24T07:00:00", None),  # CET = UTC+1 in November
    ("timezone: '-05:00'\n", "2026-11-24T13:00:00", None),
])
def test_date_times_without_a_zone_are_in_the_maps_timezone_or_utc_said(tmp_path, extra, expected, said):
    """Naive ISO date-times were read as UTC without a word."""
    t0, stdout, meta = _one_torque_time(tmp_path, "Zeit,M,n\n2026-11-24T08:00:00,1,100\n2026-11-24T08:00:01,1,100\n",
                                        extra)
    assert t0 == _utc_ns(expected)
    if said:
        assert said in stdout and said in meta["time"]
    else:
        assert "taken as UTC" not in stdout


def test_a_date_time_with_its_own_zone_is_that_instant_whatever_the_map_says(tmp_path):
    rows = "Zeit,M,n\n2026-11-24T08:00:00+02:00,1,100\n2026-11-24T08:00:01+02:00,1,100\n"
    t0, _, _ = _one_torque_time(tmp_path, rows, "timezone: Europe/Berlin\n")
    assert t0 == _utc_ns("2026-11-24T06:00:00")


def test_a_daqs_preamble_date_puts_clock_times_on_their_day(tmp_path):
    """A German DAQ writes ``Datum;24.11.2026`` above clock times: they landed on 1970-01-01."""
    text = "Messung;Prüfstand 3\nDatum;24.11.2026\n\nZeit;M;n\n23:59:59,500;1;100\n00:00:00,500;1;100\n"
    t0, stdout, meta = _one_torque_time(tmp_path, text, "date: {preamble: Datum}\ntimezone: Europe/Berlin\n")
    assert t0 == _utc_ns("2026-11-24T22:59:59.5")  # 23:59:59.5 CET
    t, _ = float_series(read_mcap_ros2(tmp_path / "o.mcap"), "/rollergear/motor/torque")
    assert int(t[1]) - int(t[0]) == 1_000_000_000  # past midnight into the 25th
    t0, stdout, meta = _one_torque_time(tmp_path, text, "")  # no date: said
    assert t0 == _utc_ns("1970-01-01T23:59:59.5") and "clock times without a date" in stdout
    (tmp_path / "map.yaml").write_text((tmp_path / "map.yaml").read_text() + "date: {preamble: Datum2}\n")
    proc = run_cli("import", str(tmp_path / "rig.csv"), "--channels", str(tmp_path / "map.yaml"), "--out",
                   str(tmp_path / "o.mcap"), check=False)
    assert proc.returncode == 2 and "no preamble line 'Datum2'" in proc.stderr


def test_clock_times_past_midnight_read_in_batches_equal_the_file_read_whole(tmp_path):
    from rollergear_ros.sources.arrowstream import aligned_batches
    from rollergear_ros.sources.channelmap import load_channel_map
    from rollergear_ros.sources.timeseries import align, read_series

    clock = [f"23:59:{s:02d}" for s in range(50, 60)] + [f"00:00:{s:02d}" for s in range(0, 10)]
    (tmp_path / "rig.csv").write_text("Zeit,M,n\n" + "".join(f"{c},1,100\n" for c in clock))
    (tmp_path / "map.yaml").write_text("time: {column: Zeit, unit: datetime}\nmotor_torque: {column: M, unit: N*m}\n"
                                       "motor_speed: {column: n, unit: rpm}\ndate: 2026-11-24\n")
    cmap = load_channel_map(tmp_path / "map.yaml")
    whole = align(read_series(tmp_path / "rig.csv", cmap)).t_ns
    import pyarrow as pa
    import pyarrow.parquet as pq

    # batches of 3 rows (the CSV reader's blocks are larger): the same clock times as Parquet text
    pq.write_table(pa.table({"Zeit": clock, "M": [1.0] * 20, "n": [100.0] * 20}), tmp_path / "rig.parquet")
    parts = np.concatenate([p.t_ns for p in aligned_batches(tmp_path / "rig.parquet", cmap, batch_rows=3)])
    np.testing.assert_array_equal(parts, whole)
    assert np.all(np.diff(whole) == 1_000_000_000) and whole[0] == _utc_ns("2026-11-24T23:59:50")


def test_a_constant_channel_is_a_spin_test(tmp_path):
    """``output_torque: {constant: 0, unit: N*m}``: a joint or gearbox driven with nothing on its
    output -- the drive torque is all loss; the constant is written at every sample (CSV and MDF4)."""
    from asammdf import MDF, Signal

    t = np.arange(200) * 0.01
    torque = 0.3 + 0.1 * np.sin(t)
    (tmp_path / "spin.csv").write_text("t,T\n" + "".join(f"{a:.3f},{b:.6f}\n" for a, b in zip(t, torque)))
    cmap = ("motor_torque: {column: T, unit: N*m}\nmotor_speed: {constant: 600, unit: rpm}\n"
            "output_torque: {constant: 0, unit: N*m}\n")
    (tmp_path / "map.yaml").write_text("time: {column: t, unit: s}\n" + cmap + "ratio: 2\n")
    import_source(tmp_path / "spin.csv", tmp_path / "spin.mcap", tmp_path / "map.yaml")
    mdf = MDF(version="4.10")
    mdf.append([Signal(torque, t, name="T", unit="Nm")])
    mdf.save(tmp_path / "spin.mf4", overwrite=True)
    (tmp_path / "mmap.yaml").write_text(cmap + "ratio: 2\n")
    import_source(tmp_path / "spin.mf4", tmp_path / "spin_mf4.mcap", tmp_path / "mmap.yaml")
    for mcap in ("spin.mcap", "spin_mf4.mcap"):
        messages = read_rosbags(tmp_path / mcap)
        _, out = float_series(messages, "/rollergear/output/torque")
        _, speed = float_series(messages, "/rollergear/motor/speed")
        _, drive = float_series(messages, "/rollergear/motor/torque")
        assert len(out) == len(drive) == 200 and (out == 0).all()
        np.testing.assert_allclose(speed, 600 * RPM)
        np.testing.assert_allclose(drive, torque, atol=1e-6)  # the CSV holds 6 decimals


@pytest.mark.parametrize(("entry", "message"), [
    ("output_torque: {constant: .nan, unit: N*m}", "constant must be a finite number"),
    ("output_torque: {constant: 0, column: T_out, unit: N*m}", "expected {column: NAME, unit: UNIT} or {constant"),
    ("time: {constant: 0, unit: s}", "time cannot be constant"),
])
def test_bad_constants_are_one_line(tmp_path, entry, message):
    from rollergear_ros.sources.channelmap import load_channel_map

    (tmp_path / "m.yaml").write_text("motor_torque: {column: T, unit: N*m}\nmotor_speed: {column: n, unit: rpm}\n"
                                     + entry + "\n")
    with pytest.raises(InputFileError, match=re.escape(message)):
        load_channel_map(tmp_path / "m.yaml")


def test_a_damaged_tdms_is_read_as_far_as_it_goes_and_said_in_one_line(tmp_path):
    """The warnings nptdms printed to stderr (with a dump of the damaged bytes) are one note in the
    import's summary."""
    src = tmp_path / "rig.tdms"
    _tdms(src, {"wf_increment": 1e-3})
    src.write_bytes(src.read_bytes()[:-500])  # the last segment's data cut short
    (tmp_path / "map.yaml").write_text(TDMS_MAP)
    proc = run_cli("import", str(src), "--channels", str(tmp_path / "map.yaml"), "--out", str(tmp_path / "o.mcap"))
    assert "nptdms" not in proc.stderr and proc.stderr == ""
    assert "damaged TDMS, read as far as nptdms could (" in proc.stdout
    assert "Last segment of file has less data than expected" in proc.stdout
