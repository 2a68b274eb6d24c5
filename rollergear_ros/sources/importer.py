"""Data in: any supported source -> one ROS 2 MCAP with the interface's topics.

``rollergear import SRC --out OUT.mcap`` and, behind it, every command that reads recordings
(``replay``, ``calibrate``): a source that is not already an MCAP bag is converted first, so
that one reader (:mod:`recordings.baginfo`) and one estimator see everything.  Sources, by what ``SRC`` is:

* a ROS 2 MCAP file: used as it is;
* a rosbag2 folder (``metadata.yaml``; MCAP or SQLite ``.db3`` storage, split into several
  files or not), a folder of split ``.mcap`` files without metadata, or a single ``.db3``:
  read with ``rosbags``; the input topics are copied message by message (raw CDR, untouched);
* CSV, Parquet, MDF4 or TDMS with a channel map (:mod:`.channelmap`, :mod:`.timeseries`):
  the channels in SI on the motor torque's time base, Float64 topics plus
  ``sensor_msgs/Temperature`` for the oil; the resampling rule and the source go into the
  ``rollergear_import`` metadata record;
* a steady-state table -- a VECTO ``.vtlm``, or CSV/Parquet with a ``format: steady_state`` map
  (:mod:`.tables`): one sample per row, 1 s apart in file order, its input-referred loss ``L``
  carried as an output torque ``T − L·sgn ω`` at an output speed equal to the input speed, so
  that ``(T·ω − T_out·ω_out)/|ω| = L`` whatever ratio the gearbox has; rows at standstill (whose
  loss no power balance carries) are left out and counted.  ``calibrate`` reads tables directly
  as dwell means; this is for ``replay``, ``play`` and the node.

No rclpy import.
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Callable, Iterator, Sequence
from contextlib import closing, contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..recordings.messages import MSG_DEFINITIONS, TopicMap, float64_payloads, temperature_payloads
from ..recordings.bagwriter import BagWriter
from .channelmap import load_channel_map
from ..base.errors import InputFileError, UsageError
from .formats import INPUT_FORMATS, input_format
from ..base.interface import Channel, MessageType, Metadata
from .timeseries import align, read_series

__all__ = ["ImportSummary", "as_mcap", "copy_rosbag2", "import_source", "source_kind"]

IMPORT_METADATA = Metadata.IMPORT
RESAMPLING_RULE = ("paired channels on the motor torque's time stamps: taken as they are where they coincide, "
                   "else linear interpolation between the two neighbouring samples (no extrapolation: NaN "
                   "outside a channel's span); oil temperature at its own time stamps, at most 1 Hz")


@dataclass
class ImportSummary:
    """What an import wrote."""

    source: Path
    kind: str  #: MCAP | rosbag2 | CSV | Parquet | MDF4 | TDMS
    out: Path
    messages: int
    samples: int  #: motor torque messages
    resampled: list[str] = field(default_factory=list)
    topics: dict[str, int] = field(default_factory=dict)  #: topic -> messages copied (rosbag2)
    left_out: int = 0  #: table rows at standstill, not written
    ratio: float | None = None  #: the channel map's ratio, when the output speed was derived from it
    notes: list[str] = field(default_factory=list)  #: what was done to the time base (said in :meth:`text`)

    def text(self, kept: bool = True) -> str:
        """One line; ``kept=False``: imported for the command at hand only (its temporary MCAP unnamed)."""
        how = f"; resampled onto the motor torque's time base: {', '.join(self.resampled)}" if self.resampled else ""
        if self.ratio is not None:
            how += f"; output speed = motor speed / {self.ratio:g} (the channel map's ratio)"
        if self.left_out:
            how += f"; {self.left_out} rows at standstill left out (no power balance carries their loss)"
        elif "table" in self.kind:
            how += "; one sample per row, 1 s apart"
        how += "".join(f"; {note}" for note in self.notes)
        where = f"-> {self.out}" if kept else "(read for this command; `rollergear import` keeps it as MCAP)"
        return (f"imported {self.source} ({self.kind}): {self.samples:,} samples, "
                f"{self.messages:,} messages {where}{how}")


def source_kind(path: str | Path) -> str:
    """The name of ``path``'s format in :data:`~.formats.INPUT_FORMATS` (MCAP, rosbag2, VTLM, CSV, …)."""
    return input_format(path).name


