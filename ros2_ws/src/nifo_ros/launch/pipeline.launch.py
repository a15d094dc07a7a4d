"""ros2 launch nifo_ros pipeline.launch.py [source:=simulator|file] [path:=...] [model_file:=...] [rerun:=true]

acquisition -> integrator -> identifier in namespace /nifo, parameters from config/*.yaml
(the same files launch_scripts/run_pipeline.py uses).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    cfg = os.path.join(get_package_share_directory("nifo_ros"), "config")
    ns = LaunchConfiguration("namespace")
    args = [
        DeclareLaunchArgument("namespace", default_value="nifo"),
        DeclareLaunchArgument("source", default_value="simulator"),
        DeclareLaunchArgument("path", default_value=""),
        DeclareLaunchArgument("model_file", default_value=os.path.join(cfg, "model.yaml")),
        DeclareLaunchArgument("checkpoint_file", default_value=""),
        DeclareLaunchArgument("rerun", default_value="false",
                              description="also start the live Rerun viewer node (spawns a viewer)"),
    ]
    return LaunchDescription(args + [
        Node(package="nifo_ros", executable="acquisition", name="acquisition", namespace=ns,
             parameters=[os.path.join(cfg, "acquisition.yaml"),
                         {"source": LaunchConfiguration("source"), "path": LaunchConfiguration("path")}],
             output="screen"),
        Node(package="nifo_ros", executable="integrator", name="integrator", namespace=ns,
             parameters=[os.path.join(cfg, "integrator.yaml")], output="screen"),
        Node(package="nifo_ros", executable="identifier", name="identifier", namespace=ns,
             parameters=[os.path.join(cfg, "identifier.yaml"),
                         {"model_file": LaunchConfiguration("model_file"),
                          "checkpoint_file": LaunchConfiguration("checkpoint_file")}],
             output="screen"),
        Node(package="nifo_ros", executable="rerun_viewer", name="rerun_viewer", namespace=ns,
             condition=IfCondition(LaunchConfiguration("rerun")), output="screen"),
    ])
