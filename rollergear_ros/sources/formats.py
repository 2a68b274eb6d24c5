"""The input formats this package reads, in one table: what each is called, its file name endings,
how it is read and what it needs.

``import``, ``replay``, ``calibrate``, ``fleet`` and ``play`` ask this table what a path is
(:func:`input_format`); the time-series reader, the CSV/Parquet stream, the fleet's collector and
the error messages take their suffixes and names from it.  A new format is one entry here plus its
reader (``reader`` names it) and its tests.  No rclpy, no reader library imported here.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ..base.errors import InputFileError


@dataclass(frozen=True)
class InputFormat:
    """One input format."""

    name: str  #: as users see it (``ImportSummary.kind``, messages): "CSV", "MDF4", …
    suffixes: tuple[str, ...]  #: file name endings, lower case (a rosbag2 bag is also a folder)
    #: ``mcap`` (read as it is), ``rosbag2`` (imported by topic), ``timeseries`` (channels named by a
    #: channel map), ``table`` (steady-state operating points)
    family: str
    own_time: bool = False  #: carries its time base (a channel map needs no ``time`` entry)
    #: read through pyarrow: in bounded batches, and also as a steady-state table (else whole, as its
    #: library reads channels)
    arrow: bool = False
    #: what reads a time series of this format into channels (``timeseries`` family): a function
    #: ``(path, channel_map, notes) -> {channel: Series}``, or its ``module:function`` (imported when
    #: first asked: its library may be heavy)
    reader: str | Callable = ""

    def read_series(self) -> Callable:
        """The reader function."""
        if callable(self.reader):
            return self.reader
        module, function = self.reader.split(":")
        return getattr(importlib.import_module(module, __package__), function)


#: every format ``import`` reads, by name, in the order messages list them (:func:`register` adds one)
INPUT_FORMATS: dict[str, InputFormat] = {}


def register(fmt: InputFormat) -> InputFormat:
    """Add (or replace) an input format; returns it."""
    INPUT_FORMATS[fmt.name] = fmt
    return fmt


def unregister(name: str) -> None:
    """Remove an input format (tests that register a toy format)."""
    INPUT_FORMATS.pop(name, None)


def format_by_suffix(path: str | Path) -> InputFormat | None:
    """The format ``path``'s ending names (None: none of the table's), without opening it."""
    suffix = Path(path).suffix.lower()
    return next((f for f in INPUT_FORMATS.values() if suffix in f.suffixes), None)


def is_format(path: str | Path, name: str) -> bool:
    """Whether ``path``'s ending names the format ``name``."""
    found = format_by_suffix(path)
    return found is not None and found.name == name


def suffixes(*families: str) -> tuple[str, ...]:
    """The endings of the formats of these families (all of them: none given)."""
    return tuple(s for f in INPUT_FORMATS.values() if not families or f.family in families for s in f.suffixes)


def recording_suffixes() -> tuple[str, ...]:
    """Endings of the formats that hold channels over time (not the steady-state tables): what a fleet collects."""
    return suffixes("mcap", "rosbag2", "timeseries")


def input_format(path: str | Path) -> InputFormat:
    """What ``path`` is: a rosbag2 bag (a folder, its ``metadata.yaml`` or a ``.db3``), or the format its
    ending names.  One clear error for a path that is missing, not a regular file, or of no format here."""
    p = Path(path)
    if not p.exists():
        raise InputFileError(f"{p} does not exist")
    if not (p.is_dir() or p.is_file()):  # a FIFO or a device would block or never end
        raise InputFileError(f"{p} is not a regular file")
    if p.is_dir() or p.name == "metadata.yaml":
        return INPUT_FORMATS["rosbag2"]
    found = format_by_suffix(p)
    if found is None:
        raise InputFileError(f"{p}: not a recording this package reads (MCAP, a rosbag2 folder or .db3, a VECTO "
                             f".vtlm, or {', '.join(sorted(suffixes('timeseries')))} with --channels MAP.yaml)")
    return found


for _fmt in (
    InputFormat("MCAP", (".mcap",), "mcap"),
    InputFormat("rosbag2", (".db3",), "rosbag2"),
    InputFormat("VTLM", (".vtlm",), "table"),
    InputFormat("CSV", (".csv",), "timeseries", arrow=True, reader=".arrowfiles:read_arrow_series"),
    InputFormat("Parquet", (".parquet",), "timeseries", arrow=True, reader=".arrowfiles:read_arrow_series"),
    InputFormat("MDF4", (".mf4", ".mdf"), "timeseries", own_time=True, reader=".mdf4:read_mdf4_series"),
    InputFormat("TDMS", (".tdms",), "timeseries", own_time=True, reader=".tdms:read_tdms_series"),
):
    register(_fmt)


__all__ = ["INPUT_FORMATS", "InputFormat", "format_by_suffix", "input_format", "is_format", "recording_suffixes",
           "register", "suffixes", "unregister"]
