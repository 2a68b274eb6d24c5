"""Channel maps: which column of a non-ROS file is which input, in which unit (``interface.md``).

A channel map is a YAML file given as ``--channels MAP.yaml``::

    format: timeseries            # timeseries | steady_state
    time: {column: t, unit: s}    # s | ms | us | ns | datetime (ISO 8601 strings)
    motor_torque: {column: T_in, unit: N*m}
    motor_speed: {column: n_in, unit: rpm}
    output_torque: {column: T_out, unit: N*m, scale: -1}
    oil_temperature: {column: T_oil, unit: degC}
    ratio: 5.875                  # steady_state: also {column: NAME}, each row's ratio
    group: {column: gear}
    timezone: Europe/Berlin       # of date-times and clock times written without a zone (default UTC)
    date: {preamble: Datum}       # the day of clock times HH:MM:SS: a preamble line, or 2026-11-24

A steady-state table may give the output side instead of the motor's (output torque, output
speed, efficiency and the ratio: NREL ADVISOR's maps).  Values are converted to SI as
``value_SI = (value·factor + offset)·scale`` (the offset only for temperatures).  Everything wrong
in a map is one :class:`~base.errors.InputFileError` line naming the map, the key and what is wrong.  No rclpy import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..base import safeyaml
from ..base.errors import InputFileError
from ..base.interface import Channel

__all__ = ["ChannelMap", "ChannelSpec", "UNITS", "load_channel_map", "unit_matches", "zone_info"]

_TORQUE = {"N*m": (1.0, 0.0), "N*mm": (1e-3, 0.0), "kN*m": (1e3, 0.0), "lbf*ft": (1.3558179483314004, 0.0)}
_SPEED = {"rad/s": (1.0, 0.0), "rpm": (2.0 * math.pi / 60.0, 0.0), "rev/s": (2.0 * math.pi, 0.0),
          "deg/s": (math.pi / 180.0, 0.0)}
_TEMPERATURE = {"degC": (1.0, 0.0), "K": (1.0, -273.15), "degF": (5.0 / 9.0, -32.0 * 5.0 / 9.0)}
#: channel -> unit -> (factor, offset) to SI (N·m, rad/s, °C, 1, ns)
UNITS: dict[str, dict[str, tuple[float, float]]] = {
    Channel.MOTOR_TORQUE: _TORQUE, Channel.OUTPUT_TORQUE: _TORQUE, "loss_torque": _TORQUE,
    Channel.MOTOR_SPEED: _SPEED, Channel.OUTPUT_SPEED: _SPEED,
    Channel.OIL_TEMPERATURE: _TEMPERATURE,
    "efficiency": {"%": (0.01, 0.0), "1": (1.0, 0.0)},
    "time": {"s": (1e9, 0.0), "ms": (1e6, 0.0), "us": (1e3, 0.0), "ns": (1.0, 0.0), "datetime": (1.0, 0.0)},
}
#: other spellings of the units, as files write them
_ALIASES = {"nm": "N*m", "n·m": "N*m", "n.m": "N*m", "n m": "N*m", "n-m": "N*m", "nmm": "N*mm", "n·mm": "N*mm",
            "knm": "kN*m", "kn·m": "kN*m", "lbf·ft": "lbf*ft", "ft*lbf": "lbf*ft", "lb-ft": "lbf*ft",
            "1/min": "rpm", "min-1": "rpm", "min^-1": "rpm", "min⁻¹": "rpm", "u/min": "rpm", "upm": "rpm",
            "rev/min": "rpm", "r/min": "rpm", "rad/sec": "rad/s",
            "°c": "degC", "c": "degC", "degc": "degC", "deg c": "degC", "celsius": "degC", "k": "K",
            "°f": "degF", "degf": "degF", "deg f": "degF", "sec": "s", "µs": "us", "-": "1", "percent": "%"}
STEADY_LOSS_CHANNELS = ("loss_torque", Channel.OUTPUT_TORQUE, "efficiency")
FORMATS = ("timeseries", "steady_state")


def _canonical(unit: str) -> str:
    u = str(unit).strip()
    return _ALIASES.get(u.lower(), u)


def unit_matches(channel: str, file_unit: str | None, map_unit: str) -> bool:
    """Whether a unit a file's metadata states agrees with the map's (empty: nothing stated)."""
    if not file_unit or not str(file_unit).strip():
        return True
    canonical = _canonical(file_unit)
    return canonical == map_unit or UNITS.get(channel, {}).get(canonical) == UNITS[channel][map_unit]


@dataclass(frozen=True)
class ChannelSpec:
    """One channel: its column (or ``group/channel`` in TDMS), unit and scale; or a constant (a
    channel known but not measured: ``output_torque: {constant: 0, unit: N*m}`` in a spin test)."""

    channel: str
    column: str
    unit: str
    scale: float = 1.0
    constant: float | None = None  #: the channel's value in the map's unit (no column)
    #: how much later than the drive torque this channel reads the same moment [s] (a DAQ's filter, a
    #: sensor's electronics; ``calibrate`` fits and reports it): its times are moved back by it on reading
    lag_s: float = 0.0

    @property
    def label(self) -> str:
        """How messages name it: its column, or its constant."""
        return self.column if self.constant is None else f"constant {self.constant:g} {self.unit}"

    def to_si(self, values: np.ndarray) -> np.ndarray:
        factor, offset = UNITS[self.channel][self.unit]
        return (np.asarray(values, dtype=np.float64) * factor + offset) * self.scale


@dataclass(frozen=True)
class ChannelMap:
    """A validated channel map."""

    path: Path
    format: str
    channels: dict[str, ChannelSpec]  #: channel -> spec (only those the file has)
    time: ChannelSpec | None = None
    ratio: float | None = None
    group: str | None = None  #: column whose value tells gearbox states apart
    extra: dict[str, Any] = field(default_factory=dict)
    ratio_column: str | None = None  #: steady_state: a column with each row's ratio (``ratio: {column: …}``)
    timezone: str | None = None  #: the zone of date-times and clock times written without one (None: UTC, said)
    date: str | None = None  #: the day of clock times (ISO ``YYYY-MM-DD``)
    date_label: str | None = None  #: ... or the preamble line that gives it (``Datum;24.11.2026``)
    date_format: str | None = None  #: strptime format of the preamble's date (None: ISO, then dd.mm.yyyy)

    @property
    def output_side(self) -> bool:
        """A steady-state table of the output shaft (output torque, speed and efficiency; the input
        side follows from the ratio)."""
        return Channel.MOTOR_TORQUE not in self.channels

    def columns(self) -> list[str]:
        """Every column the map reads."""
        cols = [s.column for s in self.channels.values() if s.constant is None]
        if self.time is not None and self.time.column not in cols:
            cols.insert(0, self.time.column)
        cols += [c for c in (self.group, self.ratio_column) if c is not None and c not in cols]
        return cols


def _finite_number(value: Any) -> bool:
    """Whether ``value`` is a finite number as a float (not a bool, a string or None; an integer of 400
    digits is not)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    try:
        return math.isfinite(float(value))
    except OverflowError:
        return False


