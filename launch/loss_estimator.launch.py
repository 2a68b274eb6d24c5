"""Start the loss estimator with the package's parameter file (``ros2 launch rollergear_ros
loss_estimator.launch.py [params_file:=PATH] [namespace:=NS]``)."""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    default_params = os.path.join(get_package_share_directory("rollergear_ros"), "config", "gearbox.yaml")
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="parameter file (a calibrated one from rollergear calibrate --out)"),
        DeclareLaunchArgument("namespace", default_value="rollergear", description="namespace of the topics"),
        Node(
            package="rollergear_ros",
            executable="loss_estimator",
            name="loss_estimator",
            namespace=LaunchConfiguration("namespace"),
            parameters=[LaunchConfiguration("params_file")],
            output="screen",
        ),
    ])
