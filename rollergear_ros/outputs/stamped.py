"""The stamped estimate: one message per estimated sample, with the sample's time in its header.

The four ``std_msgs/Float64`` outputs carry no time: a consumer that wants a sample's loss with
its efficiency and residual must re-pair them, the problem the node solves on its inputs.  The
node therefore also publishes each estimate as one ``sensor_msgs/msg/JointState`` on
``loss/estimate`` (``Topic.LOSS_ESTIMATE``):

* ``header.stamp`` -- the time of the sample the estimate is of: the time the node paired the
  inputs by (the motor torque's publisher timestamp, or its arrival time; ROS time under
  ``use_sim_time``), the same time its recording logs the inputs at;
* ``name`` -- :data:`ESTIMATE_FIELDS`, always all of them in this order;
* ``position`` -- the values, in the order of ``name`` (SI units as the names say; efficiencies as
  fractions, NaN where undefined; residual and measured efficiency NaN without a measured output);
* ``velocity``, ``effort`` -- empty.

Why ``JointState``: it is the one message of common_interfaces with a header *and* named float64
values, so plotting tools (PlotJuggler, Foxglove) show each value by its name, and the message
describes itself.  ``std_msgs`` has no stamped array; the stamped ``geometry_msgs`` types
(``Vector3Stamped``, ``WrenchStamped``) have fixed x/y/z fields that would misname the quantities
and hold too few of them.  Custom ``.msg`` packages do not build from the PyPI wheels.

The message is encoded by patching a serialised template (the stamp and 8 bytes per value), so
one estimate costs one ``bytes`` copy and two ``struct.pack_into`` (~1 µs), and the node's
highest loss-free rate with only this output on passes its rate with the four Float64 topics.
No rclpy import.
"""

from __future__ import annotations

import functools
import operator
import struct

import numpy as np

from ..recordings.messages import decoder_for, encoder_for
from ..base.errors import BagError
from ..base.interface import MessageType

__all__ = ["ESTIMATE_FIELDS", "EstimateCodec", "codec", "decode_estimates", "estimate_values"]

#: the names in every stamped estimate's ``name``, the order of its ``position``
ESTIMATE_FIELDS: tuple[str, ...] = ("loss_torque_nm", "loss_power_w", "efficiency", "residual_nm",
                                    "torque_nm", "speed_rad_s", "efficiency_measured")
#: the values of :data:`ESTIMATE_FIELDS` from an :class:`~core.estimator.Estimate` or a
#: :class:`~core.estimator.BatchEstimate` (the names are their attributes)
estimate_values = operator.attrgetter(*ESTIMATE_FIELDS)
_STAMP = struct.Struct("<iI")
_SEC_MIN, _SEC_MAX = -(2**31), 2**31 - 1
_VALUES = struct.Struct(f"<{len(ESTIMATE_FIELDS)}d")


class EstimateCodec:
    """Serialises stamped estimates (CDR, little-endian) from a template made by the typestore's
    own serializer; the offsets are found in it, not assumed."""

    def __init__(self) -> None:
        encode = encoder_for(MessageType.JOINT_STATE)

        def message(sec: int, nanosec: int, values) -> bytes:
            return encode({"header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": ""},
                           "name": list(ESTIMATE_FIELDS), "position": list(values), "velocity": [], "effort": []})

        self.template = message(0, 0, [0.0] * len(ESTIMATE_FIELDS))
        markers = [1.0 + 1.0 / (k + 3) for k in range(len(ESTIMATE_FIELDS))]
        sec, nanosec = 0x12345678, 0x1ABCDEF0
        marked = message(sec, nanosec, markers)
        self._stamp_at = marked.index(_STAMP.pack(sec, nanosec))
        self._values_at = marked.index(_VALUES.pack(*markers))
        if self.encode(sec * 1_000_000_000 + nanosec, markers) != marked:
            raise RuntimeError("the stamped estimate's template does not match the serializer")

    def encode(self, t_ns: int, values) -> bytes:
        """One message: the sample time (ns since the epoch of its clock) and the values of
        :data:`ESTIMATE_FIELDS`."""
        buf = bytearray(self.template)
        sec, nanosec = divmod(int(t_ns), 1_000_000_000)
        _STAMP.pack_into(buf, self._stamp_at, sec, nanosec)
        _VALUES.pack_into(buf, self._values_at, *values)
        return bytes(buf)

    def payloads(self, t_ns: np.ndarray, values: np.ndarray) -> np.ndarray:
        """Messages for arrays, as the rows of a ``uint8`` matrix (:meth:`recordings.bagwriter.BagWriter.write_fixed`):
        ``t_ns`` (n,), ``values`` (n, len(ESTIMATE_FIELDS))."""
        t = np.asarray(t_ns, dtype=np.int64)
        n = len(t)
        if n == 0:
            return np.empty((0, len(self.template)), dtype=np.uint8)
        rows = np.tile(np.frombuffer(self.template, dtype=np.uint8), (n, 1))
        sec, nanosec = np.divmod(t, 1_000_000_000)
        if n and (sec.min() < _SEC_MIN or sec.max() > _SEC_MAX):
            raise BagError(f"a sample time of {int(sec.max() if sec.max() > _SEC_MAX else sec.min())} s does not fit "
                           "a ROS 2 header stamp (int32 seconds)")
        stamps = np.empty(n, dtype=[("sec", "<i4"), ("nanosec", "<u4")])
        stamps["sec"], stamps["nanosec"] = sec, nanosec
        rows[:, self._stamp_at:self._stamp_at + 8] = stamps.view(np.uint8).reshape(n, 8)
        vals = np.ascontiguousarray(values, dtype="<f8").reshape(n, len(ESTIMATE_FIELDS))
        rows[:, self._values_at:self._values_at + vals.shape[1] * 8] = vals.view(np.uint8).reshape(n, -1)
        return rows


@functools.cache
def codec() -> EstimateCodec:
    """The one codec of the process (its template is built once)."""
    return EstimateCodec()


def decode_estimates(payloads: list[bytes]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Stamped estimates back to arrays (with the typestore's deserializer, checking the names):
    ``(stamp ns, {field: values})``."""
    decode = decoder_for(MessageType.JOINT_STATE)
    stamps, rows = [], []
    for raw in payloads:
        m = decode(raw)
        if tuple(m.name) != ESTIMATE_FIELDS:
            raise ValueError(f"not a stamped estimate: names {list(m.name)}")
        stamps.append(m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec)
        rows.append(np.asarray(m.position, dtype=float))
    values = np.array(rows).reshape(len(rows), len(ESTIMATE_FIELDS))
    return np.array(stamps, dtype=np.int64), {k: values[:, i] for i, k in enumerate(ESTIMATE_FIELDS)}
