"""replay --csv / --parquet / --mf4: the estimates with their inputs, a row per sample, read back
with each format's own library (pyarrow, asammdf)."""

from __future__ import annotations

import datetime

import numpy as np
import pytest
from helpers import BAGS, run_cli

from rollergear_ros.outputs.exports import COLUMNS, Export
from rollergear_ros.core.params import load_config
from rollergear_ros.replay.run import replay


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """One CLI replay of a rig recording with output torque, into all three exports at once."""
    out = tmp_path_factory.mktemp("exports")
    bag = BAGS / "rig_map_drag.mcap"
    proc = run_cli("replay", str(bag), "--no-progress", "--no-png", "--csv", str(out / "e.csv"),
                   "--parquet", str(out / "e.parquet"), "--mf4", str(out / "e.mf4"))
    assert proc.returncode == 0, proc.stderr
    _, batches = replay(bag, load_config(), show_progress=False, collect=True)
    expect = {c.name: np.concatenate([np.full(len(b.t_ns), np.nan) if c.take(b) is None else c.take(b)
                                      for b in batches]) for c in COLUMNS}
    expect["log_time"] = np.concatenate([b.t_ns for b in batches])
    return out, proc.stdout, expect


def _same(got: np.ndarray, want: np.ndarray) -> None:
    np.testing.assert_array_equal(np.asarray(got, np.float64), np.asarray(want, np.float64))


def test_the_csv_has_a_row_per_sample_units_in_its_header_and_the_estimates(exported):
    import pyarrow.csv as pacsv

    out, stdout, expect = exported
    assert f"CSV table: {out / 'e.csv'}" in stdout
    table = pacsv.read_csv(out / "e.csv")
    header = table.column_names
    assert header[:2] == ["time [s]", "log_time [ns]"] and header[2:] == [c.header for c in COLUMNS]
    assert "loss_torque [N*m]" in header and "motor_speed [rad/s]" in header
    assert table.num_rows == len(expect["log_time"]) > 1000
    np.testing.assert_array_equal(table["log_time [ns]"].to_numpy(), expect["log_time"])
    np.testing.assert_allclose(table["time [s]"].to_numpy(), (expect["log_time"] - expect["log_time"][0]) * 1e-9)
    for c in COLUMNS:  # shortest round-trip text: the same doubles
        _same(table[c.header].to_numpy(zero_copy_only=False), expect[c.name])
    assert np.isfinite(table["residual_torque [N*m]"].to_numpy()).any()  # output torque was measured


def test_the_parquet_table_carries_each_columns_unit(exported):
    import pyarrow.parquet as pq

    out, stdout, expect = exported
    table = pq.read_table(out / "e.parquet")
    assert table.column_names == ["time", "log_time", *(c.name for c in COLUMNS)]
    for c in COLUMNS:
        assert table.schema.field(c.name).metadata == {b"unit": c.unit.encode()}
        _same(table[c.name].to_numpy(zero_copy_only=False), expect[c.name])
    np.testing.assert_array_equal(table["log_time"].to_numpy(), expect["log_time"])


def test_the_mdf4_file_has_a_channel_per_quantity_with_its_unit_and_the_start_date(exported):
    from asammdf import MDF

    out, stdout, expect = exported
    with MDF(out / "e.mf4") as mdf:
        start = expect["log_time"][0]
        assert mdf.start_time.astimezone(datetime.UTC) == datetime.datetime.fromtimestamp(start * 1e-9, datetime.UTC)
        for c in COLUMNS:
            sig = mdf.get(c.name)
            assert sig.unit == c.unit
            _same(sig.samples, expect[c.name])
            np.testing.assert_allclose(sig.timestamps, (expect["log_time"] - start) * 1e-9, rtol=0, atol=1e-9)


def test_an_export_of_nothing_has_its_columns_and_a_failed_one_leaves_no_file(tmp_path):
    import pyarrow.csv as pacsv

    empty = Export("csv", tmp_path / "empty.csv")
    empty.close()
    assert pacsv.read_csv(tmp_path / "empty.csv").column_names[2:] == [c.header for c in COLUMNS]
    (tmp_path / "old.parquet").write_bytes(b"old")
    abandoned = Export("parquet", tmp_path / "old.parquet")
    abandoned.close(commit_file=False)
    assert (tmp_path / "old.parquet").read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == [
        "empty.csv", "old.parquet"]


def test_an_export_with_the_suffix_of_another_kind_is_refused_before_any_work(tmp_path):
    proc = run_cli("replay", str(BAGS / "rig_map.mcap"), "--no-progress", "--csv", str(tmp_path / "e.parquet"),
                   check=False)
    assert proc.returncode != 0 and "--csv" in proc.stderr and proc.stderr.count("\n") == 1
    assert list(tmp_path.iterdir()) == []
