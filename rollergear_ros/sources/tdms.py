"""NI TDMS time series through a channel map, with ``nptdms``.

Channels are named ``group/channel``; each on its waveform's own time (``wf_start_time``,
``wf_start_offset``, ``wf_increment``) or on a time channel the map names.  What nptdms warns of
while reading a damaged file becomes one note.  No rclpy import.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..base.errors import InputFileError
from .channelmap import ChannelMap, unit_matches
from .timeseries import Series, as_numbers, seconds_to_ns, with_constants

__all__ = ["read_tdms_series"]


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
        base = np.round(cmap.time.to_si(as_numbers(path, "time", cmap.time.column,
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
        values = as_numbers(path, name, spec.column, ch[:])
        if base is not None:
            if len(base) != len(values):
                raise InputFileError(f"{path}: {name} ({spec.column}) has {len(values)} samples, the time channel "
                                     f"{cmap.time.column!r} {len(base)}")
            t_ns = base
        else:
            t_ns = _waveform_ns(path, f"{name} ({spec.column})", ch.properties, len(values))
        out[name] = Series(t_ns, spec.to_si(values))
    return with_constants(out, cmap)


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
