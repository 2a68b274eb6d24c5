"""Time series from non-ROS files -- CSV, Parquet, ASAM MDF4, NI TDMS -- through a channel map.

One reader per format behind :func:`read_series` (the format by the file's suffix), each with the
format's own library: ``pyarrow`` (CSV, Parquet), ``asammdf`` (MDF4), ``nptdms`` (TDMS).  Every
channel comes back in SI units with its own time base; :func:`align` puts them on the motor
torque's time base by the offline rule:

* a channel whose samples fall on the motor torque's time stamps is taken as it is;
* any other (a 100 Hz speed beside a 1 kHz torque, a CSV whose slower columns have empty cells)
  is **linearly interpolated between its two neighbouring samples** -- one sample of look-ahead,
  which offline replay can afford; nothing is extrapolated: before a channel's first and after its
  last sample it is NaN (such samples are skipped and counted by the estimator);
* the oil temperature keeps its own time stamps (at most one per second: oil warms over minutes,
  and each temperature message splits the MCAP's vectorised writing of the samples); the estimator holds it
  (zero-order, up to 5 s), as the live node does -- which never looks ahead.

A missing column, a unit the file's metadata contradicts, or a time that runs backwards is one
:class:`~.errors.InputFileError` line naming the file and the channel.  No rclpy import.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .channelmap import ChannelMap, ChannelSpec, unit_matches
from .csvdialect import is_number, sniff
from .errors import InputFileError
from .interface import Channel

__all__ = ["Aligned", "Series", "TIMESERIES_SUFFIXES", "align", "arrow_table", "numeric_column", "read_series"]

TIMESERIES_SUFFIXES = {".csv": "CSV", ".parquet": "Parquet", ".mf4": "MDF4", ".mdf": "MDF4", ".tdms": "TDMS"}
TEMPERATURE_MAX_RATE_HZ = 1.0


@dataclass
class Series:
    """One channel's samples in SI units on its own time base (int64 ns, non-decreasing)."""

    t_ns: np.ndarray
    values: np.ndarray


@dataclass
class Aligned:
    """The paired channels on the motor torque's time base, and the oil temperature on its own."""

    t_ns: np.ndarray
    values: dict[str, np.ndarray]  #: paired channel -> values at ``t_ns`` (NaN: no sample there)
    temperature: Series | None
    resampled: list[str]  #: channels that were interpolated (for the import's metadata)


def read_series(path: str | Path, cmap: ChannelMap) -> dict[str, Series]:
    """Every channel of the map from ``path``, in SI, each on its own time base."""
    path = Path(path)
    if not path.exists():
        raise InputFileError(f"{path} does not exist")
    if not path.is_file():  # a folder, a FIFO or a device
        raise InputFileError(f"{path} is not a regular file")
    kind = TIMESERIES_SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise InputFileError(f"{path}: unknown time-series format {path.suffix!r} "
                             f"(one of {', '.join(sorted(TIMESERIES_SUFFIXES))})")
    if cmap.format != "timeseries":
        raise InputFileError(f"{path}: the channel map {cmap.path} is for format: {cmap.format}, not timeseries")
    reader = {"CSV": _read_arrow, "Parquet": _read_arrow, "MDF4": _read_mdf4, "TDMS": _read_tdms}[kind]
    series = reader(path, cmap)
    for name, s in series.items():
        back = np.flatnonzero(np.diff(s.t_ns) < 0)
        if back.size:
            raise InputFileError(f"{path}: {name} ({cmap.channels[name].column}): time runs backwards after "
                                 f"sample {int(back[0])} (time must not decrease)")
    return series


# ------------------------------------------------------------------------------------ CSV / Parquet
def arrow_table(path: Path, cmap: ChannelMap):
    """The map's columns of a CSV or Parquet file as a ``pyarrow.Table`` (a missing column: one line),
    and the line number of its first data row (for messages; 2 for Parquet: after a header).

    A CSV's header line, delimiter, decimal mark, encoding and units row are found by
    :func:`~.csvdialect.sniff`."""
    import pyarrow as pa

    wanted = sorted(set(cmap.columns()))
    if path.suffix.lower() == ".csv":
        import pyarrow.csv as pacsv

        dialect = sniff(path, cmap)
        if not dialect.header:
            raise InputFileError(f"{path}: the file is empty")
        _require(path, cmap, list(dialect.header))
        convert = pacsv.ConvertOptions(include_columns=wanted, decimal_point=dialect.decimal_point)
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
        except pa.ArrowInvalid as exc:
            raise InputFileError(f"{path}: not a Parquet file ({exc})") from None
        _require(path, cmap, available)
        table = pq.read_table(path, columns=wanted)
        first_line = 2
    if table.num_rows == 0:
        raise InputFileError(f"{path}: no data rows (only the column names)")
    return table, first_line


