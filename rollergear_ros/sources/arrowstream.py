"""CSV and Parquet time series read in bounded batches and aligned as they come (no rclpy).

A Parquet file of a few hundred kilobytes can hold 30 million rows; read whole, its columns, their
SI copies and their messages take several gigabytes.  :func:`aligned_batches` reads
``batch_rows`` rows at a time (Parquet row batches, pyarrow's streaming CSV reader with the sniffed
dialect) and yields each part on the motor torque's time base by exactly the rule of
:func:`~.timeseries.align`: a channel with an empty cell is interpolated between its neighbouring
samples -- across a batch boundary too: the rows after the batch's last row with every channel are
held back for the next batch, and each channel's last sample is kept as the anchor of the next
interpolation; the oil temperature is thinned to one a second over the whole file.  The values are
those of reading the file whole (tested byte for byte).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .channelmap import ChannelMap
from ..base.errors import InputFileError
from .formats import is_format
from ..base.interface import Channel
from .timeseries import (TEMPERATURE_MAX_RATE_HZ, Aligned, Series, _first_line, _require, _time_ns, csv_reading,
                         has_value, numeric_column)

__all__ = ["BATCH_ROWS", "aligned_batches"]

BATCH_ROWS = 1_000_000  #: rows read at a time: ~50 MB of columns and messages in flight
MAX_HELD_ROWS = 4 * BATCH_ROWS  #: rows held for a channel's next sample, at most (a channel gone for good)


def _batches(path: Path, cmap: ChannelMap, batch_rows: int) -> Iterator:
    """The file's rows as pyarrow tables of about ``batch_rows`` rows (the map's columns only)."""
    import pyarrow as pa

    wanted = sorted(set(cmap.columns()))
    if is_format(path, "CSV"):
        import pyarrow.csv as pacsv

        dialect, convert = csv_reading(path, cmap)
        read = dialect.read_options()
        read.block_size = max(1 << 16, batch_rows * 16 * max(len(dialect.header), 1))
        try:
            reader = pacsv.open_csv(path, read_options=read, parse_options=dialect.parse_options(),
                                    convert_options=convert)
            for batch in reader:
                yield pa.Table.from_batches([batch])
        except pa.ArrowInvalid as exc:
            raise InputFileError(f"{path}: {exc}") from None
    else:
        import pyarrow.parquet as pq

        try:
            pf = pq.ParquetFile(path)
        except (pa.ArrowException, OSError) as exc:
            raise InputFileError(f"{path}: not a Parquet file ({_first_line(exc)})") from None
        _require(path, cmap, pf.schema_arrow.names)
        try:
            for batch in pf.iter_batches(batch_size=batch_rows, columns=wanted):
                yield pa.Table.from_batches([batch])
        except (pa.ArrowException, OSError) as exc:  # a damaged page or footer
            raise InputFileError(f"{path}: a damaged Parquet file ({_first_line(exc)})") from None


@dataclass
class _Held:
    """Rows read but not yet aligned: a channel's next sample is still to come."""

    t_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    t_valid: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    values: dict[str, np.ndarray] = field(default_factory=dict)
    present: dict[str, np.ndarray] = field(default_factory=dict)


