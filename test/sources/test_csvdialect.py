"""How a CSV file is written: delimiter, decimal mark, encoding and units row, found from its first lines."""

from __future__ import annotations

import csv

import pytest

from rollergear_ros.sources.channelmap import load_channel_map
from rollergear_ros.sources.csvdialect import SNIFF_LINES, sniff
from rollergear_ros.base.errors import InputFileError

MAP = """format: timeseries
time: {column: t, unit: s}
motor_torque: {column: T in, unit: N*m}
motor_speed: {column: n in, unit: rpm}
"""


def write(path, rows, delimiter=",", encoding="utf-8"):
    """Rows written by Python's csv module (the standard library's writer)."""
    with path.open("w", newline="", encoding=encoding) as fh:
        csv.writer(fh, delimiter=delimiter).writerows(rows)
    return path


@pytest.fixture
def cmap(tmp_path):
    (tmp_path / "map.yaml").write_text(MAP)
    return load_channel_map(tmp_path / "map.yaml")


def data_rows(decimal=".", n=30):
    return [[f"{i * 0.001:.3f}", f"{40 + i * 0.25:.2f}", f"{1500 + i}"] for i in range(n)] if decimal == "." else \
        [[f"{i * 0.001:.3f}".replace(".", ","), f"{40 + i * 0.25:.2f}".replace(".", ","), f"{1500 + i}"]
         for i in range(n)]


@pytest.mark.parametrize(("delimiter", "decimal"), [(",", "."), (";", ","), (";", "."), ("\t", "."), ("\t", ","),
                                                    ("|", ".")])
def test_delimiter_and_decimal_mark_are_found(tmp_path, cmap, delimiter, decimal):
    path = write(tmp_path / "a.csv", [["t", "T in", "n in"], *data_rows(decimal)], delimiter)
    d = sniff(path, cmap)
    assert (d.delimiter, d.decimal_point, d.units, d.header) == (delimiter, decimal, None, ("t", "T in", "n in"))
    assert d.first_data_line == 2


def test_a_comma_file_whose_cells_hold_semicolons_stays_a_comma_file(tmp_path, cmap):
    rows = [["t", "T in", "n in", "note"], *[[*r, "a;b"] for r in data_rows()]]
    assert sniff(write(tmp_path / "a.csv", rows), cmap).delimiter == ","


@pytest.mark.parametrize("unit_cells", [["s", "Nm", "1/min"], ["[s]", "[N·m]", "(rpm)"], ["sec", "N m", "min-1"],
                                        ["s", "N-m", "U/min"], ["sec", "Nm", "min⁻¹"], ["s", "Nm", "rev/min"]])
def test_a_units_row_is_found_skipped_and_agrees_with_the_map(tmp_path, cmap, unit_cells):
    path = write(tmp_path / "a.csv", [["t", "T in", "n in"], unit_cells, *data_rows(",")], ";")
    d = sniff(path, cmap)
    assert d.units is not None and d.first_data_line == 3 and d.decimal_point == ","
    assert d.units["T in"] == unit_cells[1].strip("[]()")


@pytest.mark.parametrize(("unit_cells", "message"), [
    (["s", "kNm", "1/min"], "motor_torque (T in): the file's units row says 'kNm', the channel map says N*m"),
    (["ms", "Nm", "rpm"], "time (t): the file's units row says 'ms', the channel map says s"),
    (["s", "Nm", "rad/s"], "motor_speed (n in): the file's units row says 'rad/s', the channel map says rpm"),
])
def test_a_units_row_that_contradicts_the_map_is_one_line(tmp_path, cmap, unit_cells, message):
    path = write(tmp_path / "a.csv", [["t", "T in", "n in"], unit_cells, *data_rows()])
    with pytest.raises(InputFileError, match="^" + str(path) + ": " + message.replace("(", r"\(").replace(")", r"\)")
                       .replace("*", r"\*") + "$"):
        sniff(path, cmap)


def test_a_first_row_of_numbers_empty_cells_or_nan_is_data_not_units(tmp_path, cmap):
    for first in (["0.0", "", "1500"], ["0", "nan", "NaN"], ["", "", ""]):
        path = write(tmp_path / "a.csv", [["t", "T in", "n in"], first, *data_rows()])
        assert sniff(path, cmap).units is None, first


def test_only_the_maps_columns_decide_whether_the_second_line_is_units(tmp_path, cmap):
    """A text column beside the numbers (a DAQ's event marker) does not make a data row a units row."""
    rows = [["t", "T in", "n in", "event"], ["0.000", "40.0", "1500", "start"], *[[*r, ""] for r in data_rows()]]
    assert sniff(write(tmp_path / "a.csv", rows), cmap).units is None


def test_windows_1252_text_is_read_and_anything_else_is_one_line(tmp_path, cmap):
    path = write(tmp_path / "a.csv", [["t", "T in", "n in", "Öltemp"], ["s", "Nm", "1/min", "°C"],
                                      *[[*r, "40"] for r in data_rows()]], ";", encoding="cp1252")
    d = sniff(path, cmap)
    assert d.encoding == "cp1252" and d.header[3] == "Öltemp" and d.units["Öltemp"] == "°C"
    (tmp_path / "b.csv").write_bytes(b"t,T in,n in\x81\xff\n0,1,2\n")
    with pytest.raises(InputFileError, match="neither UTF-8 nor Windows-1252 text"):
        sniff(tmp_path / "b.csv", cmap)


def test_ragged_or_single_column_files_are_left_to_the_reader(tmp_path, cmap):
    """No consistent delimiter in the first lines: plain CSV, so pyarrow's own error names the row."""
    path = tmp_path / "a.csv"
    path.write_text("t,T in,n in\n" + "0,1,2\n" * 3 + "0,1\n" + "0,1,2\n" * SNIFF_LINES)
    assert sniff(path, cmap).delimiter == ","
    path.write_text("t\n1\n2\n")
    assert sniff(path, cmap).header == ("t",)


def test_a_preamble_before_the_header_line_is_skipped(tmp_path, cmap):
    """A DAQ's preamble (comments, blank lines, ``key: value`` lines, even with the delimiter) ends at
    the first line holding every column of the map."""
    path = tmp_path / "a.csv"
    path.write_text("# exported by rig DAQ v2\n\nRig: 3; operator: A\nsample rate;1000;Hz\n"
                    "t;T in;n in\ns;Nm;rpm\n" + "\n".join(";".join(r) for r in data_rows(",")) + "\n")
    d = sniff(path, cmap)
    assert (d.preamble_lines, d.delimiter, d.decimal_point, d.header) == (4, ";", ",", ("t", "T in", "n in"))
    assert d.units is not None and d.first_data_line == 7
    assert path.read_text().splitlines()[d.first_data_line - 1] == "0,000;40,00;1500"
