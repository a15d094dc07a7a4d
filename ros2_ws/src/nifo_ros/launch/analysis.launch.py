"""ros2 launch nifo_ros analysis.launch.py [model_file:=...] [input_reliability:=reliable]   then:  ros2 bag play BAG

integrator -> identifier only (namespace /nifo): the sensors come from the vehicle's own drivers or
from a bag (ros2 bag play, or nifo replay), on /nifo/spindle/imu and /nifo/body/imu.
input_reliability:=reliable makes the integrator's input reliable + keep-all (lossless replay: pair it with
`nifo replay BAG --reliable`, or ros2 bag play with reliable/keep_all QoS overrides, docs/ros.md);
the live estimate then equals `nifo identify` on the same bag.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    cfg = os.path.join(get_package_share_directory("nifo_ros"), "config")
    ns = LaunchConfiguration("namespace")
    return LaunchDescription([
        DeclareLaunchArgument("namespace", default_value="nifo"),
        DeclareLaunchArgument("model_file", default_value=os.path.join(cfg, "model.yaml")),
        DeclareLaunchArgument("checkpoint_file", default_value=""),
        DeclareLaunchArgument("input_reliability", default_value="best_effort", choices=["best_effort", "reliable"],
                              description="reliable: lossless replay (reliable, keep-all integrator input)"),
        Node(package="nifo_ros", executable="integrator", name="integrator", namespace=ns,
             parameters=[os.path.join(cfg, "integrator.yaml"),
                         {"input_reliability": LaunchConfiguration("input_reliability")}],
             output="screen"),
        Node(package="nifo_ros", executable="identifier", name="identifier", namespace=ns,
             parameters=[os.path.join(cfg, "identifier.yaml"),
                         {"model_file": LaunchConfiguration("model_file"),
                          "checkpoint_file": LaunchConfiguration("checkpoint_file")}],
             output="screen"),
    ])
