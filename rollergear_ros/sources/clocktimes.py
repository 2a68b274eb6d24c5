"""A time column as int64 ns since 1970: numbers in a unit, ISO 8601 date-times, or clock times.

Date-times written without a zone are in the channel map's ``timezone`` (else UTC, and said);
clock times ``HH:MM:SS[.fff]`` count from the midnight of the map's ``date`` (or a date read from
the CSV's preamble) and run on past midnight into the next day.  A time that is not one is one
:class:`~base.errors.InputFileError` line naming the file, the column and the row.  No rclpy import.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..base.errors import InputFileError
from .channelmap import ChannelMap, ChannelSpec

__all__ = ["TimeBase", "time_base", "time_column_ns"]


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


def time_column_ns(path: Path, spec: ChannelSpec, column, base: TimeBase = TimeBase(), after_ns: int | None = None,
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
