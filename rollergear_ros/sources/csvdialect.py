"""How a CSV file is written -- header line, delimiter, decimal mark, encoding, units row -- from its first lines.

Rig DAQs and spreadsheets do not all write ``,``-separated files with ``.`` decimals.  A German
export is ``;``-separated with decimal commas (``0,125``), a tab-separated one comes from a
copy-paste, and many DAQs write a row of units under the column names.  :func:`sniff` reads the
first lines and finds:

* the **delimiter**: of ``,`` ``;`` tab ``|``, the one that splits the header and every data line
  read into the same number (≥ 2) of cells; of several, the one giving the most cells;
* the **decimal mark**: ``,`` when the delimiter is not ``,`` and the data's numbers are written
  with a decimal comma (``-12,5``), ``.`` otherwise;
* the **header line**: the first line holding every column the channel map names -- lines before
  it (a DAQ's preamble: ``# rig 3``, ``Date: …``, blank lines) are skipped; without a map, the
  first line that is not blank;
* the **encoding**: UTF-8 (with or without a byte-order mark), else Windows-1252 (what Windows
  tools in western locales write: ``Öltemp`` as one byte ``0xD6``);
* a **units row**: the line after the header when none of the map's columns holds a number there
  (``s;Nm;1/min``; ``[Nm]`` and ``(Nm)`` are read as ``Nm``).  It is skipped, and a unit it states
  that contradicts the channel map is one :class:`~base.errors.InputFileError` line, as for the units
  in MDF4 and TDMS metadata.

No rclpy import.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

from .channelmap import ChannelMap, unit_matches
from ..base.errors import InputFileError

__all__ = ["CsvDialect", "DELIMITERS", "is_number", "preamble_value", "sniff"]

DELIMITERS = (",", ";", "\t", "|")
SNIFF_LINES = 20  #: data lines looked at (after the header)
PREAMBLE_LINES = 100  #: lines searched for the header line
_SNIFF_BYTES = 1 << 16
_DECIMAL_COMMA = re.compile(r"^[+-]?\d*,\d+(?:[eE][+-]?\d+)?$")


@dataclass(frozen=True)
class CsvDialect:
    """What :func:`sniff` found in a CSV file."""

    delimiter: str = ","
    decimal_point: str = "."
    encoding: str = "utf8"
    header: tuple[str, ...] = ()  #: the column names
    units: dict[str, str] | None = None  #: column -> unit text of the units row (None: the file has none)
    preamble_lines: int = 0  #: lines before the header line

    @property
    def first_data_line(self) -> int:
        """The 1-based line number of the first data row."""
        return self.preamble_lines + (2 if self.units is None else 3)

    def parse_options(self):
        import pyarrow.csv as pacsv

        return pacsv.ParseOptions(delimiter=self.delimiter)

    def read_options(self):
        import pyarrow.csv as pacsv

        return pacsv.ReadOptions(skip_rows=self.preamble_lines, skip_rows_after_names=0 if self.units is None else 1,
                                 encoding=self.encoding)


def preamble_value(path: str | Path, dialect: CsvDialect, label: str) -> str | None:
    """The value a DAQ's preamble gives ``label`` (``Datum;24.11.2026``, ``Date: 2026-11-24``): the
    cell after the label on the first preamble line that starts with it (None: no such line)."""
    raw, _ = _lines(Path(path))
    for line in raw[:dialect.preamble_lines]:
        for delimiter in (dialect.delimiter, *DELIMITERS, ":", "="):
            cells = [c.strip() for c in line.split(delimiter)]
            if len(cells) >= 2 and cells[0].rstrip(":").strip() == label and cells[1]:
                return cells[1]
    return None


def _lines(path: Path) -> tuple[list[str], str]:
    """The lines of the file's first 64 KiB (text, BOM removed), and the encoding."""
    with path.open("rb") as fh:
        head = fh.read(_SNIFF_BYTES)
    if len(head) == _SNIFF_BYTES and b"\n" in head:
        head = head[: head.rindex(b"\n")]  # no line cut in the middle
    try:
        text, encoding = head.decode("utf-8-sig"), "utf8"
    except UnicodeDecodeError as exc:
        try:
            text, encoding = head.decode("cp1252"), "cp1252"
        except UnicodeDecodeError:
            raise InputFileError(f"{path}: the header is neither UTF-8 nor Windows-1252 text (byte "
                                 f"0x{exc.object[exc.start]:02x} at offset {exc.start})") from None
    return text.splitlines(), encoding


