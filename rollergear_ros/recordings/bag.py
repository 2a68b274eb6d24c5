"""ROS 2 MCAP bags without ROS: topic discovery, batched reading, fast Float64 decoding, writing.

Bags follow ``interface.md``: MCAP, ``ros2`` profile, ``ros2msg`` schemas named like
``std_msgs/msg/Float64``, ``cdr`` messages — so ``ros2 bag``, Foxglove and ``rosbags`` open them.
Float64 payloads are decoded with numpy (4-byte CDR encapsulation header + one float64); other
types are decoded and encoded by ``rosbags`` (:func:`decoder_for`, :func:`encoder_for`).  No rclpy import here.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Callable, Mapping
from functools import lru_cache
from typing import Any
from collections.abc import Iterator

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.well_known import MessageEncoding, SchemaEncoding

from ..base.errors import BagError
from ..base.interface import NAMESPACE, Channel, MessageType, Metadata, Topic
from ..base.output_channels import OUTPUT_CHANNELS

_HEADER_DEF = """================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""

#: ros2msg schema texts (with dependencies, as rosbag2 writes them)
MSG_DEFINITIONS: dict[str, str] = {
    MessageType.FLOAT64: "float64 data\n",
    MessageType.TEMPERATURE: "std_msgs/Header header\nfloat64 temperature\nfloat64 variance\n" + _HEADER_DEF,
    MessageType.JOINT_STATE: (
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
        "float64[] effort\n" + _HEADER_DEF
    ),
    MessageType.CLOCK: ("builtin_interfaces/Time clock\n" + "=" * 80 + "\n"
                        "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"),
    # as rosbags' type store generates it (with the level constants and the nested KeyValue)
    MessageType.DIAGNOSTIC_STATUS: (
        "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\nbyte level\nstring name\nstring message\n"
        "string hardware_id\ndiagnostic_msgs/KeyValue[] values\n" + "=" * 80 + "\n"
        "MSG: diagnostic_msgs/KeyValue\nstring key\nstring value\n"),
    # as rosbags' type store generates them (with their nested types)
    MessageType.DIAGNOSTIC_ARRAY: (
        "std_msgs/Header header\ndiagnostic_msgs/DiagnosticStatus[] status\n" + _HEADER_DEF + "=" * 80 + "\n"
        "MSG: diagnostic_msgs/DiagnosticStatus\nbyte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\nbyte level\n"
        "string name\nstring message\nstring hardware_id\ndiagnostic_msgs/KeyValue[] values\n" + "=" * 80 + "\n"
        "MSG: diagnostic_msgs/KeyValue\nstring key\nstring value\n"),
    MessageType.FLOAT64_MULTI_ARRAY: (
        "std_msgs/MultiArrayLayout layout\nfloat64[] data\n" + "=" * 80 + "\n"
        "MSG: std_msgs/MultiArrayLayout\nstd_msgs/MultiArrayDimension[] dim\nuint32 data_offset\n" + "=" * 80 + "\n"
        "MSG: std_msgs/MultiArrayDimension\nstring label\nuint32 size\nuint32 stride\n"),
    # as rosbags' type store generates it (rcl_interfaces/msg/ParameterEvent with its nested types)
    MessageType.PARAMETER_EVENT: (
        "builtin_interfaces/Time stamp\n"
        "string node\n"
        "rcl_interfaces/Parameter[] new_parameters\n"
        "rcl_interfaces/Parameter[] changed_parameters\n"
        "rcl_interfaces/Parameter[] deleted_parameters\n"
        "================================================================================\n"
        "MSG: builtin_interfaces/Time\n"
        "int32 sec\n"
        "uint32 nanosec\n"
        "================================================================================\n"
        "MSG: rcl_interfaces/Parameter\n"
        "string name\n"
        "rcl_interfaces/ParameterValue value\n"
        "================================================================================\n"
        "MSG: rcl_interfaces/ParameterValue\n"
        "uint8 type\n"
        "bool bool_value\n"
        "int64 integer_value\n"
        "float64 double_value\n"
        "string string_value\n"
        "byte[] byte_array_value\n"
        "bool[] bool_array_value\n"
        "int64[] integer_array_value\n"
        "float64[] double_array_value\n"
        "string[] string_array_value\n"
    ),
}

