"""ASAM MDF4 time series through a channel map, with ``asammdf``.

Each channel on its own master (time) channel from the measurement's start, or on a time channel
the map names; a channel name found in several data groups is chosen as ``name@GROUP``.  A file
``asammdf`` cannot read is one line.  No rclpy import.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..base.errors import InputFileError
from .channelmap import ChannelMap, unit_matches
from .timeseries import Series, as_numbers, seconds_to_ns, with_constants

__all__ = ["open_mdf", "read_mdf4_series"]


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
            clock = np.round(cmap.time.to_si(as_numbers(path, "time", cmap.time.column,
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
            values = spec.to_si(as_numbers(path, name, spec.column, signal.samples))
            if clock is None:
                t_ns = start_ns + seconds_to_ns(path, f"{name} ({spec.column})", signal.timestamps)
            elif len(clock) == len(values):
                t_ns = start_ns + clock.astype(np.int64)
            else:
                raise InputFileError(f"{path}: {name} ({spec.column}) has {len(values)} samples, the time channel "
                                     f"{cmap.time.column!r} {len(clock)}: a time channel serves the channels of its "
                                     "data group (leave time out of the map to use each channel's own)")
            out[name] = Series(t_ns, values)
        return with_constants(out, cmap)
    finally:
        mdf.close()


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
