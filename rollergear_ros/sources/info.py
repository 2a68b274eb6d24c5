"""``rollergear info FILE``: what a recording or table holds, for every format ``import`` reads.

What ``ros2 bag info`` and ``mcap info`` print -- topics (or channels, or columns) with their types,
counts and rates, the time span, the metadata keys, and the damaged spans -- from the file alone,
without pairing or estimating.  The format comes from :mod:`.formats`; a time-series file with a
channel map (``--channels``) is described channel by channel as ``import`` would read it, without
one by its columns.  No rclpy import.
"""

from __future__ import annotations

import math

import datetime
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .channelmap import ChannelMap, load_channel_map
from ..base.text import printable
from ..base.errors import InputFileError
from .formats import InputFormat, input_format


@dataclass
class StreamInfo:
    """One topic, channel or column."""

    name: str
    kind: str  #: message type, unit, or column type
    count: int
    rate_hz: float | None = None  #: mean rate over its own span (None: fewer than two samples or no time)


@dataclass
class FileInfo:
    """What one file holds."""

    path: str
    format: str
    size_bytes: int
    start_ns: int | None = None
    end_ns: int | None = None
    streams: list[StreamInfo] = field(default_factory=list)
    metadata: list[str] | None = field(default_factory=list)  #: metadata record names / keys (None: unknown)
    damaged: list[str] = field(default_factory=list)  #: what of the file cannot be read, and where
    notes: list[str] = field(default_factory=list)
    counted: str = "messages"  #: what a stream's count counts (messages, samples, rows)
    #: the share of a recording its damage cost (:func:`base.errors.lost_share`; 1: nothing readable)
    lost_share: float = 0.0

    @property
    def duration_s(self) -> float | None:
        if self.start_ns is None or self.end_ns is None:
            return None
        return (self.end_ns - self.start_ns) * 1e-9

    def as_dict(self) -> dict[str, Any]:
        return {**asdict(self), "duration_s": self.duration_s}

    def text(self) -> str:
        """As ``mcap info`` lays it out: one field per line, then one line per stream; what the file
        names (topics, types, metadata) with control characters escaped: a file cannot fake lines."""
        return "\n".join(printable(line, None) for line in self._lines())

    def _lines(self) -> list[str]:
        lines = [f"path:      {self.path}", f"format:    {self.format}", f"size:      {_size(self.size_bytes)}"]
        if self.duration_s is not None:
            lines += [f"duration:  {self.duration_s:.3f} s", f"start:     {_when(self.start_ns)}",
                      f"end:       {_when(self.end_ns)}"]
        total = sum(s.count for s in self.streams)
        lines.append(f"streams:   {len(self.streams)} ({total:,} {self.counted})" if self.streams
                     else "streams:   none")
        width = max((len(s.name) for s in self.streams), default=0)
        kind_width = max((len(s.kind) for s in self.streams), default=0)
        for s in self.streams:
            rate = f"  {s.rate_hz:.4g} Hz" if s.rate_hz is not None else ""
            lines.append(f"  {s.name:{width}s}  {s.kind:{kind_width}s}  {s.count:>12,}{rate}")
        lines.append("metadata:  unknown (see the notes)" if self.metadata is None
                     else f"metadata:  {', '.join(self.metadata) or 'none'}")
        lines.append(f"damaged:   {'; '.join(self.damaged) or 'nothing found'}")
        lines += [f"note:      {n}" for n in self.notes]
        return lines


def describe(path: str | Path, channels: str | Path | None = None) -> FileInfo:
    """What ``path`` holds (``channels``: a channel map, for a time-series file)."""
    fmt = input_format(path)
    p = Path(path)
    size = sum(f.stat().st_size for f in p.rglob("*") if f.is_file()) if p.is_dir() else p.stat().st_size
    info = FileInfo(str(path), fmt.name, size)
    cmap = load_channel_map(channels) if channels is not None and fmt.family in ("table", "timeseries") else None
    if fmt.family == "mcap":
        _mcap(p, info)
    elif fmt.family == "rosbag2":
        _rosbag2(p, info)
    elif fmt.family == "table" or (cmap is not None and cmap.format == "steady_state"):
        _table(p, info, cmap)
    elif cmap is not None:
        _mapped_series(p, info, cmap)
    else:
        _columns(p, fmt, info)
    return info


def _rate(count: int, start_ns: int | None, end_ns: int | None) -> float | None:
    if count < 2 or start_ns is None or end_ns is None or end_ns <= start_ns:
        return None
    return (count - 1) / ((end_ns - start_ns) * 1e-9)


