"""The estimator's output channels in one table: name, topic, message type, unit, value and QoS.

Every place that publishes, records, writes or shows an estimate loops over :data:`OUTPUT_CHANNELS`:
the node (its publishers, its per-sample publishing plan and its MCAP recorder), replay's MCAP
output, ``rollergear watch`` (the Float64 channels) and ``docs/interface.md`` (a test checks that
each channel has its row there).  A channel's name is also its field of :class:`~recordings.messages.TopicMap`
(per-sample channels: ``--topic-<name>``) and its key wherever outputs are keyed.

Five kinds of channel:

- a **Float64** channel carries one value of each estimate: the attribute :attr:`OutputChannel.value`
  of :class:`~core.estimator.Estimate` (node) and :class:`~core.estimator.BatchEstimate` (replay); the node
  publishes these when ``node.publish_float64`` is on;
- the **stamped** channel carries each estimate as one ``sensor_msgs/msg/JointState`` with its
  sample time (:mod:`outputs.stamped`), when ``node.publish_stamped`` is on;
- the **map** channel carries the live loss map (:mod:`outputs.livemap`), one message per map rather
  than per estimate, latched (transient-local) for subscribers that join later, when
  ``node.publish_map`` is on.  Only the node publishes it (replay writes maps as ``.vtlm`` files);
- a **window** channel carries one value of the measured efficiency over the last
  ``node.efficiency_window_s`` of sample time (:class:`~core.measured.WindowValue`, its attribute
  :attr:`OutputChannel.value`), once per second of sample time and only where the output torque is
  measured: the node publishes these when ``node.publish_float64`` is on, replay writes them;
- the **trace** channel carries each online trace's result (:mod:`ros.tracer`) as one
  ``diagnostic_msgs/msg/DiagnosticStatus``, latched, when ``node.trace`` is on.  Only the node
  publishes it (and records it).

The per-sample channels (Float64 and stamped) are also the fields of
:class:`~recordings.messages.TopicMap`, so ``--topic-<name>`` moves them in a recording.

To add a Float64 output: one :class:`OutputChannel` entry passed to :func:`register` (its value an
attribute both estimate types have), its row in ``docs/interface.md``, and its tests; the node,
replay, the recordings and ``watch`` take it from here.
"""

from __future__ import annotations

from dataclasses import dataclass

from .interface import NAMESPACE, OUTPUT_QUEUE_DEPTH, MessageType, Topic

__all__ = ["OUTPUT_CHANNELS", "OutputChannel", "float64_channels", "map_channels", "register", "sample_channels",
           "stamped_channels", "trace_channels", "unregister", "window_channels"]


@dataclass(frozen=True)
class OutputChannel:
    """One output of the estimator (see the module docstring)."""

    name: str  #: key of the channel everywhere (TopicMap field, ``watch``, the node's topic table)
    topic: str  #: relative to the node's namespace
    message_type: str  #: as MCAP schemas name it (:class:`~.interface.MessageType`)
    unit: str  #: of the value ("1": dimensionless; "" for the stamped message, whose values have their own)
    description: str  #: what it carries (docs)
    #: attribute of :class:`~core.estimator.Estimate` / :class:`~core.estimator.BatchEstimate` a Float64 channel
    #: carries (None: the stamped channel, which carries :data:`~outputs.stamped.ESTIMATE_FIELDS`); of
    #: :class:`~core.measured.WindowValue` for a window channel
    value: str | None = None
    #: published only for samples with measured output torque (the value is NaN without one)
    measured_only: bool = False
    reliable: bool = True  #: QoS reliability the node offers it with (keep-last)
    #: QoS history depth; a per-sample or per-window channel's is the node's ``node.output_depth``
    #: (:meth:`offered_depth`), this default where there is no node (replay's offered QoS)
    depth: int = OUTPUT_QUEUE_DEPTH
    #: one message per estimate ("sample"), per second of measured efficiency ("window"), per loss map
    #: ("map") or per online trace ("trace")
    per: str = "sample"
    #: QoS durability: transient-local (the last ``depth`` messages kept for late joiners), else volatile
    transient_local: bool = False

    @property
    def stamped(self) -> bool:
        """Each estimate as one stamped message (rather than one Float64 value)."""
        return self.per == "sample" and self.value is None

    def offered_depth(self, output_depth: int) -> int:
        """The history depth the node offers this channel with, given ``node.output_depth``: that
        depth for a channel of samples or windows, the channel's own (1) for a latched one."""
        return output_depth if self.per in ("sample", "window") else self.depth

    def absolute_topic(self, namespace: str = NAMESPACE) -> str:
        """The topic under ``namespace`` (the node's default namespace unless given)."""
        ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
        return f"{ns}/{self.topic}"


#: name -> channel, in publishing order
OUTPUT_CHANNELS: dict[str, OutputChannel] = {}