CDR_LE_HEADER = b"\x00\x01\x00\x00"


@dataclass(frozen=True)
class TopicMap:
    """Names of the input and output topics in a bag (defaults: ``interface.md``)."""

    motor_torque: str = f"{NAMESPACE}/{Topic.MOTOR_TORQUE}"
    motor_speed: str = f"{NAMESPACE}/{Topic.MOTOR_SPEED}"
    output_torque: str = f"{NAMESPACE}/{Topic.OUTPUT_TORQUE}"
    output_speed: str = f"{NAMESPACE}/{Topic.OUTPUT_SPEED}"
    oil_temperature: str = f"{NAMESPACE}/{Topic.OIL_TEMPERATURE}"
    joint_states: str = Topic.JOINT_STATES
    input_joint: str = "motor"
    output_joint: str = "output"
    # the output channels' topics (:mod:`base.output_channels`), a field each so that ``--topic-<name>`` moves it
    loss_torque: str = OUTPUT_CHANNELS["loss_torque"].absolute_topic()
    loss_power: str = OUTPUT_CHANNELS["loss_power"].absolute_topic()
    efficiency: str = OUTPUT_CHANNELS["efficiency"].absolute_topic()
    residual_torque: str = OUTPUT_CHANNELS["residual_torque"].absolute_topic()
    loss_estimate: str = OUTPUT_CHANNELS["loss_estimate"].absolute_topic()

    def output(self, name: str) -> str:
        """The topic of output channel ``name``: its field here, else (a channel without one) the
        table's topic under the node's namespace."""
        topic = getattr(self, name, None)
        return topic if isinstance(topic, str) else OUTPUT_CHANNELS[name].absolute_topic()

    def float64_inputs(self) -> dict[str, str]:
        """Estimator channel name -> topic, for the Float64 inputs."""
        return {
            Channel.MOTOR_TORQUE: self.motor_torque,
            Channel.MOTOR_SPEED: self.motor_speed,
            Channel.OUTPUT_TORQUE: self.output_torque,
            Channel.OUTPUT_SPEED: self.output_speed,
        }


# ------------------------------------------------------------------------------------ decoding
def cdr_problem(payload: bytes) -> str | None:
    """Why a payload does not start with the plain CDR encapsulation ROS 2 writes (None: it does)."""
    if len(payload) < 4 or payload[0] != 0 or payload[1] > 1:
        return f"CDR encapsulation {payload[:2].hex()} is not plain CDR (0000 or 0001)"
    return None


def float64_problem(payload: bytes) -> str | None:
    """Why ``payload`` is not a CDR ``std_msgs/msg/Float64`` (None: it is one)."""
    if len(payload) < 12:
        return f"payload of {len(payload)} bytes (a Float64 message has 12)"
    return cdr_problem(payload)


def decode_float64(payloads: list[bytes], problems: list[tuple[int, str]] | None = None) -> np.ndarray:
    """Decode Float64 CDR payloads (4-byte encapsulation + float64) to an array, vectorised.

    A malformed payload (:func:`float64_problem`) raises :class:`BagError`; when ``problems`` is
    given it decodes to NaN instead and ``(index, reason)`` is appended.
    """
    n = len(payloads)
    if n == 0:
        return np.empty(0)
    blob = b"".join(payloads)
    if len(blob) == 12 * n:
        raw = np.frombuffer(blob, dtype=np.uint8).reshape(n, 12)
        if np.all(raw[:, 1] == 1) and not raw[:, 0].any():  # little endian CDR
            return raw[:, 4:].copy().view("<f8").ravel()
    # mixed, padded or malformed payloads: one at a time
    out = np.empty(n)
    for i, p in enumerate(payloads):
        problem = float64_problem(p)
        if problem is None:
            out[i] = struct.unpack("<d" if p[1] == 1 else ">d", p[4:12])[0]
        elif problems is None:
            raise BagError(f"malformed Float64 message: {problem}")
        else:
            out[i] = np.nan
            problems.append((i, problem))
    return out