def import_source(src: str | Path, out: str | Path, channels: str | Path | None = None,
                  topics: TopicMap = TopicMap()) -> ImportSummary:
    """Convert ``src`` to the MCAP ``out`` (see the module docstring)."""
    src, out = Path(src), Path(out)
    kind = source_kind(src)
    if kind == "MCAP":
        raise UsageError(f"{src} is already an MCAP recording: replay, calibrate and play read it directly")
    if kind == "rosbag2":
        return _import_rosbag2(src, out, topics)
    if kind == "VTLM":
        return _import_table(src, kind, out, None, topics)
    if channels is None:
        raise UsageError(f"{src}: a {kind} file needs a channel map (--channels MAP.yaml, see docs/interface.md)")
    if load_channel_map(channels).format == "steady_state":
        return _import_table(src, kind, out, channels, topics)
    return _import_timeseries(src, kind, out, channels, topics)


# ------------------------------------------------------------------------------------ rosbag2
def _rosbag2_paths(src: Path) -> list[Path]:
    """What rosbags' AnyReader opens: the bag folder, or each file of a split bag without metadata;
    every storage file checked to be a regular file first (a FIFO would block the reader for ever)."""
    if src.name == "metadata.yaml":
        src = src.parent
    if not src.is_dir():
        files = opened = [src]
    elif (src / "metadata.yaml").exists():
        files, opened = _storage_files(src), [src]
    else:
        files = opened = sorted(src.glob("*.mcap")) or sorted(src.glob("*.db3"))
        if not files:
            raise InputFileError(f"{src}: a folder without metadata.yaml and without .mcap/.db3 files")
    for f in files:
        if not f.is_file():
            raise InputFileError(f"{f}: a storage file of {src} that is "
                                 f"{'missing' if not f.exists() else 'not a regular file'}")
    return opened


def _zstd_errors() -> tuple[type[BaseException], ...]:
    """The error classes of the zstd modules rosbags may decompress with (those installed)."""
    import importlib

    found = []
    for module in ("backports.zstd", "compression.zstd", "zstandard"):
        try:
            found.append(importlib.import_module(module).ZstdError)
        except (ImportError, AttributeError):
            continue
    return tuple(found)


def _storage_files(folder: Path) -> list[Path]:
    """The storage files a rosbag2 folder's ``metadata.yaml`` names (read within bounds: no
    anchors, no YAML bombs)."""
    from ..base.safeyaml import YamlProblem, load

    try:
        meta = load(folder / "metadata.yaml")
    except YamlProblem as exc:
        raise InputFileError(f"{folder}: a damaged rosbag2 metadata.yaml ({exc.message})") from None
    info = meta.get("rosbag2_bagfile_information") if isinstance(meta, dict) else None
    names = info.get("relative_file_paths") if isinstance(info, dict) else None
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise InputFileError(f"{folder / 'metadata.yaml'}: no list of storage files (relative_file_paths)")
    return [folder / n for n in names]


@contextmanager
def rosbag2_reader(src: str | Path) -> Iterator:
    """The rosbags ``AnyReader`` on a rosbag2 bag (a folder, its metadata.yaml, or .mcap/.db3 files),
    opened; what the bag's damage makes rosbags raise comes out as one :class:`InputFileError` line."""
    import sqlite3

    import yaml
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.rosbag2.errors import ReaderError as Rosbag2Error

    src = Path(src)
    try:
        import apsw  # rosbags' SQLite driver, where installed: a damaged .db3 raises its errors

        storage_errors: tuple[type[BaseException], ...] = (sqlite3.DatabaseError, apsw.Error)
    except ImportError:
        storage_errors = (sqlite3.DatabaseError,)
    try:
        reader = AnyReader(_rosbag2_paths(src))
        try:
            reader.open()
        except (TypeError, KeyError, AttributeError, RecursionError) as exc:  # metadata.yaml taken on trust
            raise InputFileError(f"{src}: a damaged rosbag2 metadata.yaml ({type(exc).__name__}: "
                                 f"{str(exc)[:200]})") from None
        with closing(reader):
            yield reader
    except (Rosbag2Error, AnyReaderError, FileNotFoundError, ValueError, yaml.YAMLError, *storage_errors,
            *_zstd_errors()) as exc:  # a "compressed" storage file that is not zstd, too
        reason = " ".join(str(exc).split())
        raise InputFileError(f"{src}: not a rosbag2 bag rosbags can read ({reason})") from None