def numeric_column(path: Path, name: str, spec: ChannelSpec, table) -> np.ndarray:
    """A numeric column as float64 (null -> NaN); anything else is one line naming the channel."""
    import pyarrow as pa

    col = table.column(spec.column)
    if not (pa.types.is_floating(col.type) or pa.types.is_integer(col.type) or pa.types.is_null(col.type)):
        if pa.types.is_string(col.type) or pa.types.is_large_string(col.type):
            for row, cell in enumerate(col.to_pylist(), start=1):
                if cell is not None and not is_number(cell, ","):
                    raise InputFileError(f"{path}: {name} ({spec.column}): data row {row}: {cell!r} is not a number")
        raise InputFileError(f"{path}: {name} ({spec.column}): not numbers (column type {col.type})")
    return col.to_numpy(zero_copy_only=False).astype(np.float64)


def _read_arrow(path: Path, cmap: ChannelMap) -> dict[str, Series]:
    table, _ = arrow_table(path, cmap)
    t_col = table.column(cmap.time.column)
    t_valid = ~np.asarray(t_col.is_null())
    t_ns = _time_ns(path, cmap.time, t_col)
    back = np.flatnonzero(np.diff(t_ns[t_valid]) < 0)
    if back.size:
        raise InputFileError(f"{path}: time ({cmap.time.column}) runs backwards after data row {int(back[0]) + 1} "
                             "(time must not decrease)")
    out = {}
    for name, spec in cmap.channels.items():
        values = numeric_column(path, name, spec, table)
        present = t_valid & ~np.asarray(table.column(spec.column).is_null())  # empty cell: no sample here
        out[name] = Series(t_ns[present], spec.to_si(values[present]))
    return out


def _require(path: Path, cmap: ChannelMap, available: list[str]) -> None:
    specs = [("time", cmap.time.column)] if cmap.time is not None else []
    specs += [(name, spec.column) for name, spec in cmap.channels.items()]
    specs += [("group", cmap.group)] if cmap.group is not None else []
    for name, column in specs:
        if column not in available:
            raise InputFileError(f"{path}: no column {column!r} for {name} (the file has: "
                                 f"{', '.join(available[:20])}{' …' if len(available) > 20 else ''})")


_CLOCK = re.compile(r"^\s*(\d{1,2}):(\d{2}):(\d{2}(?:[.,]\d+)?)\s*$")
_DAY_NS = 86_400 * 10**9


