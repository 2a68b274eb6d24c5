"""The names other tools depend on (``docs/interface.md``), defined once: namespace, topics,
estimator channels, message types, metadata records and the rpm conversion.

Plain ``str`` constants grouped in classes rather than ``StrEnum`` members: the node's hot path
indexes dictionaries by channel per message, and a dict lookup keyed by a ``StrEnum`` member
costs ~220 ns (Python-level ``__hash__``) against ~25 ns for a ``str``.
"""

from __future__ import annotations

import math

#: the node's default namespace; every topic below except the absolute ones is relative to it
NAMESPACE = "/rollergear"
NODE_NAME = "loss_estimator"


class Channel:
    """The estimator's input channels (also the keys of a channel map)."""

    MOTOR_TORQUE = "motor_torque"
    MOTOR_SPEED = "motor_speed"
    OUTPUT_TORQUE = "output_torque"
    OUTPUT_SPEED = "output_speed"
    OIL_TEMPERATURE = "oil_temperature"
    #: the channels that pair into one sample, in sample order
    PAIRED: tuple[str, ...] = (MOTOR_TORQUE, MOTOR_SPEED, OUTPUT_TORQUE, OUTPUT_SPEED)
    #: every input channel; replay's channel codes index this tuple
    ALL: tuple[str, ...] = PAIRED + (OIL_TEMPERATURE,)


class Topic:
    """Topic names relative to the node's namespace (remappable), and the absolute ones."""

    MOTOR_TORQUE = "motor/torque"
    MOTOR_SPEED = "motor/speed"
    OUTPUT_TORQUE = "output/torque"
    OUTPUT_SPEED = "output/speed"
    OIL_TEMPERATURE = "oil/temperature"
    LOSS_TORQUE = "loss/torque"
    LOSS_POWER = "loss/power"
    EFFICIENCY = "efficiency"
    RESIDUAL_TORQUE = "residual/torque"
    EFFICIENCY_MEASURED = "efficiency/measured"  #: energy-weighted over a window, once a second
    EFFICIENCY_MEASURED_UNCERTAINTY = "efficiency/measured_uncertainty"  #: its standard uncertainty
    LOSS_ESTIMATE = "loss/estimate"  #: one stamped sensor_msgs/JointState per estimate (:mod:`outputs.stamped`)
    LOSS_MAP = "loss/map"  #: the live loss map, std_msgs/Float64MultiArray, transient-local (:mod:`outputs.livemap`)
    LOSS_TRACED = "loss/traced"  #: the latest online trace, diagnostic_msgs/DiagnosticStatus, transient-local
    JOINT_STATES = "/joint_states"  #: absolute
    DIAGNOSTICS = "/diagnostics"  #: absolute
    CLOCK = "/clock"  #: absolute
    PARAMETER_EVENTS = "/parameter_events"  #: absolute: the node's run-time parameter changes, in its recording
    #: Float64 input topic of each paired channel
    OF_CHANNEL: dict[str, str] = {Channel.MOTOR_TORQUE: MOTOR_TORQUE, Channel.MOTOR_SPEED: MOTOR_SPEED,
                                  Channel.OUTPUT_TORQUE: OUTPUT_TORQUE, Channel.OUTPUT_SPEED: OUTPUT_SPEED}


class MessageType:
    """ROS 2 message type names as MCAP schemas carry them."""

    FLOAT64 = "std_msgs/msg/Float64"
    TEMPERATURE = "sensor_msgs/msg/Temperature"
    JOINT_STATE = "sensor_msgs/msg/JointState"
    FLOAT64_MULTI_ARRAY = "std_msgs/msg/Float64MultiArray"
    PARAMETER_EVENT = "rcl_interfaces/msg/ParameterEvent"
    DIAGNOSTIC_STATUS = "diagnostic_msgs/msg/DiagnosticStatus"
    DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
    CLOCK = "rosgraph_msgs/msg/Clock"


class Metadata:
    """Names of the MCAP metadata records the package writes."""

    RECORDING = "rollergear_recording"  #: written by the node: how it paired its inputs
    GEARBOX = "rollergear"  #: key ``gearbox_id``: which gearbox a recording is of (fleets)
    SIMULATION = "rollergear_simulation"  #: written by ``simulate``: the ground truth (tests only)
    PROVENANCE = "rollergear_provenance"  #: written by ``replay --out`` and the node: what made the estimates
    IMPORT = "rollergear_import"  #: written by ``import``: the source, its kind and how its samples were made
    #: key of :attr:`IMPORT`: ``"true"`` where each sample is a steady-state table's row (an operating point)
    IMPORT_ROWS = "operating_points"
    #: key of :attr:`IMPORT`: ``"true"`` where a table's loss was the power balance of its drive and output
    #: torque readings (:attr:`~sources.tables.SteadyStateTable.readings`)
    IMPORT_READINGS = "torque_readings"
    #: key of :attr:`IMPORT`: the table's own input/output ratio (the channel map's), empty for none
    IMPORT_RATIO = "table_ratio"


#: default depth of the node's (reliable, volatile, keep-last) per-sample and per-window output
#: publishers (``node.output_depth``): what a reliable subscriber that stalls can still have resent --
#: 1 s at 1 kHz, as deep as the sensor-data inputs
OUTPUT_QUEUE_DEPTH = 1000
#: the deepest history Fast DDS keeps for a writer or reader (its default resource limit
#: ``max_samples``), whatever larger depth is asked for
MAX_QUEUE_DEPTH = 5000


def package_version() -> str:
    """The installed package's version (``setup.py``), as written into outputs and ``--version``."""
    try:
        from importlib.metadata import version

        return version("rollergear_ros")
    except Exception:  # noqa: BLE001 - a source tree that is not installed
        return "unknown (source tree)"


#: 1 rpm in rad/s, and its inverse
RAD_S_PER_RPM = 2.0 * math.pi / 60.0
RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)

__all__ = ["Channel", "MessageType", "Metadata", "NAMESPACE", "NODE_NAME", "RAD_S_PER_RPM", "RPM_PER_RAD_S", "Topic",
           "package_version"]