def float64_payloads(values: np.ndarray) -> np.ndarray:
    """Float64 CDR payloads (little endian) as the rows of an ``(n, 12)`` uint8 array."""
    v = np.ascontiguousarray(values, dtype="<f8")
    buf = np.empty((len(v), 12), dtype=np.uint8)
    buf[:, :4] = np.frombuffer(CDR_LE_HEADER, dtype=np.uint8)
    buf[:, 4:] = v.view(np.uint8).reshape(-1, 8)
    return buf


def encode_float64(values: np.ndarray) -> list[bytes]:
    """Encode floats as Float64 CDR payloads (little endian), one ``bytes`` each."""
    raw = float64_payloads(values).tobytes()
    return [raw[i : i + 12] for i in range(0, len(raw), 12)]


_decoders: dict[tuple[str, str | None], Any] = {}


def decoder_for(type_name: str, schema_text: str | None = None):
    """CDR decoder (bytes -> message; fields as attributes, numeric sequences as numpy arrays) for a
    ROS 2 message type, by ``rosbags`` -- the library that encodes too (:func:`encoder_for`): from
    the bag's own ros2msg definition when given (with its dependencies, as rosbag2 writes them),
    else from the Jazzy type store."""
    key = (type_name, schema_text)
    if key not in _decoders:
        store = _typestore() if schema_text is None else _store_of(type_name, schema_text)
        deserialize = store.deserialize_cdr
        _decoders[key] = lambda payload: deserialize(payload, type_name)
    return _decoders[key]