def _clock_ns(path: Path, spec: ChannelSpec, column) -> np.ndarray:
    """Clock times ``HH:MM:SS[.fff]`` (a decimal comma too) as ns since the first midnight: a
    recording that runs past midnight goes on into the next day (a step back of more than 12 h)."""
    cells = column.to_pylist()
    out = np.zeros(len(cells), dtype=np.int64)
    present = np.zeros(len(cells), dtype=bool)
    for row, cell in enumerate(cells):
        if cell is None:
            continue
        m = _CLOCK.match(cell)
        if m is None:
            raise InputFileError(f"{path}: time ({spec.column}): data row {row + 1}: {cell!r} is not a clock time "
                                 "HH:MM:SS[.fff] like the rows before it")
        h, mi, sec = m.groups()
        out[row] = round((int(h) * 3600 + int(mi) * 60 + float(sec.replace(",", "."))) * 1e9)
        present[row] = True
    t = out[present]
    t += _DAY_NS * np.cumsum(np.diff(t, prepend=t[:1]) < -_DAY_NS // 2)
    out[present] = t
    return out


def _time_ns(path: Path, spec: ChannelSpec, column) -> np.ndarray:
    """A time column as int64 ns (numbers in the map's unit, ISO 8601 date-times, or clock times)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    if spec.unit == "datetime":
        if pa.types.is_string(column.type) or pa.types.is_large_string(column.type):
            first = next((c for c in column.to_pylist()[:1000] if c is not None), None)
            if first is not None and _CLOCK.match(first):
                return _clock_ns(path, spec, column)
            try:
                column = pc.strptime(column, format="%Y-%m-%dT%H:%M:%S", unit="ns", error_is_null=False)
            except pa.ArrowInvalid:
                column = pc.cast(column, pa.timestamp("ns"))
        if not pa.types.is_timestamp(column.type):
            raise InputFileError(f"{path}: time ({spec.column}) is not ISO 8601 date-times (type {column.type})")
        return pc.cast(pc.cast(column, pa.timestamp("ns")), pa.int64()).to_numpy(zero_copy_only=False)
    if not (pa.types.is_floating(column.type) or pa.types.is_integer(column.type)):
        raise InputFileError(f"{path}: time ({spec.column}) is not numbers in {spec.unit} (type {column.type}); "
                             "ISO 8601 date-times need unit: datetime")
    values = column.to_numpy(zero_copy_only=False).astype(np.float64)
    t = np.round(spec.to_si(values))
    present = ~np.asarray(column.is_null())  # empty cells are rows without a sample (the caller skips them)
    bad = present & ~(np.abs(t) < 2.0**63)
    if bad.any():
        raise InputFileError(f"{path}: time ({spec.column}) is not a finite time at data row "
                             f"{int(np.flatnonzero(bad)[0]) + 1} ({float(values[bad][0])!r} {spec.unit})")
    return np.where(present, t, 0).astype(np.int64)


# ------------------------------------------------------------------------------------ MDF4
def _read_mdf4(path: Path, cmap: ChannelMap) -> dict[str, Series]:
    from asammdf import MDF

    try:
        mdf = MDF(path)
    except Exception as exc:  # noqa: BLE001 - asammdf raises many types for a file that is not MDF
        raise InputFileError(f"{path}: not an MDF file asammdf can read ({exc})") from None
    try:
        out = {}
        for name, spec in cmap.channels.items():
            group, index = _mdf_channel(path, mdf, name, spec.column)
            signal = mdf.get(group=group, index=index)
            if not unit_matches(name, signal.unit, spec.unit):
                raise InputFileError(f"{path}: {name} ({spec.column}) is in {signal.unit!r} by the file's metadata, "
                                     f"the channel map says {spec.unit}")
            t_ns = np.round(np.asarray(signal.timestamps, dtype=np.float64) * 1e9).astype(np.int64)
            out[name] = Series(t_ns, spec.to_si(_numbers(path, name, spec.column, signal.samples)))
        return out
    finally:
        mdf.close()


def _mdf_channel(path: Path, mdf, name: str, column: str) -> tuple[int, int]:
    """(data group, channel index) of ``column``: a channel name, or ``name@G`` for the one in data
    group ``G`` (its number or its acquisition name) when several groups have a channel of that name."""
    occurrences = mdf.channels_db.get(column)
    wanted = None
    if not occurrences and "@" in column:
        column, _, wanted = column.rpartition("@")
        occurrences = mdf.channels_db.get(column)
    if not occurrences:
        masters = {mdf.groups[g].channels[i].name for g, i in mdf.masters_db.items()} if mdf.masters_db else set()
        available = sorted(n for n in mdf.channels_db if n not in masters)
        raise InputFileError(f"{path}: no channel {column!r} for {name} (the file has: {', '.join(available[:20])}"
                             f"{' …' if len(available) > 20 else ''})")

    def acq_name(g: int) -> str:
        return getattr(mdf.groups[g].channel_group, "acq_name", "") or ""

    def label(g: int) -> str:
        return f"{g} {acq_name(g)!r}" if acq_name(g) else str(g)

    if wanted is not None:
        chosen = [(g, i) for g, i in occurrences if wanted in (str(g), acq_name(g))]
        if len(chosen) != 1:
            raise InputFileError(f"{path}: {name}: no single channel {column!r} in data group {wanted!r} (it is in "
                                 f"{', '.join(label(g) for g, _ in occurrences)})")
        return chosen[0]
    if len(occurrences) > 1:
        groups = [g for g, _ in occurrences]
        raise InputFileError(f"{path}: {name}: channel {column!r} is in {len(groups)} data groups "
                             f"({', '.join(label(g) for g in groups)}): name one as "
                             f"{' or '.join(repr(f'{column}@{g}') for g in groups)}")
    return occurrences[0]


def _numbers(path: Path, name: str, column: str, values) -> np.ndarray:
    """A channel's samples as float64; text or other non-numbers: one line naming the channel."""
    values = np.asarray(values)
    if values.dtype.kind not in "fiub":
        raise InputFileError(f"{path}: {name} ({column}): not numbers (samples of type {values.dtype})")
    return values.astype(np.float64)


# ------------------------------------------------------------------------------------ TDMS
def _read_tdms(path: Path, cmap: ChannelMap) -> dict[str, Series]:
    from nptdms import TdmsFile

    try:
        tdms = TdmsFile.read(path)
    except Exception as exc:  # noqa: BLE001 - nptdms raises many types for a file that is not TDMS
        raise InputFileError(f"{path}: not a TDMS file nptdms can read ({exc})") from None

    def channel(name: str, column: str):
        group, _, chan = column.partition("/")
        try:
            return tdms[group][chan]
        except KeyError:
            available = [f"{g.name}/{c.name}" for g in tdms.groups() for c in g.channels()]
            raise InputFileError(f"{path}: no channel {column!r} for {name} (TDMS channels are named group/channel; "
                                 f"the file has: {', '.join(available[:20])}{' …' if len(available) > 20 else ''})"
                                 ) from None

    base = None
    if cmap.time is not None and "/" in cmap.time.column:
        base = np.round(cmap.time.to_si(channel("time", cmap.time.column)[:])).astype(np.int64)
    out = {}
    for name, spec in cmap.channels.items():
        ch = channel(name, spec.column)
        unit = ch.properties.get("unit_string")
        if not unit_matches(name, unit, spec.unit):
            raise InputFileError(f"{path}: {name} ({spec.column}) is in {unit!r} by the file's metadata, "
                                 f"the channel map says {spec.unit}")
        values = _numbers(path, name, spec.column, ch[:])
        if base is not None and len(base) == len(values):
            t_ns = base
        elif "wf_increment" in ch.properties:
            t_ns = np.round(np.asarray(ch.time_track(), dtype=np.float64) * 1e9).astype(np.int64)
        else:
            raise InputFileError(f"{path}: {name} ({spec.column}) has no time: no wf_increment property and no "
                                 "time channel (time: {column: group/channel}) of its length")
        out[name] = Series(t_ns, spec.to_si(values))
    return out


# ------------------------------------------------------------------------------------ alignment
def align(series: dict[str, Series]) -> Aligned:
    """The paired channels on the motor torque's time base (see the module docstring)."""
    base = series[Channel.MOTOR_TORQUE]
    values = {Channel.MOTOR_TORQUE: base.values}
    resampled = []
    for name in Channel.PAIRED[1:]:
        s = series.get(name)
        if s is None:
            continue
        if len(s.t_ns) == len(base.t_ns) and np.array_equal(s.t_ns, base.t_ns):
            values[name] = s.values
            continue
        resampled.append(name)
        values[name] = _interpolate(s, base.t_ns)
    temperature = series.get(Channel.OIL_TEMPERATURE)
    if temperature is not None and len(temperature.t_ns) > 1:
        keep = _decimate(temperature.t_ns, TEMPERATURE_MAX_RATE_HZ)
        temperature = Series(temperature.t_ns[keep], temperature.values[keep])
    return Aligned(base.t_ns, values, temperature, resampled)


def _interpolate(s: Series, t_ns: np.ndarray) -> np.ndarray:
    """Linear between neighbouring samples; NaN outside the channel's span (no extrapolation)."""
    if len(s.t_ns) == 0:
        return np.full(len(t_ns), np.nan)
    t0 = s.t_ns[0]
    x = (s.t_ns - t0).astype(np.float64)
    xi = (t_ns - t0).astype(np.float64)
    out = np.interp(xi, x, s.values)
    out[(t_ns < s.t_ns[0]) | (t_ns > s.t_ns[-1])] = np.nan
    return out


def _decimate(t_ns: np.ndarray, max_rate_hz: float) -> np.ndarray:
    """Indices of samples at least ``1/max_rate_hz`` apart (the first of each interval)."""
    period = int(1e9 / max_rate_hz)
    slot = (t_ns - t_ns[0]) // period
    return np.flatnonzero(np.r_[True, slot[1:] != slot[:-1]])