def rosbag2_messages(reader, topics: set[str] | None = None) -> Iterator[tuple[object, int, bytes]]:
    """``(connection, log time, CDR bytes)`` of every message an open :func:`rosbag2_reader` holds
    (of ``topics`` only, when given), each storage file read by its own topics.

    rosbags pairs a storage file's topics with ``metadata.yaml``'s by name, type *and* offered QoS;
    where the two QoS texts differ (rosbag2 of 2020 wrote a deadline of 0 s to one and of ~68 years
    to the other) its reader yields none of that topic's messages, and a bag reads as empty.  Read
    by the storage's own topics, every message it holds comes (message compression undone); files
    are taken one after the other, in each one's time order."""
    for bag in reader.readers:
        folder = bag.storage
        storages = getattr(folder, "storages", None)
        if storages is None:  # a storage file given as it is: its own topics already
            conns = [c for c in bag.connections if topics is None or c.topic in topics]
            if conns:
                yield from bag.messages(connections=conns)
            continue
        decompress = None
        if bag.compression_mode == "message":
            import zstandard

            decompress = zstandard.ZstdDecompressor().decompress
        for storage in storages:
            conns = [c for c in storage.connections if topics is None or c.topic in topics]
            if not conns:
                continue
            for con, t_ns, raw in storage.messages(conns):
                yield con, t_ns, decompress(raw) if decompress else raw


def _import_rosbag2(src: Path, out: Path, topics: TopicMap) -> ImportSummary:
    wanted = {topics.motor_torque, topics.motor_speed, topics.output_torque, topics.output_speed,
              topics.oil_temperature, topics.joint_states}
    counts: dict[str, int] = {}
    with rosbag2_reader(src) as reader:
        connections = [c for c in reader.connections if c.topic in wanted]
        if not any(c.topic in (topics.motor_torque, topics.joint_states) for c in connections):
            found = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})) or "none"
            raise InputFileError(f"{src}: no input topics {topics.motor_torque} or {topics.joint_states} "
                                 f"(topics: {found})")
        with BagWriter(out, background=True) as bw:  # in log-time order whatever order the storage gives
            bw.add_metadata(IMPORT_METADATA, {"source": str(src), "kind": "rosbag2"})
            for con, t_ns, raw in rosbag2_messages(reader, {c.topic for c in connections}):
                if con.msgtype not in MSG_DEFINITIONS:
                    raise InputFileError(f"{src}: {con.topic} is {con.msgtype}, not an input type "
                                         f"({', '.join(sorted(MSG_DEFINITIONS))})")
                bw.write_raw(con.topic, con.msgtype, t_ns, bytes(raw))
                counts[con.topic] = counts.get(con.topic, 0) + 1
    samples = counts.get(topics.motor_torque, counts.get(topics.joint_states, 0))
    return ImportSummary(src, "rosbag2", out, sum(counts.values()), samples, topics=counts)


def copy_rosbag2(src: str | Path, out: str | Path) -> dict[str, int]:
    """Every topic of a rosbag2 bag (MCAP or SQLite storage, split or not) into one ROS 2 MCAP, in
    log-time order, with the message definitions the bag carries (what ``play`` publishes a rosbag2
    bag from; :func:`import_source` keeps only the estimator's inputs).  Returns topic -> messages."""
    src = Path(src)
    counts: dict[str, int] = {}
    with rosbag2_reader(src) as reader, BagWriter(out, background=True) as bw:
        bw.add_metadata(IMPORT_METADATA, {"source": str(src), "kind": "rosbag2 (every topic)"})
        for con in reader.connections:  # topics without messages are kept (their publishers are made)
            definition = MSG_DEFINITIONS.get(con.msgtype) or getattr(getattr(con, "msgdef", None), "data", "")
            bw.channel(con.topic, con.msgtype, definition)
            counts.setdefault(con.topic, 0)
        for con, t_ns, raw in rosbag2_messages(reader):
            bw.write_raw(con.topic, con.msgtype, t_ns, bytes(raw))
            counts[con.topic] = counts.get(con.topic, 0) + 1
    return counts


