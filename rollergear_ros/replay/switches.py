"""The run-time parameter changes of a live recording, applied where the node applied them.

The node records each parameter change it accepts on ``/parameter_events``
(``rcl_interfaces/msg/ParameterEvent``), its ``stamp`` the sample boundary it took effect at: the
log time of the last input message its recording holds from before the change (0: before any).
Replay, which takes a recording's inputs in log-time order, applies each at the same boundary --
after the inputs logged at or before it, before the next -- as the node did: a new
:class:`~core.estimator.Estimator` for the changed parameters that takes over the input stream
(:meth:`~core.estimator.Estimator.take_over_inputs`), so a recording replays to what the node
published, also across a change (a traced effect the node took in, ``node.accept_traced: on``).
No rclpy import.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..base.interface import NODE_NAME, MessageType, Topic
from ..core.estimator import Estimator
from ..core.paramspecs import spec_by_name
from ..recordings.baginfo import BagInfo, iter_raw_batches
from ..recordings.messages import decoder_for

__all__ = ["ParameterSwitch", "apply_switch", "recorded_switches", "split_at"]

#: ``rcl_interfaces/msg/ParameterType``: the field of ``ParameterValue`` each type's value is in
_VALUE_FIELDS = {1: "bool_value", 2: "integer_value", 3: "double_value", 4: "string_value"}


@dataclass(frozen=True)
class ParameterSwitch:
    """A recorded parameter change: after the inputs logged at or before ``at_ns``."""

    at_ns: int
    changes: dict[str, Any]


def recorded_switches(info: BagInfo) -> list[ParameterSwitch]:
    """The package parameters the recording's ``loss_estimator`` changed, in the order it did
    (none for a recording without ``/parameter_events``: nothing is read)."""
    if not info.counts.get(Topic.PARAMETER_EVENTS):
        return []
    decode = decoder_for(MessageType.PARAMETER_EVENT)
    names = spec_by_name()
    switches = []
    for batch in iter_raw_batches(info, {Topic.PARAMETER_EVENTS}):
        for data in batch.data:
            event = decode(data)
            if event.node.rsplit("/", 1)[-1] != NODE_NAME:
                continue
            changes = {p.name: getattr(p.value, _VALUE_FIELDS[p.value.type]) for p in event.changed_parameters
                       if p.name in names and p.value.type in _VALUE_FIELDS}
            if changes:
                switches.append(ParameterSwitch(event.stamp.sec * 1_000_000_000 + event.stamp.nanosec, changes))
    return switches


def split_at(log_ns: np.ndarray, at_ns: int) -> int:
    """How many of the inputs (in the order they are taken) come before the boundary ``at_ns``:
    up to the first one logged after it."""
    after = np.flatnonzero(np.asarray(log_ns) > at_ns)
    return int(after[0]) if len(after) else len(log_ns)


def apply_switch(estimator: Estimator, switch: ParameterSwitch) -> Estimator:
    """The estimator after ``switch``, as the node makes it: the changed parameters (validated),
    the same pairing, the input stream taken over."""
    new = Estimator(estimator.config.with_values(switch.changes), estimator.pairing, estimator.sample_period_s)
    new.take_over_inputs(estimator)
    return new