def aligned_batches(path: str | Path, cmap: ChannelMap, batch_rows: int = BATCH_ROWS,
                    notes: list[str] | None = None) -> Iterator[Aligned]:
    """The file's channels on the motor torque's time base, part by part (see the module docstring).
    ``notes`` is told what was done to the time (a relative time that started below 0, shifted)."""
    path = Path(path)
    if cmap.time is None:
        raise InputFileError(f"{path}: a {path.suffix.lstrip('.').upper()} file needs time: {{column: …, unit: "
                             f"s|ms|us|ns|datetime}} in the channel map {cmap.path} (only MDF4 and TDMS carry their "
                             "own time)")
    names = list(cmap.channels)
    paired = [c for c in Channel.PAIRED if c in cmap.channels]
    held = _Held(values={n: np.zeros(0) for n in names}, present={n: np.zeros(0, bool) for n in names})
    anchor: dict[str, tuple[int, float]] = {}  # channel -> its last sample aligned so far
    origin: dict[str, int] = {}  # channel -> its first sample's time (the interpolation's origin)
    resampled: set[str] = set()
    last_t: int | None = None
    shift: int | None = None
    temp_first: int | None = None
    temp_slot: int | None = None
    rows_read = 0
    period = int(1e9 / TEMPERATURE_MAX_RATE_HZ)
    from .csvdialect import sniff
    from .timeseries import time_base

    clock = time_base(path, cmap, sniff(path, cmap) if is_format(path, "CSV") else None)
    batches = _batches(path, cmap, batch_rows)
    final = False
    while not final:
        table = next(batches, None)
        final = table is None
        if table is not None:
            t_col = table.column(cmap.time.column)
            t_valid = ~np.asarray(t_col.is_null())
            t_ns = _time_ns(path, cmap.time, t_col, clock, last_t, notes)
            values, present = {}, {}
            for name, spec in cmap.channels.items():
                try:
                    raw = numeric_column(path, name, spec, table)
                except InputFileError as exc:  # its data row counts from this batch: from the file's start
                    raise InputFileError(_renumber(str(exc), rows_read)) from None
                values[name] = spec.to_si(raw)
                present[name] = t_valid & has_value(table, spec)
            valid_t = t_ns[t_valid]
            back = np.flatnonzero(np.diff(valid_t) < 0)
            if back.size or (last_t is not None and len(valid_t) and valid_t[0] < last_t):
                row = rows_read + (int(np.flatnonzero(t_valid)[back[0]]) + 1 if back.size else 0)
                raise InputFileError(f"{path}: time ({cmap.time.column}) runs backwards after data row {row} "
                                     "(time must not decrease)")
            if len(valid_t):
                last_t = int(valid_t[-1])
            rows_read += table.num_rows
            if shift is None:
                any_present = np.logical_or.reduce([present[n] for n in names])
                if any_present.any():
                    first = int(t_ns[np.flatnonzero(any_present)[0]])
                    shift = 0 if first >= 0 else -first
                    if shift:
                        if cmap.time.unit == "datetime":
                            raise InputFileError(f"{path}: time ({cmap.time.column}) lies before 1970-01-01: not "
                                                 "a recording's date")
                        if notes is not None:
                            notes.append(f"time started at {first * 1e-9:g} s: shifted by {shift * 1e-9:g} s "
                                         "to start at 0")
            t_ns = t_ns + (shift or 0)
            held = _Held(np.concatenate([held.t_ns, t_ns]), np.concatenate([held.t_valid, t_valid]),
                         {n: np.concatenate([held.values[n], values[n]]) for n in names},
                         {n: np.concatenate([held.present[n], present[n]]) for n in names})
        elif rows_read == 0:
            raise InputFileError(f"{path}: no data rows (only the column names)")
        # the rows up to the last one with every paired channel can be aligned now
        if final or not paired:
            cut = len(held.t_ns)
        else:
            complete = np.logical_and.reduce([held.present[n] for n in paired])
            idx = np.flatnonzero(complete)
            cut = int(idx[-1]) + 1 if len(idx) else 0
            if len(held.t_ns) - cut > max(MAX_HELD_ROWS, 4 * batch_rows):  # a channel gone for good: stop waiting
                cut = len(held.t_ns)
        if cut == 0:
            continue
        part = _Held(held.t_ns[:cut], held.t_valid[:cut], {n: v[:cut] for n, v in held.values.items()},
                     {n: p[:cut] for n, p in held.present.items()})
        held = _Held(held.t_ns[cut:], held.t_valid[cut:], {n: v[cut:] for n, v in held.values.items()},
                     {n: p[cut:] for n, p in held.present.items()})
        base = part.present[Channel.MOTOR_TORQUE]
        base_t = part.t_ns[base]
        out = {Channel.MOTOR_TORQUE: part.values[Channel.MOTOR_TORQUE][base]}
        for name in paired[1:]:
            has = part.present[name]
            s_t, s_v = part.t_ns[has], part.values[name][has]
            if name not in origin and len(s_t):
                origin[name] = int(s_t[0])
            if not np.array_equal(has, base):
                resampled.add(name)
            if name in resampled:
                out[name] = _interpolate(s_t, s_v, base_t, anchor.get(name), origin.get(name))
            else:
                out[name] = s_v
            if len(s_t):
                anchor[name] = (int(s_t[-1]), float(s_v[-1]))
        temperature = None
        if Channel.OIL_TEMPERATURE in cmap.channels:
            has = part.present[Channel.OIL_TEMPERATURE]
            tt, tv = part.t_ns[has], part.values[Channel.OIL_TEMPERATURE][has]
            if len(tt):
                if temp_first is None:
                    temp_first = int(tt[0])
                slot = (tt - temp_first) // period
                keep = np.r_[temp_slot is None or slot[0] != temp_slot, slot[1:] != slot[:-1]]
                temp_slot = int(slot[-1])
                temperature = Series(tt[keep], tv[keep])
        yield Aligned(base_t, out, temperature, [c for c in paired if c in resampled])


def _interpolate(s_t: np.ndarray, s_v: np.ndarray, t_ns: np.ndarray, anchor: tuple[int, float] | None,
                 origin: int | None) -> np.ndarray:
    """:func:`~.timeseries._interpolate` of a channel's samples with the one before this part
    (``anchor``), relative to the channel's first sample in the file (``origin``: the same numbers
    as reading the file whole)."""
    if anchor is not None:
        s_t = np.concatenate([[anchor[0]], s_t])
        s_v = np.concatenate([[anchor[1]], s_v])
    if len(s_t) == 0:
        return np.full(len(t_ns), np.nan)
    out = np.interp((t_ns - origin).astype(np.float64), (s_t - origin).astype(np.float64), s_v)
    out[(t_ns < origin) | (t_ns > s_t[-1])] = np.nan
    return out


def _renumber(message: str, offset: int) -> str:
    """A message's ``data row N`` counted from the file's first data row instead of the batch's."""
    import re

    return re.sub(r"data row (\d+)", lambda m: f"data row {int(m.group(1)) + offset}", message, count=1)