# ------------------------------------------------------------------------------------ time series
def _import_timeseries(src: Path, kind: str, out: Path, channels: str | Path, topics: TopicMap) -> ImportSummary:
    from .arrowstream import aligned_batches

    cmap = load_channel_map(channels)
    notes: list[str] = []
    # CSV and Parquet in bounded batches (a small Parquet file can hold 30 M rows); MDF4 and TDMS whole,
    # as their libraries read channels
    parts = aligned_batches(src, cmap, notes=notes) if INPUT_FORMATS[kind].arrow else \
        iter([align(read_series(src, cmap, notes))])
    ratio_used: list[float] = []

    def with_output_speed(aligned):
        """The map's ratio reaches the measured loss as an output speed (a replay of the MCAP reads no map)."""
        values = aligned.values
        if cmap.ratio is not None and Channel.OUTPUT_SPEED not in values and Channel.OUTPUT_TORQUE in values:
            values[Channel.OUTPUT_SPEED] = values[Channel.MOTOR_SPEED] / cmap.ratio
            ratio_used[:] = [cmap.ratio]
        return aligned

    resampled: list[str] = []

    def metadata() -> dict[str, str]:
        ratio = ratio_used[0] if ratio_used else None
        return {"source": str(src), "kind": kind, "channel_map": Path(channels).read_text(encoding="utf-8"),
                "resampling": RESAMPLING_RULE, "resampled": json.dumps(resampled),
                "output_speed": "" if ratio is None else f"motor_speed / {ratio!r} (the channel map's ratio)",
                "time": "; ".join(notes)}

    written, samples = write_aligned_parts(map(with_output_speed, parts), out, topics, metadata, resampled)
    return ImportSummary(src, kind, out, written, samples, resampled, ratio=ratio_used[0] if ratio_used else None,
                         notes=notes)


def write_aligned(aligned, out: Path, topics: TopicMap = TopicMap(), metadata: dict[str, str] | None = None) -> int:
    """Write aligned channels (:func:`~.timeseries.align`) to the MCAP ``out``: the paired channels as
    Float64 topics interleaved sample by sample, as a recorder stores them, the oil temperature at
    its own times; ``metadata``: the ``rollergear_import`` record.  Returns how many messages."""
    written, _ = write_aligned_parts([aligned], out, topics, (lambda: metadata) if metadata is not None else None)
    return written


def write_aligned_parts(parts, out: Path, topics: TopicMap = TopicMap(),
                        metadata: Callable[[], dict[str, str] | None] | None = None,
                        resampled: list[str] | None = None) -> tuple[int, int]:
    """:func:`write_aligned` of consecutive parts of one recording (:func:`~.arrowstream.aligned_batches`);
    ``metadata()`` gives the ``rollergear_import`` record once every part is written (it may say what
    they showed), ``resampled`` collects the channels any part resampled.  Returns (messages, samples)."""
    topic_of = topics.float64_inputs()
    written = samples = 0
    with BagWriter(out, time_ordered=False, background=True) as bw:
        for aligned in parts:
            names = [c for c in Channel.PAIRED if c in aligned.values]
            n, k = len(aligned.t_ns), len(names)
            if resampled is not None:
                resampled[:] = [c for c in Channel.PAIRED if c in resampled or c in aligned.resampled]
            payloads = float64_payloads(np.stack([aligned.values[c] for c in names], axis=1).ravel())
            float_topics = [(topic_of[c], MessageType.FLOAT64, None) for c in names]
            temp = aligned.temperature
            _write_in_time_order(bw, topics, _FloatMessages(float_topics, np.tile(np.arange(k), n),
                                                            np.repeat(aligned.t_ns, k), payloads),
                                 ([], []) if temp is None else (temp.t_ns, temp.values))
            written += n * k + (0 if temp is None else len(temp.t_ns))
            samples += n
        record = metadata() if metadata is not None else None
        if record is not None:
            bw.add_metadata(IMPORT_METADATA, record)
    return written, samples


@dataclass(frozen=True)
class _FloatMessages:
    """Float64 messages in time order: message i is on topic ``topics[which[i]]`` at ``t_ns[i]``."""

    topics: list  #: (topic, type, None) as :meth:`BagWriter.write_fixed_mixed` takes them
    which: np.ndarray
    t_ns: np.ndarray
    payloads: np.ndarray


def _write_in_time_order(bw: BagWriter, topics: TopicMap, floats: _FloatMessages,
                         temperatures: tuple[np.ndarray, np.ndarray]) -> None:
    """Float64 messages and oil temperatures ``(times, °C)`` in log-time order across topics: each
    temperature before the samples at and after its time (the writer takes them as they come:
    ``bw`` need not hold anything back)."""
    float_topics, which, t_ns, payloads = floats.topics, floats.which, floats.t_ns, floats.payloads
    temp_t = np.asarray(temperatures[0], dtype=np.int64)
    temp_rows = temperature_payloads(temp_t, np.asarray(temperatures[1], dtype=np.float64))
    cuts = np.searchsorted(t_ns, temp_t, side="left").tolist()
    done = 0
    for t, upto, row in zip(temp_t.tolist(), cuts, temp_rows):
        if upto > done:
            bw.write_fixed_mixed(float_topics, which[done:upto], t_ns[done:upto], payloads[done:upto])
            done = upto
        bw.write_raw(topics.oil_temperature, MessageType.TEMPERATURE, t, row.tobytes())
    if len(t_ns) > done:
        bw.write_fixed_mixed(float_topics, which[done:], t_ns[done:], payloads[done:])


