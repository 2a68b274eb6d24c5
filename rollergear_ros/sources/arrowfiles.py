"""CSV and Parquet time series through a channel map, with ``pyarrow``.

A CSV's header, delimiter, decimal mark, encoding and units row come from
:func:`~.csvdialect.sniff`; its time column (numbers, date-times or clock times) from
:mod:`.clocktimes`.  :func:`read_arrow_series` is the registry's reader of both formats
(:mod:`.formats`); the streaming import of large files (:mod:`.arrowstream`) reads their columns
with the same functions.  No rclpy import.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..base.errors import InputFileError
from .channelmap import ChannelMap, ChannelSpec
from .clocktimes import time_base, time_column_ns
from .csvdialect import is_number, sniff
from .formats import is_format
from .timeseries import Series

__all__ = ["arrow_table", "csv_reading", "first_line", "has_value", "numeric_column", "read_arrow_series",
           "require_columns"]


def arrow_table(path: Path, cmap: ChannelMap):
    """The map's columns of a CSV or Parquet file as a ``pyarrow.Table`` (a missing column: one line),
    and the line number of its first data row (for messages; 2 for Parquet: after a header).

    A CSV's header line, delimiter, decimal mark, encoding and units row are found by
    :func:`~.csvdialect.sniff`."""
    import pyarrow as pa

    wanted = sorted(set(cmap.columns()))
    if is_format(path, "CSV"):
        import pyarrow.csv as pacsv

        dialect, convert = csv_reading(path, cmap)
        try:
            table = pacsv.read_csv(path, read_options=dialect.read_options(), parse_options=dialect.parse_options(),
                                   convert_options=convert)
        except pa.ArrowInvalid as exc:
            raise InputFileError(f"{path}: {exc}") from None
        first_line = dialect.first_data_line
    else:
        import pyarrow.parquet as pq

        try:
            available = pq.read_schema(path).names
        except (pa.ArrowException, OSError) as exc:
            raise InputFileError(f"{path}: not a Parquet file ({first_line(exc)})") from None
        require_columns(path, cmap, available)
        try:
            table = pq.read_table(path, columns=wanted)
        except (pa.ArrowException, OSError) as exc:  # a damaged page or footer
            raise InputFileError(f"{path}: a damaged Parquet file ({first_line(exc)})") from None
        first_line = 2
    if table.num_rows == 0:
        raise InputFileError(f"{path}: no data rows (only the column names)")
    return table, first_line


def first_line(exc: BaseException) -> str:
    """The first line of an error's text (pyarrow's thrift errors run over several)."""
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0]


def numeric_column(path: Path, name: str, spec: ChannelSpec, table) -> np.ndarray:
    """A numeric column as float64 (null -> NaN); anything else is one line naming the channel; a
    constant channel is its constant on every row."""
    import pyarrow as pa

    if spec.constant is not None:
        return np.full(table.num_rows, spec.constant)
    col = table.column(spec.column)
    if not (pa.types.is_floating(col.type) or pa.types.is_integer(col.type) or pa.types.is_null(col.type)):
        if pa.types.is_string(col.type) or pa.types.is_large_string(col.type):
            for row, cell in enumerate(col.to_pylist(), start=1):
                if cell is not None and not is_number(cell, ","):
                    raise InputFileError(f"{path}: {name} ({spec.column}): data row {row}: {cell!r} is not a number")
        raise InputFileError(f"{path}: {name} ({spec.column}): not numbers (column type {col.type})")
    return col.to_numpy(zero_copy_only=False).astype(np.float64)


def read_arrow_series(path: Path, cmap: ChannelMap, notes: list[str] | None = None) -> dict[str, Series]:
    table, _ = arrow_table(path, cmap)
    t_col = table.column(cmap.time.column)
    t_valid = ~np.asarray(t_col.is_null())
    base = time_base(path, cmap, sniff(path, cmap) if is_format(path, "CSV") else None)
    t_ns = time_column_ns(path, cmap.time, t_col, base, notes=notes)
    back = np.flatnonzero(np.diff(t_ns[t_valid]) < 0)
    if back.size:
        raise InputFileError(f"{path}: time ({cmap.time.column}) runs backwards after data row {int(back[0]) + 1} "
                             "(time must not decrease)")
    out = {}
    for name, spec in cmap.channels.items():
        values = numeric_column(path, name, spec, table)
        present = t_valid & has_value(table, spec)  # empty cell: no sample here
        out[name] = Series(t_ns[present], spec.to_si(values[present]))
    return out


def has_value(table, spec: ChannelSpec) -> np.ndarray:
    """The rows of ``table`` with a value of the channel (a constant: every row)."""
    if spec.constant is not None:
        return np.ones(table.num_rows, dtype=bool)
    return ~np.asarray(table.column(spec.column).is_null())


def csv_reading(path: Path, cmap: ChannelMap):
    """A CSV's dialect (:func:`~.csvdialect.sniff`) and the pyarrow conversion of the map's columns,
    once the file is known to have them."""
    import pyarrow.csv as pacsv

    dialect = sniff(path, cmap)
    if not dialect.header:
        raise InputFileError(f"{path}: the file is empty")
    require_columns(path, cmap, list(dialect.header))
    return dialect, pacsv.ConvertOptions(include_columns=sorted(set(cmap.columns())),
                                         decimal_point=dialect.decimal_point)


def require_columns(path: Path, cmap: ChannelMap, available: list[str]) -> None:
    specs = [("time", cmap.time.column)] if cmap.time is not None else []
    specs += [(name, spec.column) for name, spec in cmap.channels.items() if spec.constant is None]
    specs += [("group", cmap.group)] if cmap.group is not None else []
    for name, column in specs:
        if column not in available:
            raise InputFileError(f"{path}: no column {column!r} for {name} (the file has: "
                                 f"{', '.join(available[:20])}{' …' if len(available) > 20 else ''})")
