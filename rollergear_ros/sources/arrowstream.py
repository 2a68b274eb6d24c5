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
from .arrowfiles import csv_reading, first_line, has_value, numeric_column, require_columns
from .clocktimes import time_column_ns
from .timeseries import TEMPERATURE_MAX_RATE_HZ, Aligned, Series

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
            raise InputFileError(f"{path}: not a Parquet file ({first_line(exc)})") from None
        require_columns(path, cmap, pf.schema_arrow.names)
        try:
            for batch in pf.iter_batches(batch_size=batch_rows, columns=wanted):
                yield pa.Table.from_batches([batch])
        except (pa.ArrowException, OSError) as exc:  # a damaged page or footer
            raise InputFileError(f"{path}: a damaged Parquet file ({first_line(exc)})") from None


@dataclass
class _Held:
    """Rows read but not yet aligned: a channel's next sample is still to come."""

    t_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    t_valid: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    values: dict[str, np.ndarray] = field(default_factory=dict)
    present: dict[str, np.ndarray] = field(default_factory=dict)

    def then(self, later: _Held) -> _Held:
        """These rows followed by ``later``'s."""
        return _Held(np.concatenate([self.t_ns, later.t_ns]), np.concatenate([self.t_valid, later.t_valid]),
                     {n: np.concatenate([v, later.values[n]]) for n, v in self.values.items()},
                     {n: np.concatenate([v, later.present[n]]) for n, v in self.present.items()})

    def rows(self, part: slice) -> _Held:
        """The rows of ``part``."""
        return _Held(self.t_ns[part], self.t_valid[part], {n: v[part] for n, v in self.values.items()},
                     {n: v[part] for n, v in self.present.items()})


def aligned_batches(path: str | Path, cmap: ChannelMap, batch_rows: int = BATCH_ROWS,
                    notes: list[str] | None = None) -> Iterator[Aligned]:
    """The file's channels on the motor torque's time base, part by part (see the module docstring).
    ``notes`` is told what was done to the time (a relative time that started below 0, shifted)."""
    path = Path(path)
    if cmap.time is None:
        raise InputFileError(f"{path}: a {path.suffix.lstrip('.').upper()} file needs time: {{column: …, unit: "
                             f"s|ms|us|ns|datetime}} in the channel map {cmap.path} (only MDF4 and TDMS carry their "
                             "own time)")
    aligner = _Aligner(path, cmap, batch_rows, notes)
    batches = _batches(path, cmap, batch_rows)
    final = False
    while not final:
        table = next(batches, None)
        final = table is None
        if table is not None:
            aligner.read(table)
        elif aligner.rows_read == 0:
            raise InputFileError(f"{path}: no data rows (only the column names)")
        part = aligner.take(final)
        if part is not None:
            yield aligner.align(part)


