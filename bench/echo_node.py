#!/usr/bin/env python3
"""Baseline for bench_node.py: a bare rclpy echo node.  It subscribes to the same input topics with
the same QoS and executor (argument: events | single_threaded) as loss_estimator and republishes
every message it receives, unchanged, on an output topic (motor torque on ``loss/torque``, the
others on ``echo/...``): four callbacks and four publications per sample, like loss_estimator."""

from __future__ import annotations

import sys

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from std_msgs.msg import Float64

from rollergear_ros.ros.qos import SENSOR_QOS, output_qos
from rollergear_ros.base.output_channels import OUTPUT_CHANNELS

#: as the node offers its loss torque
OUTPUT_QOS = output_qos(OUTPUT_CHANNELS["loss_torque"])


def main() -> None:
    rclpy.init()
    node = Node("echo", namespace="/rollergear")
    for rel, out in (("motor/torque", "loss/torque"), ("motor/speed", "echo/motor_speed"),
                     ("output/torque", "echo/output_torque"), ("output/speed", "echo/output_speed")):
        pub = node.create_publisher(Float64, out, OUTPUT_QOS)
        node.create_subscription(Float64, rel, lambda raw, pub=pub: pub.publish(raw), SENSOR_QOS, raw=True)
    ex = SingleThreadedExecutor() if sys.argv[1:] == ["single_threaded"] else EventsExecutor()
    ex.add_node(node)
    try:
        while rclpy.ok():
            ex.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