def _store_of(type_name: str, schema_text: str):
    """A type store holding the types of a bag's ros2msg schema text; the Jazzy store when the text
    cannot be read on its own (dependencies left out) and Jazzy knows the type."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    try:
        store = get_typestore(Stores.EMPTY)
        store.register(get_types_from_msg(schema_text, type_name))
        store.get_msgdef(type_name)  # its code, with every type it uses: raises when one is missing
        return store
    except Exception:  # noqa: BLE001 - rosbags raises assorted errors on a definition it cannot read
        pass
    if type_name in _typestore().types:
        return _typestore()
    raise BagError(f"the bag's definition of {type_name} cannot be read")


@lru_cache(maxsize=1)
def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def _message(store, type_name: str, value: Any):
    """A ``rosbags`` message of ``type_name`` from a dict (nested dicts for nested messages, lists
    for sequences; missing fields take their zero value)."""
    from rosbags.interfaces import Nodetype

    fields = {}
    for name, (kind, arg) in store.fielddefs[type_name][1]:
        v = value.get(name) if isinstance(value, Mapping) else None
        if kind == Nodetype.NAME:
            fields[name] = _message(store, arg, v or {})
        elif kind in (Nodetype.SEQUENCE, Nodetype.ARRAY):
            (sub_kind, sub_arg), _size = arg
            if sub_kind == Nodetype.NAME:
                fields[name] = [_message(store, sub_arg, x) for x in v or []]
            elif sub_arg[0] in ("string", "wstring"):
                fields[name] = list(v or [])
            else:
                fields[name] = np.asarray(v if v is not None else [], dtype=_NUMPY_TYPE.get(sub_arg[0], sub_arg[0]))
        else:  # a base type
            fields[name] = v if v is not None else ("" if arg[0] in ("string", "wstring") else 0)
    return store.types[type_name](**fields)


_NUMPY_TYPE = {"byte": "uint8", "char": "uint8", "bool": "bool", "octet": "uint8"}


def encoder_for(type_name: str):
    """CDR encoder (message dict -> bytes, little endian) for a ROS 2 message type, by ``rosbags``'
    type store for Jazzy."""
    store = _typestore()

    def encode(message: Mapping[str, Any]) -> bytes:
        return bytes(store.serialize_cdr(_message(store, type_name, message), type_name))

    return encode


@lru_cache(maxsize=4)
def _temperature_template(frame_id: str) -> tuple[bytes, int, int]:
    """A ``sensor_msgs/Temperature`` serialised by the typestore, and where its stamp and its two
    values are (found by markers, not assumed)."""
    encode = encoder_for(MessageType.TEMPERATURE)
    sec, nanosec, temp, var = 0x12345678, 0x1ABCDEF0, 1.0 + 1.0 / 3.0, 1.0 + 1.0 / 7.0
    marked = encode({"header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame_id},
                     "temperature": temp, "variance": var})
    return marked, marked.index(struct.pack("<iI", sec, nanosec)), marked.index(struct.pack("<dd", temp, var))


def temperature_payloads(t_ns: np.ndarray, temperature_c: np.ndarray, variance: float = 0.0,
                         frame_id: str = "oil") -> np.ndarray:
    """``sensor_msgs/Temperature`` CDR payloads (little endian), stamped ``t_ns``, as the rows of a
    uint8 array (a template the typestore serialised, patched with numpy)."""
    template, stamp_at, values_at = _temperature_template(frame_id)
    t = np.asarray(t_ns, dtype=np.int64)
    n = len(t)
    rows = np.tile(np.frombuffer(template, dtype=np.uint8), (n, 1))
    sec, nanosec = np.divmod(t, 1_000_000_000)
    if n and (sec.min() < -(2**31) or sec.max() > 2**31 - 1):
        raise BagError(f"a time of {int(sec.max() if sec.max() > 0 else sec.min())} s does not fit a ROS 2 header "
                       "stamp (int32 seconds)")
    stamps = np.empty(n, dtype=[("sec", "<i4"), ("nanosec", "<u4")])
    stamps["sec"], stamps["nanosec"] = sec, nanosec
    rows[:, stamp_at:stamp_at + 8] = stamps.view(np.uint8).reshape(n, 8)
    values = np.empty((n, 2), dtype="<f8")
    values[:, 0], values[:, 1] = temperature_c, variance
    rows[:, values_at:values_at + 16] = values.view(np.uint8).reshape(n, 16)
    return rows


def stamp(t_ns: int) -> dict[str, int]:
    return {"sec": int(t_ns // 1_000_000_000), "nanosec": int(t_ns % 1_000_000_000)}


# ------------------------------------------------------------------------------------ reading
@dataclass
class BagInfo:
    """What a bag holds: topics with types and counts; whether its index (summary) is intact."""

    path: Path
    topics: dict[str, str]  #: topic -> schema (type) name
    counts: dict[str, int]  #: topic -> message count (None-free; counted when no summary)
    schema_texts: dict[str, str] = field(default_factory=dict)  #: type -> ros2msg text
    indexed: bool = True
    truncated: bool = False
    bytes_total: int = 0
    bytes_readable: int = 0
    start_ns: int = 0
    end_ns: int = 0
    problem: str = ""

    @property
    def message_count(self) -> int:
        return sum(self.counts.values())

    def describe_topics(self) -> str:
        return ", ".join(f"{t} [{ty}]" for t, ty in sorted(self.topics.items())) or "no topics"


def _check_mcap(path: Path) -> None:
    if not path.exists():
        raise BagError(f"{path} does not exist")
    if path.is_dir():
        mcaps = sorted(path.glob("*.mcap"))
        raise BagError(
            f"{path} is a directory; pass the .mcap file inside it" + (f" (e.g. {mcaps[0]})" if mcaps else "")
        )
    if not path.is_file():  # a FIFO or a device would block or never end
        raise BagError(f"{path} is not a regular file")
    with path.open("rb") as fh:
        magic = fh.read(8)
    if magic != b"\x89MCAP0\r\n":
        raise BagError(f"{path} is not an MCAP file (it does not begin with MCAP's magic bytes)")


#: metadata record the node writes into its recordings: how it paired the inputs it recorded
RECORDING_METADATA = Metadata.RECORDING
#: the metadata record rosbag2's MCAP storage plugin writes (key ``serialized_metadata``: its YAML)
ROSBAG2_METADATA = "rosbag2"


def offered_qos_yaml(reliable: bool, depth: int, transient_local: bool = False) -> str:
    """One publisher's QoS as rosbag2 stores it in ``offered_qos_profiles`` (rmw enum values: history
    1 keep last, reliability 1 reliable / 2 best effort, durability 1 transient local / 2 volatile;
    infinite deadline, lifespan and lease as 0, automatic liveliness)."""
    zero = "\n    sec: 0\n    nsec: 0"
    return (f"- history: 1\n  depth: {depth}\n  reliability: {1 if reliable else 2}\n"
            f"  durability: {1 if transient_local else 2}\n  deadline:{zero}\n  lifespan:{zero}\n"
            f"  liveliness: 1\n  liveliness_lease_duration:{zero}\n  avoid_ros_namespace_conventions: false")


def read_metadata(path: str | Path, name: str) -> dict[str, str] | None:
    """The bag's MCAP metadata record ``name`` (string key/values), or None when it has none or
    it cannot be read (a recording without its summary)."""
    try:
        with Path(path).open("rb") as fh:
            for md in make_reader(fh).iter_metadata():
                if md.name == name:
                    return dict(md.metadata)
    except SUMMARY_ERRORS:
        return None
    return None


#: what the ``mcap`` library raises on a damaged summary (lengths, offsets and ids it trusts)
SUMMARY_ERRORS = (McapError, struct.error, ValueError, EOFError, KeyError, IndexError, OSError, OverflowError)


def _from_summary(path: Path, size: int, summary) -> BagInfo:
    """The bag's topics, types and counts from its summary (KeyError when the summary contradicts itself)."""
    topics = {c.topic: (summary.schemas[c.schema_id].name if c.schema_id else "") for c in summary.channels.values()}
    texts = {s.name: s.data.decode(errors="replace") for s in summary.schemas.values()}
    enc = {s.encoding for s in summary.schemas.values()} | {c.message_encoding for c in summary.channels.values()}
    counts: dict[str, int] = {}
    for cid, n in summary.statistics.channel_message_counts.items():
        topic = summary.channels[cid].topic
        counts[topic] = counts.get(topic, 0) + n
    info = BagInfo(path, topics, counts, texts, True, False, size, size, summary.statistics.message_start_time,
                   summary.statistics.message_end_time)
    _check_encodings(info, enc)
    return info


