"""Time series from non-ROS files -- CSV, Parquet, ASAM MDF4, NI TDMS -- through a channel map.

One reader per format behind :func:`read_series` (the format by the file's suffix, the reader by
:mod:`.formats`' registry), each with the format's own library: :mod:`.arrowfiles` (``pyarrow``: CSV,
Parquet), :mod:`.mdf4` (``asammdf``), :mod:`.tdms` (``nptdms``).  Every
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


from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .channelmap import ChannelMap
from ..base.errors import InputFileError
from .formats import INPUT_FORMATS, format_by_suffix, suffixes
from ..base.interface import Channel

__all__ = ["Aligned", "Series", "align", "as_numbers", "read_series", "seconds_to_ns", "with_constants"]

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


def with_constants(out: dict[str, Series], cmap: ChannelMap) -> dict[str, Series]:
    """The map's constant channels at the motor torque's times."""
    base = out[Channel.MOTOR_TORQUE].t_ns
    for name, spec in cmap.channels.items():
        if spec.constant is not None:
            out[name] = Series(base, spec.to_si(np.full(len(base), spec.constant)))
    return out


def as_numbers(path: Path, name: str, column: str, values) -> np.ndarray:
    """A channel's samples as float64; text or other non-numbers: one line naming the channel."""
    values = np.asarray(values)
    if values.dtype.kind not in "fiub":
        raise InputFileError(f"{path}: {name} ({column}): not numbers (samples of type {values.dtype})")
    return values.astype(np.float64)


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