def _spec(path: Path, key: str, value: Any) -> ChannelSpec:
    if not isinstance(value, dict) or ("column" in value) == ("constant" in value):
        raise InputFileError(f"{path}: {key}: expected {{column: NAME, unit: UNIT}} or "
                             f"{{constant: VALUE, unit: UNIT}}, got {value!r}")
    unknown = set(value) - {"column", "constant", "unit", "scale", "lag_s"}
    if unknown:
        raise InputFileError(f"{path}: {key}: unknown key(s) {', '.join(sorted(unknown))} (column or constant, unit, "
                             "scale, lag_s)")
    constant = value.get("constant")
    if "constant" in value:
        if key == "time" or not _finite_number(constant):
            raise InputFileError(f"{path}: {key}: constant must be a finite number"
                                 f"{' (time cannot be constant)' if key == 'time' else ''}, got {constant!r}")
    allowed = UNITS[key]
    if "unit" not in value:
        raise InputFileError(f"{path}: {key}: no unit (one of {', '.join(allowed)})")
    unit = _canonical(value["unit"])
    if unit not in allowed:
        raise InputFileError(f"{path}: {key}: unknown unit {value['unit']!r} (one of {', '.join(allowed)})")
    scale = value.get("scale", 1.0)
    if not _finite_number(scale) or scale == 0:
        raise InputFileError(f"{path}: {key}: scale must be a finite non-zero number, got {scale!r}")
    lag = value.get("lag_s", 0.0)
    if not _finite_number(lag) or abs(lag) > MAX_LAG_S:
        raise InputFileError(f"{path}: {key}: lag_s must be a finite number of seconds within ±{MAX_LAG_S:g}, "
                             f"got {lag!r}")
    if lag and (key == "time" or constant is not None):
        raise InputFileError(f"{path}: {key}: lag_s is for a measured channel (not the time, not a constant)")
    if constant is not None:
        return ChannelSpec(key, "", unit, float(scale), float(constant))
    return ChannelSpec(key, str(value["column"]), unit, float(scale), lag_s=float(lag))