class _Aligner:
    """The state :func:`aligned_batches` carries from one batch to the next: the rows held back,
    each channel's anchor and origin, the time's shift and the temperature's thinning."""

    def __init__(self, path: Path, cmap: ChannelMap, batch_rows: int, notes: list[str] | None) -> None:
        from .csvdialect import sniff
        from .clocktimes import time_base

        self.path, self.cmap, self.batch_rows, self.notes = path, cmap, batch_rows, notes
        self.names = list(cmap.channels)
        self.paired = [c for c in Channel.PAIRED if c in cmap.channels]
        self.held = _Held(values={n: np.zeros(0) for n in self.names},
                          present={n: np.zeros(0, bool) for n in self.names})
        self.anchor: dict[str, tuple[int, float]] = {}  # channel -> its last sample aligned so far
        self.origin: dict[str, int] = {}  # channel -> its first sample's time (the interpolation's origin)
        self.resampled: set[str] = set()
        self.last_t: int | None = None
        self.shift: int | None = None
        self.temp_first: int | None = None
        self.temp_slot: int | None = None
        self.rows_read = 0
        self.clock = time_base(path, cmap, sniff(path, cmap) if is_format(path, "CSV") else None)
        #: a channel that reads a moment later than the drive torque (the map's lag_s): its samples
        #: at their row's time minus the lag, and rows held back until the ones it needs are read
        self.lag_ns = {n: int(round(spec.lag_s * 1e9)) for n, spec in cmap.channels.items() if spec.lag_s}
        self.lead_ns = max([v for v in self.lag_ns.values() if v > 0], default=0)
        self.tail: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # a lagged channel's samples the next part needs
        self.ahead = _Held(values={n: np.zeros(0) for n in self.names},
                           present={n: np.zeros(0, bool) for n in self.names})
        if self.lag_ns and notes is not None:
            notes.append("aligned: " + ", ".join(f"{n} {1e-6 * v:g} ms earlier (the channel map's lag_s)"
                                                 for n, v in self.lag_ns.items()))

    def read(self, table) -> None:
        """Convert one batch's columns to SI, check its time and hold its rows."""
        path, cmap = self.path, self.cmap
        t_col = table.column(cmap.time.column)
        t_valid = ~np.asarray(t_col.is_null())
        t_ns = time_column_ns(path, cmap.time, t_col, self.clock, self.last_t, self.notes)
        values, present = {}, {}
        for name, spec in cmap.channels.items():
            try:
                raw = numeric_column(path, name, spec, table)
            except InputFileError as exc:  # its data row counts from this batch: from the file's start
                raise InputFileError(_renumber(str(exc), self.rows_read)) from None
            values[name] = spec.to_si(raw)
            present[name] = t_valid & has_value(table, spec)
        valid_t = t_ns[t_valid]
        back = np.flatnonzero(np.diff(valid_t) < 0)
        if back.size or (self.last_t is not None and len(valid_t) and valid_t[0] < self.last_t):
            row = self.rows_read + (int(np.flatnonzero(t_valid)[back[0]]) + 1 if back.size else 0)
            raise InputFileError(f"{path}: time ({cmap.time.column}) runs backwards after data row {row} "
                                 "(time must not decrease)")
        if len(valid_t):
            self.last_t = int(valid_t[-1])
        self.rows_read += table.num_rows
        if self.shift is None:
            self._find_shift(t_ns, present)
        self.held = self.held.then(_Held(t_ns + (self.shift or 0), t_valid, values, present))

    def _find_shift(self, t_ns: np.ndarray, present: dict[str, np.ndarray]) -> None:
        """A relative time that starts below 0 is shifted to start at 0 (a date may not)."""
        any_present = np.logical_or.reduce([present[n] for n in self.names])
        if not any_present.any():
            return
        first = int(t_ns[np.flatnonzero(any_present)[0]])
        self.shift = 0 if first >= 0 else -first
        if self.shift:
            if self.cmap.time.unit == "datetime":
                raise InputFileError(f"{self.path}: time ({self.cmap.time.column}) lies before 1970-01-01: not "
                                     "a recording's date")
            if self.notes is not None:
                self.notes.append(f"time started at {first * 1e-9:g} s: shifted by {self.shift * 1e-9:g} s "
                                  "to start at 0")

    def take(self, final: bool) -> _Held | None:
        """The held rows that can be aligned now: up to the last one with every paired channel
        (all of them at the end, or once a channel has been gone for too long); None if none."""
        held = self.held
        if final or not self.paired:
            cut = len(held.t_ns)
        else:
            complete = np.logical_and.reduce([held.present[n] for n in self.paired])
            idx = np.flatnonzero(complete)
            cut = int(idx[-1]) + 1 if len(idx) else 0
            if len(held.t_ns) - cut > max(MAX_HELD_ROWS, 4 * self.batch_rows):  # a channel gone for good
                cut = len(held.t_ns)
        if not final and self.lead_ns and cut:  # the lagging channel's samples for these rows come later
            limit = int(np.searchsorted(held.t_ns, held.t_ns[-1] - self.lead_ns, side="right"))
            if limit < cut:  # the last row there with every paired channel
                complete = np.logical_and.reduce([held.present[n] for n in self.paired]) if self.paired else \
                    np.ones(len(held.t_ns), bool)
                idx = np.flatnonzero(complete[:limit])
                cut = int(idx[-1]) + 1 if len(idx) else 0
        if cut == 0:
            return None
        self.held = held.rows(slice(cut, None))
        self.ahead = self.held
        return held.rows(slice(None, cut))

    def align(self, part: _Held) -> Aligned:
        """``part``'s paired channels on the motor torque's time base, and its thinned temperature."""
        base = part.present[Channel.MOTOR_TORQUE]
        base_t = part.t_ns[base]
        out = {Channel.MOTOR_TORQUE: part.values[Channel.MOTOR_TORQUE][base]}
        for name in self.paired[1:]:
            has = part.present[name]
            lag = self.lag_ns.get(name, 0)
            s_t, s_v = part.t_ns[has] - lag, part.values[name][has]
            if name not in self.origin and len(s_t):
                self.origin[name] = int(s_t[0])
            if lag or not np.array_equal(has, base):
                self.resampled.add(name)
            if lag:  # with the samples of earlier rows that reach into this part (a channel that leads)
                # and of the rows read after it (one that lags)
                tail_t, tail_v = self.tail.get(name, (np.zeros(0, np.int64), np.zeros(0)))
                more = self.ahead.present[name]
                t_all = np.concatenate([tail_t, s_t, self.ahead.t_ns[more] - lag])
                v_all = np.concatenate([tail_v, s_v, self.ahead.values[name][more]])
                out[name] = _interpolate(t_all, v_all, base_t, None, self.origin.get(name))
                mine_t, mine_v = np.concatenate([tail_t, s_t]), np.concatenate([tail_v, s_v])
                if len(base_t):  # what the next part may need: from the last sample before its rows on
                    first = max(int(np.searchsorted(mine_t, base_t[-1], side="right")) - 1, 0)
                    self.tail[name] = (mine_t[first:], mine_v[first:])
                continue
            elif name in self.resampled:
                out[name] = _interpolate(s_t, s_v, base_t, self.anchor.get(name), self.origin.get(name))
            else:
                out[name] = s_v
            if len(s_t):
                self.anchor[name] = (int(s_t[-1]), float(s_v[-1]))
        return Aligned(base_t, out, self._temperature(part), [c for c in self.paired if c in self.resampled])

    def _temperature(self, part: _Held) -> Series | None:
        """The oil temperature of ``part``, at most one a second over the whole file."""
        if Channel.OIL_TEMPERATURE not in self.cmap.channels:
            return None
        has = part.present[Channel.OIL_TEMPERATURE]
        tt = part.t_ns[has] - self.lag_ns.get(Channel.OIL_TEMPERATURE, 0)
        tv = part.values[Channel.OIL_TEMPERATURE][has]
        if not len(tt):
            return None
        if self.temp_first is None:
            self.temp_first = int(tt[0])
        slot = (tt - self.temp_first) // int(1e9 / TEMPERATURE_MAX_RATE_HZ)
        keep = np.r_[self.temp_slot is None or slot[0] != self.temp_slot, slot[1:] != slot[:-1]]
        self.temp_slot = int(slot[-1])
        return Series(tt[keep], tv[keep])


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
