"""The node's QoS table: what its inputs are subscribed with and what each output is offered with.

Inputs: ``node.input_qos`` picks one of :data:`INPUT_QOS`.  Outputs: each output channel's QoS is
derived from its row of :mod:`base.output_channels` (reliability, depth, durability), so that the
node's publishers, its recorder's offered QoS and replay's output agree.
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ..base.interface import OUTPUT_QUEUE_DEPTH
from ..base.output_channels import OutputChannel

__all__ = ["INPUT_QOS", "RELIABLE_INPUT_QOS", "SENSOR_QOS", "output_qos"]

#: best effort and volatile like rclpy's qos_profile_sensor_data, with a deeper queue for 1 kHz bursts
SENSOR_QOS = QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE,
                        history=HistoryPolicy.KEEP_LAST, depth=1000)
#: ``node.input_qos: reliable``: nothing lost; a publisher that outpaces the node waits for it
RELIABLE_INPUT_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE,
                                history=HistoryPolicy.KEEP_ALL)
#: ``node.input_qos`` -> the inputs' QoS
INPUT_QOS = {"sensor_data": SENSOR_QOS, "reliable": RELIABLE_INPUT_QOS}


def output_qos(channel: OutputChannel, output_depth: int = OUTPUT_QUEUE_DEPTH) -> QoSProfile:
    """The QoS an output channel is offered with: keep-last, its reliability, its depth given
    ``node.output_depth`` (:meth:`~base.output_channels.OutputChannel.offered_depth`) and durability
    (volatile, or transient-local for the loss map that late joiners should get)."""
    return QoSProfile(reliability=ReliabilityPolicy.RELIABLE if channel.reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if channel.transient_local
                      else DurabilityPolicy.VOLATILE,
                      history=HistoryPolicy.KEEP_LAST, depth=channel.offered_depth(output_depth))
