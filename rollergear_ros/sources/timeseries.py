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
:class:`~base.errors.InputFileError` line naming the file and the channel.  No rclpy import.
"""

from __future__ import annotations

import math

import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .channelmap import ChannelMap, ChannelSpec, unit_matches
from .csvdialect import is_number, sniff
from ..base.errors import InputFileError
from .formats import INPUT_FORMATS, format_by_suffix, is_format, suffixes
from ..base.interface import Channel

__all__ = ["Aligned", "Series", "align", "arrow_table", "numeric_column", "read_series"]

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


def read_series(path: str | Path, cmap: ChannelMap, notes: list[str] | None = None) -> dict[str, Series]:
    """Every channel of the map from ``path``, in SI, each on its own time base; ``notes`` is told
    what was done to the time (a relative time base that started below 0, shifted)."""
    path = Path(path)
    if not path.exists():
        raise InputFileError(f"{path} does not exist")
    if not path.is_file():  # a folder, a FIFO or a device
        raise InputFileError(f"{path} is not a regular file")
    fmt = format_by_suffix(path)
    if fmt is None or fmt.family != "timeseries":
        raise InputFileError(f"{path}: unknown time-series format {path.suffix!r} "
                             f"(one of {', '.join(sorted(suffixes('timeseries')))})")
    if cmap.format != "timeseries":
        raise InputFileError(f"{path}: the channel map {cmap.path} is for format: {cmap.format}, not timeseries")
    if not fmt.own_time and cmap.time is None:
        own = " and ".join(f.name for f in INPUT_FORMATS.values() if f.own_time)
        raise InputFileError(f"{path}: a {fmt.name} file needs time: {{column: …, unit: s|ms|us|ns|datetime}} in the "
                             f"channel map {cmap.path} (only {own} carry their own time)")
    series = fmt.read_series()(path, cmap, notes)
    for name, s in series.items():
        back = np.flatnonzero(np.diff(s.t_ns) < 0)
        if back.size:
            raise InputFileError(f"{path}: {name} ({cmap.channels[name].column}): time runs backwards after "
                                 f"sample {int(back[0])} (time must not decrease)")
    series = _from_zero_when_negative(path, cmap, series, notes)
    lagging = {name: cmap.channels[name].lag_s for name in series if cmap.channels[name].lag_s}
    for name, lag in lagging.items():  # a channel that reads a moment later: its times moved back
        series[name] = Series(series[name].t_ns - int(round(lag * 1e9)), series[name].values)
    if lagging and notes is not None:
        notes.append("aligned: " + ", ".join(f"{n} {1e3 * v:g} ms earlier (the channel map's lag_s)"
                                             for n, v in lagging.items()))
    return series


def _from_zero_when_negative(path: Path, cmap: ChannelMap, series: dict[str, Series],
                             notes: list[str] | None = None) -> dict[str, Series]:
    """Recordings start at or after 1970 (MCAP log times are unsigned): relative times that start
    below 0 (a DAQ's pre-trigger) are shifted so that the first sample is at 0; a date-time
    before 1970 is an error."""
    first = min((int(s.t_ns[0]) for s in series.values() if len(s.t_ns)), default=0)
    if first >= 0:
        return series
    if cmap.time is not None and cmap.time.unit == "datetime":
        raise InputFileError(f"{path}: time ({cmap.time.column}) lies before 1970-01-01: not a recording's date")
    if notes is not None:
        notes.append(f"time started at {first * 1e-9:g} s: shifted by {-first * 1e-9:g} s to start at 0")
    return {name: Series(s.t_ns - first, s.values) for name, s in series.items()}


def seconds_to_ns(path: Path, what: str, seconds) -> np.ndarray:
    """Times in seconds as int64 ns; a time that is not finite (or beyond 292 years) is one line."""
    seconds = np.asarray(seconds, dtype=np.float64)
    bad = ~(np.abs(seconds) < 9.2e9)
    if bad.any():
        raise InputFileError(f"{path}: {what}: time {float(seconds[bad][0])!r} s at sample "
                             f"{int(np.flatnonzero(bad)[0])} is not a finite time")
    return np.round(seconds * 1e9).astype(np.int64)


# ------------------------------------------------------------------------------------ CSV / Parquet
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
            raise InputFileError(f"{path}: not a Parquet file ({_first_line(exc)})") from None
        _require(path, cmap, available)
        try:
            table = pq.read_table(path, columns=wanted)
        except (pa.ArrowException, OSError) as exc:  # a damaged page or footer
            raise InputFileError(f"{path}: a damaged Parquet file ({_first_line(exc)})") from None
        first_line = 2
    if table.num_rows == 0:
        raise InputFileError(f"{path}: no data rows (only the column names)")
    return table, first_line


def _first_line(exc: BaseException) -> str:
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
    t_ns = _time_ns(path, cmap.time, t_col, base, notes=notes)
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
    _require(path, cmap, list(dialect.header))
    return dialect, pacsv.ConvertOptions(include_columns=sorted(set(cmap.columns())),
                                         decimal_point=dialect.decimal_point)


def _require(path: Path, cmap: ChannelMap, available: list[str]) -> None:
    specs = [("time", cmap.time.column)] if cmap.time is not None else []
    specs += [(name, spec.column) for name, spec in cmap.channels.items() if spec.constant is None]
    specs += [("group", cmap.group)] if cmap.group is not None else []
    for name, column in specs:
        if column not in available:
            raise InputFileError(f"{path}: no column {column!r} for {name} (the file has: "
                                 f"{', '.join(available[:20])}{' …' if len(available) > 20 else ''})")


_CLOCK = re.compile(r"^\s*(\d{1,2}):(\d{2}):(\d{2}(?:[.,]\d+)?)\s*$")
_DAY_NS = 86_400 * 10**9


def _times_of_day(path: Path, spec: ChannelSpec, column) -> tuple[np.ndarray, np.ndarray] | None:
    """Clock times ``HH:MM:SS[.fff]`` (a decimal comma too, or pyarrow's time-of-day type) as ns
    since midnight, with the rows that have one; None when the column holds date-times instead."""
    import pyarrow as pa
    import pyarrow.compute as pc

    present = ~np.asarray(column.is_null())
    if pa.types.is_time(column.type):  # pyarrow's CSV reader makes HH:MM:SS a time of day
        raw = pc.cast(pc.cast(column, pa.time64("ns")), pa.int64()).to_numpy(zero_copy_only=False)
        return np.where(present, raw, 0).astype(np.int64), present
    if not (pa.types.is_string(column.type) or pa.types.is_large_string(column.type)):
        return None
    cells = column.to_pylist()
    first = next((c for c in cells[:1000] if c is not None), None)
    if first is None or not _CLOCK.match(first):
        return None
    out = np.zeros(len(cells), dtype=np.int64)
    for row, cell in enumerate(cells):
        if cell is None:
            continue
        m = _CLOCK.match(cell)
        if m is None:
            raise InputFileError(f"{path}: time ({spec.column}): data row {row + 1}: {cell!r} is not a clock time "
                                 "HH:MM:SS[.fff] like the rows before it")
        h, mi, sec = m.groups()
        seconds = float(sec.replace(",", "."))
        if int(h) > 23 or int(mi) > 59 or not seconds < 61:  # 60.x: a leap second
            raise InputFileError(f"{path}: time ({spec.column}): data row {row + 1}: {cell!r} is not a clock time "
                                 "(hours 0-23, minutes 0-59, seconds below 61)")
        out[row] = round((int(h) * 3600 + int(mi) * 60 + seconds) * 1e9)
    return out, present


def _unwrap_days(out: np.ndarray, present: np.ndarray, after_ns: int | None) -> np.ndarray:
    """Times of day (ns since midnight) as ns since the first midnight: a recording that runs past
    midnight goes on into the next day (a step back of more than 12 h); ``after_ns``: the last time
    before these rows (a file read in batches), in the same count."""
    t = out[present]
    if len(t):
        days = 0 if after_ns is None else max(0, -(-(after_ns - _DAY_NS // 2 - int(t[0])) // _DAY_NS))
        t += _DAY_NS * (days + np.cumsum(np.diff(t, prepend=t[:1]) < -_DAY_NS // 2))
    out[present] = t
    return out


@dataclass(frozen=True)
class TimeBase:
    """What a file's date-times and clock times mean: the zone of those written without one, and
    the midnight (UTC ns) clock times count from."""

    zone: str = "UTC"
    clock_origin_ns: int = 0
    zone_given: bool = False
    date_given: bool = False


def time_base(path: Path, cmap: ChannelMap, dialect=None) -> TimeBase:
    """The map's ``timezone`` and ``date`` for ``path`` (``date: {preamble: LABEL}`` read from the
    CSV's preamble; ``dialect``: the file's :func:`~.csvdialect.sniff`)."""
    import datetime

    from .channelmap import zone_info
    from .csvdialect import preamble_value

    zone = cmap.timezone or "UTC"
    day = cmap.date
    if cmap.date_label is not None:
        text = preamble_value(path, dialect, cmap.date_label) if dialect is not None else None
        if text is None:
            raise InputFileError(f"{path}: no preamble line {cmap.date_label!r} with the date (the map's date: "
                                 "{preamble: …})")
        formats = [cmap.date_format] if cmap.date_format else ["%Y-%m-%d", "%d.%m.%Y"]
        for fmt in formats:
            try:
                day = datetime.datetime.strptime(text, fmt).date().isoformat()
                break
            except ValueError:
                continue
        else:
            raise InputFileError(f"{path}: the preamble's {cmap.date_label} {text!r} is not a date "
                                 f"({' or '.join(formats)}; give date: {{preamble: …, format: …}})")
    origin = 0
    if day is not None:
        midnight = datetime.datetime.combine(datetime.date.fromisoformat(day), datetime.time(), zone_info(zone))
        origin = int(round(midnight.timestamp())) * 10**9
        if not -(2**63) < origin < 2**63 - 2 * _DAY_NS:
            raise InputFileError(f"{path}: the date of its clock times, {day}, is outside the years 1678-2261 that "
                                 "ROS times (int64 ns since 1970) hold")
    return TimeBase(zone, origin, cmap.timezone is not None, day is not None)


def _time_ns(path: Path, spec: ChannelSpec, column, base: TimeBase = TimeBase(), after_ns: int | None = None,
             notes: list[str] | None = None) -> np.ndarray:
    """A time column as int64 ns (numbers in the map's unit, ISO 8601 date-times, or clock times).
    Date-times without a zone are in ``base.zone``, clock times on its day; ``notes`` is told what
    was assumed (UTC, 1970-01-01) where the map did not say; ``after_ns``: see :func:`_unwrap_days`."""
    import pyarrow as pa

    def note(text: str) -> None:
        if notes is not None and text not in notes:
            notes.append(text)

    if spec.unit == "datetime":
        day_ns = _times_of_day(path, spec, column)
        if day_ns is not None:
            if not base.date_given:
                note("clock times without a date: counted from 1970-01-01 (date: in the channel map gives their day)")
            elif not base.zone_given:
                note(f"clock times on {_day_of(base.clock_origin_ns)} taken as UTC (no timezone in the channel map)")
            values, present = day_ns
            after = None if after_ns is None else after_ns - base.clock_origin_ns
            return base.clock_origin_ns + _unwrap_days(values, present, after)
        try:
            return _date_times_ns(column, base, note)
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError, OverflowError, ValueError) as exc:
            reason = " ".join(str(exc).split())[:160]
            raise InputFileError(f"{path}: time ({spec.column}) is not ISO 8601 date-times of one kind (all with a "
                                 f"zone or all without; offsets within ±24 h) in the years 1678-2261 that ROS times "
                                 f"hold ({reason})") from None
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


def _date_times_ns(column, base: TimeBase, note: Callable[[str], None]) -> np.ndarray:
    """ISO 8601 date-time strings (or pyarrow timestamps) as int64 ns since 1970 UTC; those without
    a zone in ``base.zone``.  pyarrow's errors (a malformed or out-of-range time, mixed zones) pass."""
    import pyarrow as pa
    import pyarrow.compute as pc

    if pa.types.is_string(column.type) or pa.types.is_large_string(column.type):
        try:
            column = pc.strptime(column, format="%Y-%m-%dT%H:%M:%S", unit="ns", error_is_null=False)
        except pa.ArrowInvalid:
            try:
                column = pc.cast(column, pa.timestamp("ns"))
            except pa.ArrowInvalid:  # with a zone offset (+01:00, Z): the instant it names
                column = pc.cast(column, pa.timestamp("ns", "UTC"))
    if not pa.types.is_timestamp(column.type):
        raise ValueError(f"type {column.type}")
    if column.type.tz is None:  # written without a zone: the map's, else UTC (and said)
        if not base.zone_given:
            note("date-times without a zone taken as UTC (timezone: in the channel map says otherwise)")
        column = pc.assume_timezone(pc.cast(column, pa.timestamp("ns")), base.zone, ambiguous="earliest",
                                    nonexistent="earliest")
    return pc.cast(pc.cast(column, pa.timestamp("ns", "UTC")), pa.int64()).to_numpy(zero_copy_only=False)


def _day_of(ns: int) -> str:
    import datetime

    return datetime.datetime.fromtimestamp(ns / 1e9, datetime.UTC).date().isoformat()


# ------------------------------------------------------------------------------------ MDF4
def read_mdf4_series(path: Path, cmap: ChannelMap, notes: list[str] | None = None) -> dict[str, Series]:
    mdf = open_mdf(path)
    try:
        # the file's own time: each channel's master (time) channel from the measurement's start
        start = mdf.header.start_time
        start_ns = int(round(start.timestamp() * 1e9)) if start is not None and start.year >= 1970 else 0
        clock = None
        if cmap.time is not None:  # a time channel named in the map replaces the masters
            if cmap.time.unit == "datetime":
                raise InputFileError(f"{path}: time ({cmap.time.column}): an MDF4 time channel holds numbers "
                                     "(s|ms|us|ns), not date-times")
            group, index = _mdf_channel(path, mdf, "time", cmap.time.column)
            clock = np.round(cmap.time.to_si(_numbers(path, "time", cmap.time.column,
                                                      mdf.get(group=group, index=index).samples)))
        out = {}
        for name, spec in cmap.channels.items():
            if spec.constant is not None:
                continue
            group, index = _mdf_channel(path, mdf, name, spec.column)
            signal = mdf.get(group=group, index=index)
            if not unit_matches(name, signal.unit, spec.unit):
                raise InputFileError(f"{path}: {name} ({spec.column}) is in {signal.unit!r} by the file's metadata, "
                                     f"the channel map says {spec.unit}")
            values = spec.to_si(_numbers(path, name, spec.column, signal.samples))
            if clock is None:
                t_ns = start_ns + seconds_to_ns(path, f"{name} ({spec.column})", signal.timestamps)
            elif len(clock) == len(values):
                t_ns = start_ns + clock.astype(np.int64)
            else:
                raise InputFileError(f"{path}: {name} ({spec.column}) has {len(values)} samples, the time channel "
                                     f"{cmap.time.column!r} {len(clock)}: a time channel serves the channels of its "
                                     "data group (leave time out of the map to use each channel's own)")
            out[name] = Series(t_ns, values)
        return _with_constants(out, cmap)
    finally:
        mdf.close()


def _with_constants(out: dict[str, Series], cmap: ChannelMap) -> dict[str, Series]:
    """The map's constant channels at the motor torque's times."""
    base = out[Channel.MOTOR_TORQUE].t_ns
    for name, spec in cmap.channels.items():
        if spec.constant is not None:
            out[name] = Series(base, spec.to_si(np.full(len(base), spec.constant)))
    return out


def open_mdf(path: Path):
    """The ``asammdf`` MDF of ``path``; a file it cannot read is one line (the half-made object's
    ``__del__`` fails too, and would print an "Exception ignored" traceback after the error)."""
    import gc
    import sys

    from asammdf import MDF

    previous = sys.unraisablehook

    def quiet(unraisable) -> None:
        if "asammdf" not in getattr(getattr(unraisable.object, "__code__", None), "co_filename", ""):
            previous(unraisable)

    sys.unraisablehook = quiet
    try:
        try:
            return MDF(path)
        except Exception as exc:  # noqa: BLE001 - asammdf raises many types for a file that is not MDF
            reason = " ".join(str(exc).split())
        gc.collect()  # the half-made MDF goes now, while its __del__'s error is quiet
        raise InputFileError(f"{path}: not an MDF file asammdf can read ({reason})")
    finally:
        sys.unraisablehook = previous


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
def read_tdms_series(path: Path, cmap: ChannelMap, notes: list[str] | None = None) -> dict[str, Series]:
    """The map's channels of a TDMS file; what nptdms warns of while reading a damaged file (a
    segment cut short, an unknown version) goes to ``notes`` as one line, not to the log."""
    tdms = _read_tdms(path, notes)

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
    if cmap.time is not None:  # a time channel named in the map replaces the waveforms' own time
        if "/" not in cmap.time.column or cmap.time.unit == "datetime":
            raise InputFileError(f"{path}: time ({cmap.time.column}): a TDMS time channel is named group/channel "
                                 "and holds numbers (s|ms|us|ns); leave time out to use the waveforms' own")
        base = np.round(cmap.time.to_si(_numbers(path, "time", cmap.time.column,
                                                 channel("time", cmap.time.column)[:]))).astype(np.int64)
    out = {}
    for name, spec in cmap.channels.items():
        if spec.constant is not None:
            continue
        ch = channel(name, spec.column)
        unit = ch.properties.get("unit_string")
        if not unit_matches(name, unit, spec.unit):
            raise InputFileError(f"{path}: {name} ({spec.column}) is in {unit!r} by the file's metadata, "
                                 f"the channel map says {spec.unit}")
        values = _numbers(path, name, spec.column, ch[:])
        if base is not None:
            if len(base) != len(values):
                raise InputFileError(f"{path}: {name} ({spec.column}) has {len(values)} samples, the time channel "
                                     f"{cmap.time.column!r} {len(base)}")
            t_ns = base
        else:
            t_ns = _waveform_ns(path, f"{name} ({spec.column})", ch.properties, len(values))
        out[name] = Series(t_ns, spec.to_si(values))
    return _with_constants(out, cmap)


def _read_tdms(path: Path, notes: list[str] | None):
    """The whole TDMS file (nptdms), its warnings collected into one line of ``notes``."""
    import logging

    from nptdms import TdmsFile

    warned: list[str] = []

    class Collect(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            warned.append(" ".join(record.getMessage().split())[:120])

    from nptdms.log import log_manager  # nptdms prints through a console handler of its own

    handler, console = Collect(logging.WARNING), log_manager.console_handler
    loggers, level = list(log_manager.loggers.values()), console.level
    console.setLevel(logging.CRITICAL + 1)
    for logger in loggers:
        logger.addHandler(handler)
    try:
        tdms = TdmsFile.read(path)
    except Exception as exc:  # noqa: BLE001 - nptdms raises many types for a file that is not TDMS
        raise InputFileError(f"{path}: not a TDMS file nptdms can read ({exc})") from None
    finally:
        console.setLevel(level)
        for logger in loggers:
            logger.removeHandler(handler)
    if warned and notes is not None:
        notes.append(f"damaged TDMS, read as far as nptdms could ({len(warned)} warnings; first: {warned[0]})")
    return tdms


def _waveform_ns(path: Path, what: str, properties, n: int) -> np.ndarray:
    """A TDMS waveform's time (NI's properties): ``wf_start_time`` (absolute, when given) +
    ``wf_start_offset`` (0 when missing, as NI's readers take it) + i · ``wf_increment``."""
    inc = properties.get("wf_increment")
    if inc is None:
        raise InputFileError(f"{path}: {what} has no time: no wf_increment property (give a time channel as "
                             "time: {column: group/channel, unit: s})")
    try:
        inc, offset = float(inc), float(properties.get("wf_start_offset", 0.0))
    except (TypeError, ValueError):
        raise InputFileError(f"{path}: {what}: wf_increment / wf_start_offset are not numbers") from None
    if not (math.isfinite(inc) and inc > 0 and math.isfinite(offset)):
        raise InputFileError(f"{path}: {what}: wf_increment = {inc!r} s, wf_start_offset = {offset!r} s: a waveform "
                             "needs a finite increment > 0 and a finite start")
    start = properties.get("wf_start_time")
    start_ns = 0
    if start is not None:
        try:
            start_ns = int(np.datetime64(start, "ns").astype(np.int64))
        except (TypeError, ValueError):
            start_ns = 0
        start_ns = max(start_ns, 0)  # NI's zero time (1904) means "not set"
    return start_ns + seconds_to_ns(path, what, offset + inc * np.arange(n, dtype=np.float64))


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