def register(channel: OutputChannel) -> OutputChannel:
    """Add ``channel`` to :data:`OUTPUT_CHANNELS` (a name already there is refused)."""
    if channel.name in OUTPUT_CHANNELS:
        raise ValueError(f"output channel {channel.name!r} is already registered")
    if channel.per not in ("sample", "window", "map", "trace"):
        raise ValueError(f"output channel {channel.name!r}: per is 'sample', 'window', 'map' or 'trace', "
                         f"not {channel.per!r}")
    if channel.per == "window" and (channel.message_type != MessageType.FLOAT64 or channel.value is None):
        raise ValueError(f"output channel {channel.name!r}: a window channel carries one Float64 value")
    if channel.stamped and channel.message_type != MessageType.JOINT_STATE:
        raise ValueError(f"output channel {channel.name!r}: without a value it is the stamped JointState channel")
    if channel.per == "map" and channel.message_type != MessageType.FLOAT64_MULTI_ARRAY:
        raise ValueError(f"output channel {channel.name!r}: a map channel carries a Float64MultiArray")
    if channel.per == "trace" and channel.message_type != MessageType.DIAGNOSTIC_STATUS:
        raise ValueError(f"output channel {channel.name!r}: a trace channel carries a DiagnosticStatus")
    OUTPUT_CHANNELS[channel.name] = channel
    return channel


def unregister(name: str) -> None:
    """Remove a channel registered with :func:`register` (tests' toy channels)."""
    del OUTPUT_CHANNELS[name]


def sample_channels() -> tuple[OutputChannel, ...]:
    """The channels published once per estimate (Float64 and stamped), in publishing order."""
    return tuple(c for c in OUTPUT_CHANNELS.values() if c.per == "sample")


def float64_channels() -> tuple[OutputChannel, ...]:
    """The Float64 channels, in publishing order."""
    return tuple(c for c in OUTPUT_CHANNELS.values() if c.per == "sample" and not c.stamped)


def stamped_channels() -> tuple[OutputChannel, ...]:
    """The stamped channel(s)."""
    return tuple(c for c in OUTPUT_CHANNELS.values() if c.stamped)


def window_channels() -> tuple[OutputChannel, ...]:
    """The channels published once per second of measured efficiency, in publishing order."""
    return tuple(c for c in OUTPUT_CHANNELS.values() if c.per == "window")


def map_channels() -> tuple[OutputChannel, ...]:
    """The channel(s) published once per loss map."""
    return tuple(c for c in OUTPUT_CHANNELS.values() if c.per == "map")


def trace_channels() -> tuple[OutputChannel, ...]:
    """The channel(s) published once per online trace."""
    return tuple(c for c in OUTPUT_CHANNELS.values() if c.per == "trace")


for _channel in (
    OutputChannel("loss_torque", Topic.LOSS_TORQUE, MessageType.FLOAT64, "N*m",
                  "model (plus accepted effects) loss torque, signed, input-referred", "loss_torque_nm"),
    OutputChannel("loss_power", Topic.LOSS_POWER, MessageType.FLOAT64, "W", "loss power", "loss_power_w"),
    OutputChannel("efficiency", Topic.EFFICIENCY, MessageType.FLOAT64, "1", "efficiency, NaN where undefined",
                  "efficiency"),
    OutputChannel("residual_torque", Topic.RESIDUAL_TORQUE, MessageType.FLOAT64, "N*m",
                  "measured loss - estimated loss (only with measured output)", "residual_nm", measured_only=True),
    OutputChannel("efficiency_measured", Topic.EFFICIENCY_MEASURED, MessageType.FLOAT64, "1",
                  "measured efficiency, energy-weighted over the last node.efficiency_window_s of sample time "
                  "(P_out/P_in motoring, P_in/P_out regenerating), once a second; only with measured output",
                  "efficiency", per="window"),
    OutputChannel("efficiency_measured_uncertainty", Topic.EFFICIENCY_MEASURED_UNCERTAINTY, MessageType.FLOAT64,
                  "1", "its standard uncertainty from the sensors' stated accuracy (sensors.*; GUM first order; "
                  "0: none stated), once a second with it", "uncertainty", per="window"),
    OutputChannel("loss_estimate", Topic.LOSS_ESTIMATE, MessageType.JOINT_STATE, "",
                  "each estimate as one stamped message (sample time in header.stamp)"),
    OutputChannel("loss_map", Topic.LOSS_MAP, MessageType.FLOAT64_MULTI_ARRAY, "",
                  "the live loss map on the map.* grid (speeds in rpm, torques and losses in N*m)",
                  per="map", depth=1, transient_local=True),
    OutputChannel("loss_traced", Topic.LOSS_TRACED, MessageType.DIAGNOSTIC_STATUS, "",
                  "the latest online trace of the residual (ros/tracer.py): verdict, change point, effects with "
                  "their 95 % intervals, error now and with the candidate", per="trace", depth=1,
                  transient_local=True),
):
    register(_channel)