def _header_index(raw: list[str], cmap: ChannelMap | None) -> int:
    """Index of the header line: the first holding every column of the map (else the first not blank)."""
    wanted = set(cmap.columns()) if cmap is not None else set()
    for i, line in enumerate(raw[:PREAMBLE_LINES]):
        if wanted and any(wanted <= set(next(csv.reader([line], delimiter=d), []))
                          for d in DELIMITERS):
            return i
    return next((i for i, line in enumerate(raw) if line.strip()), 0)


def _rows(path: Path, lines: list[str], delimiter: str) -> list[list[str]]:
    try:
        return list(csv.reader(lines, delimiter=delimiter))
    except csv.Error as exc:
        raise InputFileError(f"{path}: the header is not a CSV row ({exc})") from None


def _unit_text(cell: str) -> str:
    cell = cell.strip()
    if len(cell) >= 2 and cell[0] + cell[-1] in ("[]", "()"):
        cell = cell[1:-1].strip()
    return cell


def is_number(cell: str, decimal_point: str = ".") -> bool:
    """Whether a CSV cell is a number (with ``decimal_point`` ``,`` a decimal comma, or a point)."""
    try:
        float(cell.replace(",", ".") if decimal_point == "," else cell)
    except ValueError:
        return False
    return True


def sniff(path: str | Path, cmap: ChannelMap | None = None) -> CsvDialect:
    """The dialect of the CSV file ``path`` (see the module docstring); with ``cmap`` the units row
    is recognised by the map's columns and checked against the map's units."""
    path = Path(path)
    raw, encoding = _lines(path)
    start = _header_index(raw, cmap)
    lines = [line for line in raw[start:] if line.strip()][: SNIFF_LINES + 1]
    if not lines:
        return CsvDialect(encoding=encoding)
    best: tuple[int, str, list[list[str]]] | None = None
    for delimiter in DELIMITERS:
        rows = _rows(path, lines, delimiter)
        width = len(rows[0])
        if width >= 2 and all(len(r) == width for r in rows) and (best is None or width > best[0]):
            best = (width, delimiter, rows)
    if best is None:  # one column, or ragged lines: read as plain CSV; pyarrow names what is wrong
        return CsvDialect(encoding=encoding, header=tuple(_rows(path, lines[:1], ",")[0]), preamble_lines=start)
    _width, delimiter, rows = best
    header, data = rows[0], rows[1:]
    decimal_point = "."
    if delimiter != "," and any(_DECIMAL_COMMA.match(c.strip()) for r in data for c in r):
        decimal_point = ","
    units = None
    if data:
        wanted = [header.index(c) for c in (cmap.columns() if cmap else header) if c in header]
        second = data[0]
        if wanted and not any(is_number(second[i], decimal_point) for i in wanted) \
                and any(second[i].strip() for i in wanted):
            units = {header[i]: _unit_text(second[i]) for i in range(len(header))}
    dialect = CsvDialect(delimiter, decimal_point, encoding, tuple(header), units, start)
    if units is not None and cmap is not None:
        _check_units(path, cmap, units)
    return dialect


def _check_units(path: Path, cmap: ChannelMap, units: dict[str, str]) -> None:
    specs = dict(cmap.channels)
    if cmap.time is not None:
        specs["time"] = cmap.time
    for name, spec in specs.items():
        stated = units.get(spec.column, "")
        if spec.unit == "datetime" or unit_matches(name, stated, spec.unit):
            continue
        raise InputFileError(f"{path}: {name} ({spec.column}): the file's units row says {stated!r}, "
                             f"the channel map says {spec.unit}")