def inspect_bag(path: str | Path) -> BagInfo:
    """Read the bag's summary; without a usable one (a recording cut by a crash, a damaged
    summary) scan what is readable."""
    path = Path(path)
    _check_mcap(path)
    size = path.stat().st_size
    with path.open("rb") as fh:
        try:
            summary = make_reader(fh).get_summary()
            if summary is not None and summary.statistics is not None:
                return _from_summary(path, size, summary)
        except SUMMARY_ERRORS:  # OSError: shorter than a footer
            pass
    return _scan(path, size)


def median_period_s(path: str | Path, topic: str, max_messages: int = 2000) -> float | None:
    """Median log-time interval between consecutive ``topic`` messages, over its first ``max_messages``
    (``None`` with fewer than two distinct times)."""
    from .fastmcap import ReadState, iter_message_arrays

    state = ReadState()
    parts, n = [], 0
    chunks = iter_message_arrays(path, state)
    try:
        for arrays in chunks:
            ids = [cid for cid, (name, _sid, _enc) in state.channels.items() if name == topic]
            t = arrays.log_time[np.isin(arrays.channel, ids)]
            parts.append(t)
            n += len(t)
            if n >= max_messages:
                break
    finally:
        chunks.close()
    d = np.diff(np.sort(np.concatenate(parts + [np.empty(0, dtype=np.int64)])))
    d = d[d > 0]
    return float(np.median(d)) * 1e-9 if len(d) else None


def _check_encodings(info: BagInfo, encodings: set[str]) -> None:
    foreign = encodings - {SchemaEncoding.ROS2, MessageEncoding.CDR, ""}
    if foreign:
        raise BagError(
            f"{info.path} is not a ROS 2 bag: it uses encodings {', '.join(sorted(foreign))} "
            "(expected ros2msg schemas and cdr messages)"
        )