#: a gear ratio (input/output speed) a map may state: a gearbox's, not a number's range
MIN_RATIO, MAX_RATIO = 1e-4, 1e4
MAX_LAG_S = 10.0  #: a channel's ``lag_s`` is at most this (longer is another time base, not a lag)


def load_channel_map(path: str | Path) -> ChannelMap:
    """Read and validate a channel map (see the module docstring)."""
    path = Path(path)
    if not path.exists():
        raise InputFileError(f"channel map {path} does not exist")
    try:
        doc = safeyaml.load(path)
    except safeyaml.YamlProblem as problem:
        raise InputFileError(f"channel map {problem}") from None
    if not isinstance(doc, dict):
        raise InputFileError(f"{path}: a channel map is a YAML mapping (format, time, motor_torque, …)")
    known = set(UNITS) | {"format", "ratio", "group", "timezone", "date"}
    unknown = sorted(set(doc) - known)
    if unknown:
        raise InputFileError(f"{path}: unknown key(s) {', '.join(unknown)} (known: {', '.join(sorted(known))})")
    fmt = doc.get("format", "timeseries")
    if fmt not in FORMATS:
        raise InputFileError(f"{path}: format: {fmt!r} is not one of {', '.join(FORMATS)}")
    channels = {k: _spec(path, k, v) for k, v in doc.items() if k in UNITS and k != "time"}
    _check_sides(path, doc, fmt, channels)
    time = _spec(path, "time", doc["time"]) if "time" in doc else None
    _check_kinds(path, fmt, channels)
    ratio, ratio_column = _ratio(path, doc.get("ratio"), fmt)
    group = doc.get("group")
    if group is not None:
        if not isinstance(group, dict) or set(group) != {"column"}:
            raise InputFileError(f"{path}: group: expected {{column: NAME}}, got {group!r}")
        group = str(group["column"])
    columns = [(k, s.column) for k, s in channels.items() if s.constant is None]
    columns += [("time", time.column)] if time else []
    seen: dict[str, str] = {}
    for key, column in columns:
        if column in seen:
            raise InputFileError(f"{path}: column {column!r} is mapped to both {seen[column]} and {key}")
        seen[column] = key
    zone, date, date_label, date_format = _time_keys(path, doc, time)
    return ChannelMap(path, fmt, channels, time, None if ratio is None else float(ratio), group,
                      ratio_column=ratio_column, timezone=zone, date=date, date_label=date_label,
                      date_format=date_format)


def _check_sides(path: Path, doc: dict, fmt: str, channels: dict[str, ChannelSpec]) -> None:
    """The motor's torque and speed are there, or (a steady-state table) the output side with the ratio."""
    output_side = fmt == "steady_state" and Channel.MOTOR_TORQUE not in channels and Channel.MOTOR_SPEED not in channels
    if output_side:
        missing = [k for k in (Channel.OUTPUT_TORQUE, Channel.OUTPUT_SPEED, "efficiency") if k not in channels]
        if missing or doc.get("ratio") is None:
            raise InputFileError(f"{path}: no motor_torque and motor_speed channels; a table of the output side needs "
                                 f"output_torque, output_speed, efficiency and ratio (missing: "
                                 f"{', '.join(missing + ([] if doc.get('ratio') is not None else ['ratio']))})")
    else:
        # a bench map of input torque, output speed and the ratio: the input speed is output speed x ratio
        speed_from_output = (fmt == "steady_state" and Channel.OUTPUT_SPEED in channels
                             and doc.get("ratio") is not None)
        for needed in (Channel.MOTOR_TORQUE,) + (() if speed_from_output else (Channel.MOTOR_SPEED,)):
            if needed not in channels:
                raise InputFileError(f"{path}: no {needed} channel (every file needs motor_torque and motor_speed; "
                                     "a steady-state table may give the output side instead)")