def _mcap(path: Path, info: FileInfo) -> None:
    from mcap.reader import make_reader

    from ..recordings.baginfo import SUMMARY_ERRORS, inspect_bag

    bag = inspect_bag(path)
    info.start_ns, info.end_ns = (bag.start_ns, bag.end_ns) if bag.message_count else (None, None)
    info.streams = [StreamInfo(t, bag.topics.get(t, ""), bag.counts.get(t, 0),
                               _rate(bag.counts.get(t, 0), info.start_ns, info.end_ns)) for t in sorted(bag.topics)]
    if not bag.indexed:
        info.damaged.append("no usable summary (index): topics and counts from a scan of the records")
    if bag.truncated or bag.bytes_readable < bag.bytes_total:
        info.damaged.append(f"bytes {bag.bytes_readable:,}–{bag.bytes_total:,} unreadable"
                            + (f" ({bag.problem})" if bag.problem else ""))
    # every chunk decompressed and its CRC checked, as replay and play will read them
    from ..base.errors import lost_share
    from ..recordings.fastmcap import ReadState, iter_message_arrays, preload_summary

    state = ReadState()
    preload_summary(path, state)
    read = sum(len(arrays) for arrays in iter_message_arrays(path, state))
    info.damaged += [line for line in state.damage_report() if line not in info.damaged]
    if state.damaged:
        share = 1.0 if not read else lost_share(state.damaged, bag.bytes_total, bag.message_count)
        info.lost_share = share
        info.damaged.append(f"{100 * share:.1f} % of the recording unreadable")
    info.notes.append("every chunk was read and its CRC checked")
    try:
        with path.open("rb") as fh:
            info.metadata = sorted({md.name for md in make_reader(fh).iter_metadata()})
    except SUMMARY_ERRORS:
        info.metadata = None
        info.notes.append("metadata records not listed: they are found through the summary")
    if bag.message_count:
        info.notes.append("rates are each topic's messages over the recording's span")


def _rosbag2(path: Path, info: FileInfo) -> None:
    from .importer import rosbag2_reader

    with rosbag2_reader(path) as reader:
        connections = list(reader.connections)
        counts: dict[tuple[str, str], int] = {}
        for c in connections:
            if int(c.msgcount) < 0:
                info.damaged.append(f"{c.topic}: a negative message count ({int(c.msgcount)}) in metadata.yaml")
            counts[(c.topic, c.msgtype)] = counts.get((c.topic, c.msgtype), 0) + max(int(c.msgcount), 0)
        total = sum(counts.values())
        info.start_ns, info.end_ns = (int(reader.start_time), int(reader.end_time)) if total else (None, None)
        info.streams = [StreamInfo(t, ty, n, _rate(n, info.start_ns, info.end_ns))
                        for (t, ty), n in sorted(counts.items())]
    meta = path / "metadata.yaml" if path.is_dir() else path if path.name == "metadata.yaml" else None
    if meta is not None and meta.exists():
        from ..base import safeyaml

        doc = safeyaml.load(meta)
        bag = doc.get("rosbag2_bagfile_information", {}) if isinstance(doc, dict) else {}
        info.metadata = [f"{k}: {bag[k]}" for k in ("version", "storage_identifier", "compression_format",
                                                    "compression_mode") if isinstance(bag, dict) and bag.get(k)]


def _table(path: Path, info: FileInfo, cmap: ChannelMap | None) -> None:
    from .tables import read_table

    table = read_table(path, cmap)
    n = len(table.speed_rad_s)
    info.counted = "rows"
    info.streams = [StreamInfo(name, unit, n) for name, unit in (("speed", "rad/s"), ("torque", "N*m"),
                                                                  ("loss", "N*m"))]
    if n:
        info.notes.append(f"{n:,} operating points: speed {np.min(table.speed_rad_s):.4g}…"
                          f"{np.max(table.speed_rad_s):.4g} rad/s, torque {np.min(table.torque_nm):.4g}…"
                          f"{np.max(table.torque_nm):.4g} N·m, loss {np.min(table.loss_nm):.4g}…"
                          f"{np.max(table.loss_nm):.4g} N·m")
    if table.dropped:
        info.damaged.append(f"{table.dropped} rows without a finite torque, speed or loss")