def _scan(path: Path, size: int) -> BagInfo:
    """Linear scan of a bag without summary: channels, counts, and how far it is readable."""
    from .fastmcap import ReadState, iter_message_arrays

    state = ReadState()
    counts_by_id: dict[int, int] = {}
    start = end = None
    for arrays in iter_message_arrays(path, state):
        ids, n = np.unique(arrays.channel, return_counts=True)
        for cid, k in zip(ids.tolist(), n.tolist()):
            counts_by_id[cid] = counts_by_id.get(cid, 0) + k
        lo, hi = int(arrays.log_time.min()), int(arrays.log_time.max())
        start = lo if start is None else min(start, lo)
        end = hi if end is None else max(end, hi)
    schema_names = {sid: name for sid, (name, _enc, _data) in state.schemas.items()}
    topics = {topic: schema_names.get(sid, "") for topic, sid, _enc in state.channels.values()}
    texts = {name: data.decode(errors="replace") for name, _enc, data in state.schemas.values()}
    counts: dict[str, int] = {}
    for cid, k in counts_by_id.items():
        topic = state.channels[cid][0] if cid in state.channels else "?"
        counts[topic] = counts.get(topic, 0) + k
    encodings = {enc for _n, enc, _d in state.schemas.values()} | {enc for _t, _s, enc in state.channels.values()}
    info = BagInfo(
        path,
        topics,
        counts,
        texts,
        False,
        state.truncated,
        size,
        min(max(state.bytes_read, 8), size),
        start or 0,
        end or 0,
        state.problem,
    )
    _check_encodings(info, encodings)
    return info


@dataclass
class RawBatch:
    """A batch of raw messages in file order: topic, log time, payload."""

    topics: list[str]
    log_time_ns: list[int]
    data: list[bytes]


def iter_raw_batches(info: BagInfo, topics: set[str] | None, batch_size: int = 50_000, state=None
                     ) -> Iterator[RawBatch]:
    """Yield batches of raw messages (file order, which for recorders is time order within chunks).

    Reads with :func:`~.fastmcap.iter_message_arrays`: damaged spans are skipped and
    listed in ``state.damaged`` (a :class:`~.fastmcap.ReadState`).
    """
    from .fastmcap import ReadState, iter_message_arrays

    state = state if state is not None else ReadState()
    tp: list[str] = []
    lt: list[int] = []
    dd: list[bytes] = []
    for arrays in iter_message_arrays(info.path, state):
        names = {cid: topic for cid, (topic, _sid, _enc) in state.channels.items()}
        for i, (cid, t) in enumerate(zip(arrays.channel.tolist(), arrays.log_time.tolist())):
            topic = names.get(cid)
            if topic is None or (topics is not None and topic not in topics):
                continue
            tp.append(topic)
            lt.append(t)
            dd.append(arrays.payload(i))
        if len(tp) >= batch_size:
            yield RawBatch(tp, lt, dd)
            tp, lt, dd = [], [], []
    if tp:
        yield RawBatch(tp, lt, dd)


# ------------------------------------------------------------------------------------ writing
_MAX_JOBS = 2  #: a background writer's jobs in flight before the caller waits for the oldest


