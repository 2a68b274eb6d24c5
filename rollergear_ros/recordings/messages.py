"""ROS 2 messages in MCAP bags without ROS: definitions, the topic map and the CDR codec.

Bags follow ``interface.md``: MCAP, ``ros2`` profile, ``ros2msg`` schemas named like
``std_msgs/msg/Float64`` (:data:`MSG_DEFINITIONS`), ``cdr`` messages -- so ``ros2 bag``, Foxglove
and ``rosbags`` open them.  Float64 payloads are decoded and encoded with numpy (4-byte CDR
encapsulation header + one float64); other types by ``rosbags`` (:func:`decoder_for`,
:func:`encoder_for`).  No rclpy import here.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

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


#: metadata record the node writes into its recordings: how it paired the inputs it recorded
RECORDING_METADATA = Metadata.RECORDING
#: the metadata record rosbag2's MCAP storage plugin writes (key ``serialized_metadata``: its YAML)
ROSBAG2_METADATA = "rosbag2"