# ------------------------------------------------------------------------------------ steady-state tables
TABLE_PERIOD_NS = 1_000_000_000  #: one row per second
TABLE_START_NS = 1_000_000_000  #: the first row's log time


def _import_table(src: Path, kind: str, out: Path, channels: str | Path | None, topics: TopicMap) -> ImportSummary:
    from ..core.model import rotation_sign
    from .tables import read_table

    cmap = load_channel_map(channels) if channels is not None else None
    table = read_table(src, cmap)
    if table.group is not None and len(set(table.group.tolist())) > 1:
        raise UsageError(f"{src}: {len(set(table.group.tolist()))} gearbox states in its group column; a recording "
                         "holds one: calibrate reads the table with its states apart")
    moving = table.speed_rad_s != 0
    w, tq, loss = table.speed_rad_s[moving], table.torque_nm[moving], table.loss_nm[moving]
    standstill = int(np.count_nonzero(~moving))
    n = len(w)
    if n == 0:
        raise InputFileError(f"{src}: every row is at standstill: no loss a recording can carry")
    t_rows = TABLE_START_NS + np.arange(n, dtype=np.int64) * TABLE_PERIOD_NS
    columns = [tq, w, tq - loss * rotation_sign(w, tq), w]  # output torque and speed: input-referred
    names = [Channel.MOTOR_TORQUE, Channel.MOTOR_SPEED, Channel.OUTPUT_TORQUE, Channel.OUTPUT_SPEED]
    topic_of = topics.float64_inputs()
    payloads = float64_payloads(np.stack(columns, axis=1).ravel())
    which = np.tile(np.arange(len(names)), n)
    theta = table.temperature_c[moving]
    with BagWriter(out, time_ordered=False, background=True) as bw:
        bw.add_metadata(IMPORT_METADATA, {
            "source": str(src), "kind": f"{kind} steady-state table",
            "channel_map": "" if channels is None else Path(channels).read_text(encoding="utf-8"),
            "rows": f"one sample per row, {TABLE_PERIOD_NS * 1e-9:g} s apart in file order; the input-referred "
                    "loss L as output torque T - L*sgn(w) at an output speed equal to the input speed",
            "standstill_rows_left_out": str(standstill), Metadata.IMPORT_ROWS: "true",
            Metadata.IMPORT_READINGS: "true" if table.readings else "false",
            Metadata.IMPORT_RATIO: "" if table.ratio is None else repr(float(table.ratio))})
        have = np.isfinite(theta)
        _write_in_time_order(bw, topics, _FloatMessages([(topic_of[c], MessageType.FLOAT64, None) for c in names],
                                                        which, np.repeat(t_rows, len(names)), payloads),
                             (t_rows[have], theta[have]))
    written = n * len(names) + int(np.count_nonzero(np.isfinite(theta)))
    return ImportSummary(src, f"{kind} steady-state table", out, written, n, left_out=standstill)


@contextmanager
def as_mcap(sources: Sequence[str | Path], channels: str | Path | None = None,
            topics: TopicMap = TopicMap(), note: Callable[[str], None] | None = None) -> Iterator[list[Path]]:
    """MCAP paths for ``sources``: MCAP files as they are, the others imported into a temporary
    folder that is removed afterwards (``note`` is told about each import)."""
    kinds = [source_kind(s) for s in sources]
    if all(k == "MCAP" for k in kinds):
        yield [Path(s) for s in sources]
        return
    with tempfile.TemporaryDirectory(prefix="rollergear_import_") as tmp:
        paths = []
        for i, (src, kind) in enumerate(zip(sources, kinds)):
            if kind == "MCAP":
                paths.append(Path(src))
                continue
            summary = import_source(src, Path(tmp) / f"{i}_{Path(src).stem}.mcap", channels, topics)
            if note:
                note(summary.text(kept=False))
            paths.append(summary.out)
        yield paths