class BagWriter:
    """Writes a ROS 2 MCAP bag (``ros2`` profile, ``ros2msg`` schemas, ``cdr`` messages).

    Whole series of equal-sized messages (Float64 outputs, copied inputs) are added with numpy
    (:class:`~.mcapwriter.ChunkedMcapWriter`).  Used as a context manager; :meth:`close`
    (also on error or interrupt) writes the summary and footer, so everything added so far stays
    readable.  ``time_ordered``: messages are held back and written in log-time order across topics
    (:class:`~.mcapwriter.TimeOrderBuffer`; :meth:`release` writes what is older than
    a watermark, :meth:`close` the rest), as streaming readers need; a recorder that writes as
    messages come passes False.  ``offered_qos``: topic -> the QoS profiles its publisher offers
    (:func:`offered_qos_yaml`), stored as rosbag2 does.  :meth:`close` adds rosbag2's own metadata
    record (``rosbag2``: ``serialized_metadata``), so ``ros2 bag info`` shows topics, counts and QoS.
    ``background``: full chunks are compressed and written by a second thread, and a time-ordered
    writer lays out its records in a third (bulk writers: the caller goes on while what it handed
    over is written; an error there is raised by a later call or :meth:`close`).
    ``replace_atomically`` (default): written beside ``path`` and renamed onto it when closed
    without an error (:mod:`~base.atomic`); a live recorder passes False and ``durable=True``: a
    hidden file until :meth:`publish`, whole up to its last chunk whenever it is killed
    (:class:`~.mcapwriter.ChunkedMcapWriter`).
    """

    def __init__(self, path: str | Path, chunk_size: int = 1024 * 1024, time_ordered: bool = True,
                 offered_qos: Mapping[str, str] | None = None, background: bool = False,
                 replace_atomically: bool = True, durable: bool = False) -> None:
        from .mcapwriter import ChunkedMcapWriter, TimeOrderBuffer

        self.path = Path(path)
        self._writer = ChunkedMcapWriter(self.path, chunk_size=chunk_size, background=background,
                                         replace_atomically=replace_atomically, durable=durable)
        self._held = TimeOrderBuffer(self._writer) if time_ordered else None
        self._sink = self._held if time_ordered else self._writer
        self._schema_ids: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._types: dict[str, str] = {}
        self._offered_qos = dict(offered_qos or {})
        self.closed = False
        # background + time_ordered: what touches the file (channels, held messages, metadata) runs
        # on one builder thread, in the order called; calls until the next release go as one job
        self._builder = None
        self._ops: list[Callable[[], None]] = []
        self._jobs: list = []
        self._failed = False
        self._error: BaseException | None = None  # the builder's first error
        if background and time_ordered:
            from concurrent.futures import ThreadPoolExecutor

            self._builder = ThreadPoolExecutor(1, thread_name_prefix="mcap-layout")

    def _apply(self, op: Callable[[], None]) -> None:
        """Run ``op`` (which touches the file) now, or with the builder thread's next job."""
        if self._builder is None:
            op()
        else:
            self._ops.append(op)

    def _submit(self, wait_beyond: int = _MAX_JOBS) -> None:
        """Hand the calls made since the last job to the builder thread; raise the error of a job that
        failed; wait while more than ``wait_beyond`` jobs are in flight (memory stays bounded)."""
        if self._ops:
            ops, self._ops = self._ops, []
            self._jobs.append(self._builder.submit(self._run, ops))
        while self._jobs and (len(self._jobs) > wait_beyond or self._jobs[0].done()):
            self._jobs.pop(0).result()

    def _run(self, ops: list[Callable[[], None]]) -> None:
        if self._failed:  # the file's state after a failed job is no base for the next
            return
        try:
            for op in ops:
                op()
        except BaseException as exc:
            self._failed, self._error = True, exc
            raise

    def channel(self, topic: str, type_name: str, schema_text: str | None = None) -> int:
        """Register (once) a topic of a ROS 2 type; returns its channel id."""
        if topic in self._channels:
            return self._channels[topic]
        if type_name not in self._schema_ids:
            text = schema_text if schema_text is not None else MSG_DEFINITIONS[type_name]
            self._schema_ids[type_name] = self._writer.register_schema(type_name, SchemaEncoding.ROS2, text.encode())
        cid = self._writer.register_channel(topic, MessageEncoding.CDR, self._schema_ids[type_name],
                                            metadata={"offered_qos_profiles": self._offered_qos.get(topic, "")})
        self._channels[topic] = cid
        self._types[topic] = type_name
        return cid

    def release(self, up_to_ns: int) -> None:
        """``time_ordered``: write the held messages whose log time is at most ``up_to_ns``."""
        if self._held is None:
            return
        self._apply(lambda: self._held.release(up_to_ns))
        if self._builder is not None:
            self._submit()

    def write_raw(
        self, topic: str, type_name: str, log_time_ns: int, data: bytes, schema_text: str | None = None,
        publish_time_ns: int | None = None,
    ) -> None:
        """One serialized message (``publish_time_ns``: when its publisher sent it; None: its log time)."""
        log_time_ns = int(log_time_ns)
        self._apply(lambda: self._sink.add_message(self.channel(topic, type_name, schema_text), log_time_ns, data,
                                                   publish_time_ns))

    def write_message(self, topic: str, type_name: str, log_time_ns: int, message: dict) -> None:
        """Encode a message dict with the type's CDR encoder and write it."""
        self.write_raw(topic, type_name, log_time_ns, encoder_for(type_name)(message))

    def write_fixed(
        self, topic: str, type_name: str, t_ns: np.ndarray, payloads: np.ndarray | Callable[[], np.ndarray],
        schema_text: str | None = None,
    ) -> None:
        """Many messages of one topic whose serialized payloads are the rows of ``payloads`` -- or of
        what ``payloads()`` returns, called where the records are laid out (a background writer's
        builder thread: the caller does not wait for the encoding)."""
        t_ns = np.asarray(t_ns, dtype=np.int64)
        self._apply(lambda: self._sink.add_messages(self.channel(topic, type_name, schema_text), t_ns,
                                                    payloads() if callable(payloads) else payloads))

    def write_fixed_mixed(
        self, topics: list[tuple[str, str, str | None]], which: np.ndarray, t_ns: np.ndarray, payloads: np.ndarray
    ) -> None:
        """Messages of several topics in their given (time) order: row i belongs to ``topics[which[i]]``
        (``(topic, type, schema text)``); all payloads have the same length."""
        which, t_ns = np.asarray(which), np.asarray(t_ns, dtype=np.int64)

        def add() -> None:
            ids = np.array([self.channel(tp, ty, tx) for tp, ty, tx in topics], dtype=np.int64)
            self._sink.add_messages(ids[which], t_ns, payloads)

        self._apply(add)

    def write_float64_series(self, topic: str, t_ns: np.ndarray, values: np.ndarray) -> None:
        """A whole series of Float64 messages (vectorised encoding)."""
        self.write_fixed(topic, MessageType.FLOAT64, t_ns, lambda: float64_payloads(values))

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """An MCAP metadata record (string key/values)."""
        data = dict(data)
        self._apply(lambda: self._writer.add_metadata(name, data))

    @property
    def bytes_written(self) -> int:
        """About the file's size so far (the open chunk counted uncompressed)."""
        return self._writer.bytes_written

    def publish(self, path: str | Path | None = None) -> Path:
        """A durable recording takes its name (:meth:`~.mcapwriter.ChunkedMcapWriter.publish`)."""
        self.path = self._writer.publish(path)
        return self.path

    def close(self, commit: bool = True) -> None:
        """Write what is held, rosbag2's metadata record and the summary; ``commit=False``: the
        command failed -- a file replaced atomically is not put in place (see ``replace_atomically``)."""
        if self.closed:
            return
        self.closed = True
        ok = False
        try:
            if self._builder is not None:
                self._submit(wait_beyond=0)  # every job done, its error raised
                if self._error is not None:  # raised by an earlier call: the file is not finished
                    raise self._error
            if self._held is not None:
                self._held.release()
            self._writer.add_metadata(ROSBAG2_METADATA, {"serialized_metadata": self._rosbag2_metadata()})
            ok = True
        finally:
            if self._builder is not None:
                self._failed = True  # a job still queued (after an error) does nothing
                self._builder.shutdown(wait=True)
            self._writer.close(commit=commit and ok)

    def _rosbag2_metadata(self) -> str:
        """rosbag2's ``BagMetadata`` (version 9, Jazzy) of what was written, as YAML."""
        import yaml

        start, end = self._writer.log_time_range or (0, 0)
        duration = end - start
        by_id = self._writer.channel_counts
        counts = {topic: by_id.get(cid, 0) for topic, cid in self._channels.items()}
        total = sum(counts.values())
        topics = [{"topic_metadata": {"name": topic, "type": self._types[topic], "serialization_format": "cdr",
                                      "offered_qos_profiles": self._offered_qos.get(topic, ""),
                                      "type_description_hash": ""},
                   "message_count": counts[topic]} for topic in self._channels]
        info = {"version": 9, "storage_identifier": "mcap", "duration": {"nanoseconds": duration},
                "starting_time": {"nanoseconds_since_epoch": start}, "message_count": total,
                "topics_with_message_count": topics, "compression_format": "", "compression_mode": "",
                "relative_file_paths": [self.path.name],
                "files": [{"path": self.path.name, "starting_time": {"nanoseconds_since_epoch": start},
                           "duration": {"nanoseconds": duration}, "message_count": total}],
                "custom_data": {}, "ros_distro": "jazzy"}
        return yaml.safe_dump({"rosbag2_bagfile_information": info}, sort_keys=False)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type: Any, *exc: Any) -> None:
        self.close(commit=exc_type is None)
