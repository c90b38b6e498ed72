"""Launch the belt-drive node, a torque source that drives it, and a recording of the run.

    ros2 launch belt_drive_ros belt_drive.launch.py
    ros2 launch belt_drive_ros belt_drive.launch.py record_path:=run2.mcap scene:=my_scene.yaml

Needs the package built into a workspace (colcon build) and sourced. The node
reads its parameters from config/belt_drive.yaml (installed to
share/belt_drive_ros/config; params_file:=... for your own) and records its
input and outputs to record_path (MCAP; an existing file stops the node from
starting unless record_overwrite:=true). The source is the scene's own
drive (``belt-drive source engine --scene SCENE``: truck_compressor's diesel,
whose governor holds wheel M near its speed setpoint from the node's
shaft_speed); without a torque source the node applies 0 N m and the drive
coasts to a stop.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

PACKAGE = "belt_drive_ros"


def generate_launch_description():
    params_file = os.path.join(get_package_share_directory(PACKAGE), "config", "belt_drive.yaml")
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=params_file,
                              description="ROS 2 parameters file of the node (key: belt_drive)"),
        DeclareLaunchArgument("record_path", default_value="belt_drive_run.mcap",
                              description="MCAP file the node records to; '' records nothing"),
        DeclareLaunchArgument("record_overwrite", default_value="false",
                              description="replace an existing record_path"),
        DeclareLaunchArgument("scene", default_value="truck_compressor",
                              description="scene of the node and of the source's engine (a shipped name or a YAML path)"),
        Node(
            package=PACKAGE,
            executable="node",
            name="belt_drive",
            output="screen",
            parameters=[
                LaunchConfiguration("params_file"),
                {
                    "scene": LaunchConfiguration("scene"),
                    "record_path": LaunchConfiguration("record_path"),
                    "record_overwrite": LaunchConfiguration("record_overwrite"),
                },
            ],
        ),
        Node(
            package=PACKAGE,
            executable="source",
            name="torque_source",
            output="screen",
            arguments=["engine", "--scene", LaunchConfiguration("scene")],
        ),
    ])
