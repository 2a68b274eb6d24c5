"""Lost-message marks: the placeholder value the node records in a lost message's place, and the gaps in a
publisher's sequence numbers that say a message was lost (:class:`SequenceGaps`).  No rclpy import."""

from __future__ import annotations

import struct

import numpy as np


#: a message the middleware lost, known from a gap in its publisher's sequence numbers: the live
#: node pushes (and records) one NaN with this payload per lost message, in its place, so that first-in
#: first-out pairing stays aligned across the loss and replay of the recording pairs as the node did.
#: A sample with a lost motor input is skipped as ``lost``; a lost output leaves it without a residual
LOST_BITS = 0x7FF8_0000_4C4F_5354  # a quiet NaN whose payload reads "LOST"


def placeholder(bits: int) -> float:
    """The quiet NaN whose 64 bits are ``bits``: a value that stands for something (a lost message)."""
    return struct.unpack("<d", struct.pack("<Q", bits))[0]


def is_placeholder(value: float, bits: int) -> bool:
    """Whether ``value`` is :func:`placeholder` ``(bits)``, bit for bit."""
    return value != value and struct.unpack("<Q", struct.pack("<d", value))[0] == bits


def placeholder_mask(values: np.ndarray, bits: int) -> np.ndarray:
    """:func:`is_placeholder` of each element of a float64 array."""
    return np.ascontiguousarray(values, dtype=np.float64).view(np.uint64) == np.uint64(bits)


LOST_VALUE: float = placeholder(LOST_BITS)


def is_lost(value: float) -> bool:
    """Whether ``value`` is the placeholder of a lost message (:data:`LOST_VALUE`, bit for bit)."""
    return is_placeholder(value, LOST_BITS)


def lost_mask(values: np.ndarray) -> np.ndarray:
    """:func:`is_lost` of each element of a float64 array."""
    return placeholder_mask(values, LOST_BITS)


class SequenceGaps:
    """Messages lost on one topic, from the publication sequence numbers of those received.

    A publisher numbers its messages 1, 2, 3, ...; a best-effort delivery that drops some (a
    keep-last history overwritten while the node was behind: Fast DDS reports no "sample lost"
    for that) leaves a gap.  A number that does not follow on (equal or smaller) is a new writer:
    a restarted publisher; nothing is counted for it.
    """

    def __init__(self) -> None:
        self.last: int | None = None

    def lost_before(self, sequence: int | None) -> int:
        """How many messages were lost just before the one numbered ``sequence`` (0 for the first,
        for an unnumbered one and for a new writer's)."""
        last = self.last
        if sequence is None or sequence <= 0:
            return 0
        self.last = sequence
        if last is None or sequence <= last:
            return 0
        return sequence - last - 1