def _mapped_series(path: Path, info: FileInfo, cmap: ChannelMap) -> None:
    from .timeseries import read_series

    series = read_series(path, cmap, info.notes)
    info.counted = "samples"
    starts = [int(s.t_ns[0]) for s in series.values() if len(s.t_ns)]
    ends = [int(s.t_ns[-1]) for s in series.values() if len(s.t_ns)]
    info.start_ns, info.end_ns = (min(starts), max(ends)) if starts else (None, None)
    for name, s in series.items():
        spec = cmap.channels[name]
        source = f"constant {spec.constant:g}" if spec.constant is not None else spec.column
        first, last = (int(s.t_ns[0]), int(s.t_ns[-1])) if len(s.t_ns) else (None, None)
        info.streams.append(StreamInfo(f"{name} ({source})", "SI", len(s.t_ns), _rate(len(s.t_ns), first, last)))
    info.notes.append(f"channels as import reads them with {cmap.path}")


def _columns(path: Path, fmt: InputFormat, info: FileInfo) -> None:
    """A time-series file without a channel map: its columns (their times need the map's ``time``)."""
    info.counted = "values"
    if fmt.name == "Parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        from .arrowfiles import first_line

        try:
            meta = pq.ParquetFile(path).metadata
        except (pa.ArrowException, OSError) as exc:
            raise InputFileError(f"{path}: not a Parquet file ({first_line(exc)})") from None
        schema = meta.schema.to_arrow_schema()
        info.streams = [StreamInfo(f.name, str(f.type), meta.num_rows) for f in schema]
    elif fmt.name == "CSV":
        with path.open("rb") as fh:
            header = fh.readline().decode("utf-8", errors="replace").strip()
            rows = sum(chunk.count(b"\n") for chunk in iter(lambda: fh.read(1 << 20), b""))
        import csv

        delimiter = max((",", ";", "\t"), key=header.count)
        info.streams = [StreamInfo(c.strip(), "column", rows) for c in next(csv.reader([header], delimiter=delimiter))]
        info.notes.append("columns of the first line, rows counted as lines after it (a units row counts)")
    elif fmt.name == "MDF4":
        from .mdf4 import open_mdf

        mdf = open_mdf(path)
        try:
            for g, group in enumerate(mdf.groups):
                master = mdf.get_master(g)
                span = (int(master[0] * 1e9), int(master[-1] * 1e9)) if len(master) else (None, None)
                master_index = mdf.masters_db.get(g)
                for c, ch in enumerate(group.channels):
                    if c != master_index:
                        info.streams.append(StreamInfo(ch.name, ch.unit or "", len(master), _rate(len(master),
                                                                                                    *span)))
        finally:
            mdf.close()
    elif fmt.name == "TDMS":
        from nptdms import TdmsFile

        try:
            tdms = TdmsFile.read_metadata(path)
        except Exception as exc:  # noqa: BLE001 - nptdms raises many kinds on a damaged file
            raise InputFileError(f"{path}: not a TDMS file nptdms can read ({type(exc).__name__}: {exc})") from None
        for group in tdms.groups():
            for ch in group.channels():
                dt = _waveform_increment_s(ch.properties.get("wf_increment"))
                if dt is None and ch.properties.get("wf_increment") is not None:
                    info.notes.append(f"{group.name}/{ch.name}: wf_increment "
                                      f"{str(ch.properties.get('wf_increment'))[:40]!r} is no time step in s")
                info.streams.append(StreamInfo(f"{group.name}/{ch.name}", str(ch.properties.get("unit_string", "")),
                                               len(ch), 1.0 / dt if dt else None))
    else:
        info.notes.append(f"a {fmt.name} file is described with its channel map (--channels MAP.yaml)")
    if fmt.arrow:  # CSV, Parquet: their time is a column the map names
        info.notes.append("give --channels MAP.yaml for each channel's samples, span and rate as import reads them")


def _waveform_increment_s(value) -> float | None:
    """A TDMS waveform's ``wf_increment`` as a finite time step > 0 in s, or None."""
    try:
        dt = float(value)
    except (TypeError, ValueError, OverflowError):
        return None
    return dt if math.isfinite(dt) and dt > 0 else None


def _size(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:,} B" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n} B"


def _when(t_ns: int | None) -> str:
    if t_ns is None:
        return "-"
    if abs(t_ns) < 10 ** 17:  # under ~3 years: a time from the start of a run, not a date
        return f"{t_ns * 1e-9:.3f} s"
    try:
        return datetime.datetime.fromtimestamp(t_ns / 1e9, datetime.UTC).isoformat(timespec="milliseconds")
    except (ValueError, OverflowError, OSError):
        return f"{t_ns} ns (beyond the years a date holds: a damaged time)"


__all__ = ["FileInfo", "StreamInfo", "describe"]