def _check_kinds(path: Path, fmt: str, channels: dict[str, ChannelSpec]) -> None:
    """The drive torque is measured, and no channel belongs to the other format."""
    if channels.get(Channel.MOTOR_TORQUE) is not None and channels[Channel.MOTOR_TORQUE].constant is not None:
        raise InputFileError(f"{path}: motor_torque: the drive torque is measured, not a constant")
    if fmt == "timeseries":  # time: needed by CSV and Parquet; MDF4 and TDMS carry their own (see timeseries)
        steady_only = [k for k in ("loss_torque", "efficiency") if k in channels]
        if steady_only:
            raise InputFileError(f"{path}: {', '.join(steady_only)} belong to format: steady_state")
    elif not any(k in channels for k in STEADY_LOSS_CHANNELS):
        raise InputFileError(f"{path}: a steady_state map needs loss_torque, output_torque or efficiency")


def _ratio(path: Path, ratio, fmt: str) -> tuple[float | None, str | None]:
    """The map's ratio: (a number > 0, None), (None, a column of a steady-state table) or (None, None)."""
    if isinstance(ratio, dict) and fmt == "steady_state":
        if set(ratio) != {"column"}:
            raise InputFileError(f"{path}: ratio: expected a number > 0 or {{column: NAME}}, got {ratio!r}")
        return None, str(ratio["column"])
    if ratio is not None and not (_finite_number(ratio) and MIN_RATIO <= ratio <= MAX_RATIO):
        raise InputFileError(f"{path}: ratio must be a number in [{MIN_RATIO:g}, {MAX_RATIO:g}]"
                             f"{' (or {column: NAME} in a steady_state map)' if fmt == 'steady_state' else ''}, "
                             f"got {ratio!r}")
    return ratio, None


def zone_info(name: str):
    """A ``tzinfo`` of a zone name (``Europe/Berlin``, ``UTC``) or a fixed offset (``+01:00``)."""
    import datetime
    import re
    import zoneinfo

    m = re.fullmatch(r"([+-])(\d{2}):?(\d{2})", name)
    if m:
        minutes = int(m.group(2)) * 60 + int(m.group(3))
        return datetime.timezone(datetime.timedelta(minutes=minutes if m.group(1) == "+" else -minutes))
    return zoneinfo.ZoneInfo(name)


def _time_keys(path: Path, doc: dict, time: ChannelSpec | None):
    """``timezone`` and ``date`` of a map: (zone, ISO date, preamble label, its format)."""
    import datetime

    zone = doc.get("timezone")
    if zone is not None:
        try:
            zone_info(str(zone))
        except (ValueError, KeyError, OSError):
            raise InputFileError(f"{path}: timezone: {zone!r} is not a time zone (Europe/Berlin, UTC, +01:00)") \
                from None
        zone = str(zone)
    date = doc.get("date")
    if date is None:
        return zone, None, None, None
    if time is None or time.unit != "datetime":
        raise InputFileError(f"{path}: date: belongs to clock times (time: {{column: …, unit: datetime}})")
    if isinstance(date, datetime.date):
        return zone, date.isoformat(), None, None
    if isinstance(date, str):
        try:
            return zone, datetime.date.fromisoformat(date.strip()).isoformat(), None, None
        except ValueError:
            raise InputFileError(f"{path}: date: {date!r} is not a date YYYY-MM-DD") from None
    if isinstance(date, dict) and "preamble" in date and set(date) <= {"preamble", "format"}:
        return zone, None, str(date["preamble"]), (str(date["format"]) if "format" in date else None)
    raise InputFileError(f"{path}: date: expected YYYY-MM-DD or {{preamble: LABEL, format: '%d.%m.%Y'}}, got {date!r}")
