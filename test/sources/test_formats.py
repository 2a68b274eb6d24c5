"""The input-format table: what a path is, the suffixes every reader takes from it, and a toy
format added as one entry (with its reader) that import, play and the fleet's collector then know."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rollergear_ros.cli import main as cli

from rollergear_ros.sources import formats
from rollergear_ros.base.errors import InputFileError
from rollergear_ros.fleet.logs import discover
from rollergear_ros.sources.formats import INPUT_FORMATS, InputFormat, input_format, recording_suffixes, suffixes
from rollergear_ros.sources.timeseries import Series

from bagtools import float_series, read_mcap_ros2, read_rosbags


def test_every_suffix_names_one_format_and_every_time_series_has_a_reader():
    every = suffixes()
    assert len(every) == len(set(every)), every
    for fmt in INPUT_FORMATS.values():
        assert fmt.family in ("mcap", "rosbag2", "timeseries", "table"), fmt
        if fmt.family == "timeseries":
            assert callable(fmt.read_series()), fmt.name
    assert ".vtlm" not in recording_suffixes() and {".mcap", ".db3", ".csv", ".mf4", ".tdms"} <= set(
        recording_suffixes())


def test_what_a_path_is(tmp_path):
    (tmp_path / "bag").mkdir()
    (tmp_path / "bag" / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    for name, expected in (("bag", "rosbag2"), ("bag/metadata.yaml", "rosbag2"), ("x.db3", "rosbag2"),
                           ("x.MCAP", "MCAP"), ("x.vtlm", "VTLM"), ("x.csv", "CSV"), ("x.parquet", "Parquet"),
                           ("x.mdf", "MDF4"), ("x.tdms", "TDMS")):
        path = tmp_path / name
        if not path.exists():
            path.write_bytes(b"")
        assert input_format(path).name == expected, name
    (tmp_path / "x.xlsx").write_bytes(b"")
    with pytest.raises(InputFileError, match=r"x\.xlsx: not a recording this package reads .*\.tdms"):
        input_format(tmp_path / "x.xlsx")
    with pytest.raises(InputFileError, match="does not exist"):
        input_format(tmp_path / "missing.csv")


# ------------------------------------------------------------------------------------ a toy format
def read_jsonl_series(path, cmap, notes=None):
    """A toy reader: one JSON object per line, time in the map's column in milliseconds."""
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    t_ns = np.round(np.array([r[cmap.time.column] for r in rows]) * 1e6).astype(np.int64)
    return {name: Series(t_ns, spec.to_si(np.array([r[spec.column] for r in rows], dtype=float)))
            for name, spec in cmap.channels.items()}


@pytest.fixture
def toy_format():
    fmt = formats.register(InputFormat("JSONL", (".jsonl",), "timeseries", reader=read_jsonl_series))
    try:
        yield fmt
    finally:
        formats.unregister("JSONL")


def test_a_registered_toy_format_is_imported_played_and_collected(toy_format, tmp_path, capsys):
    n = 500
    t_ms = np.arange(n, dtype=float)
    torque = 30 + 10 * np.sin(t_ms / 50)
    rows = [{"t_ms": t, "T_in": tq * 1e3, "n_in": 1000.0, "T_out": tq * 1.3, "w_out": 80.0}
            for t, tq in zip(t_ms.tolist(), torque.tolist())]
    src = tmp_path / "logs" / "rig.jsonl"
    src.parent.mkdir()
    src.write_text("".join(json.dumps(r) + "\n" for r in rows))
    cmap = tmp_path / "map.yaml"
    cmap.write_text("format: timeseries\ntime: {column: t_ms, unit: ms}\nmotor_torque: {column: T_in, unit: N*mm}\n"
                    "motor_speed: {column: n_in, unit: rpm}\noutput_torque: {column: T_out, unit: N*m}\n"
                    "output_speed: {column: w_out, unit: rad/s}\n")
    assert input_format(src) is toy_format
    # import: the one entry is enough to read it; both MCAP readers see the SI values
    out = tmp_path / "rig.mcap"
    assert cli.main(["import", str(src), "--channels", str(cmap), "--out", str(out)]) == 0
    assert "(JSONL)" in capsys.readouterr().out
    for messages in (read_mcap_ros2(out), read_rosbags(out)):
        t, values = float_series(messages, "/rollergear/motor/torque")
        np.testing.assert_array_equal(t, np.round(t_ms * 1e6).astype(np.int64))
        np.testing.assert_allclose(values, torque, rtol=1e-12)
    # play names it and the way to a recording it can publish
    assert cli.main(["play", str(src)]) == 2
    err = capsys.readouterr().err
    assert "is a JSONL file" in err and "--channels MAP.yaml" in err
    # the fleet collects it among the recordings of a folder
    assert [r.path for r in discover([str(tmp_path / "logs")])] == [str(src)]
