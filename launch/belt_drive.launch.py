"""Launch the belt-drive node, a torque source that drives it, and a recording of the run.

    ros2 launch belt_drive_ros belt_drive.launch.py
    ros2 launch belt_drive_ros belt_drive.launch.py record_path:=run2.mcap scene:=my_scene.yaml
    ros2 launch belt_drive_ros belt_drive.launch.py scene:=fead_i4      # a belt network (serpentine drive)

Needs the package built into a workspace (colcon build) and sourced. The node
reads its parameters from config/belt_drive.yaml (installed to
share/belt_drive_ros/config; params_file:=... for your own) and records its
input and outputs to record_path (MCAP; an existing file stops the node from
starting unless record_overwrite:=true); config/belt_drive.yaml sets no
model parameter, so every scene keeps its own belt. The source is the
scene's own drive, whatever its type (``belt-drive source profile --scene
SCENE``: truck_compressor's diesel, whose governor holds wheel M near its
speed setpoint from the node's shaft_speed; paper's motor curve); without a
torque source the node applies 0 N m and the drive coasts to a stop.

A belt network scene (``kind: network``, e.g. the shipped fead_i4) starts the
network node instead (``belt-drive node NETWORK``): its crank is driven by the
scene's own engine profile (drive_source:=scene; per-accessory
``<pulley>/load_torque`` topics stay open), it records the same way, and
config/belt_drive.yaml (the paper node's parameters) is not given to it; a
params_file:=... of your own is.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

PACKAGE = "belt_drive_ros"


def _is_network(scene: str) -> bool:
    from belt_drive_ros.io.scenes import is_network

    return is_network(scene)


def _nodes(context):
    """The node (and the paper node's torque source) for the scene the launch arguments name."""
    scene = LaunchConfiguration("scene").perform(context)
    params_file = LaunchConfiguration("params_file").perform(context)
    record = {"record_path": LaunchConfiguration("record_path"),
              "record_overwrite": LaunchConfiguration("record_overwrite")}
    if _is_network(scene):
        return [Node(package=PACKAGE, executable="node", name="belt_drive", output="screen", arguments=[scene],
                     parameters=[*([params_file] if params_file else []), {"drive_source": "scene", **record}])]
    if not params_file:
        params_file = os.path.join(get_package_share_directory(PACKAGE), "config", "belt_drive.yaml")
    return [
        Node(package=PACKAGE, executable="node", name="belt_drive", output="screen",
             parameters=[params_file, {"scene": LaunchConfiguration("scene"), **record}]),
        Node(package=PACKAGE, executable="source", name="torque_source", output="screen",
             arguments=["profile", "--scene", LaunchConfiguration("scene")]),
    ]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value="",
                              description="ROS 2 parameters file of the node (key: /**/belt_drive, the node in any "
                                          "namespace; belt_drive alone is /belt_drive only); '' = the package's "
                                          "config/belt_drive.yaml for the paper's drive, none for a belt network"),
        DeclareLaunchArgument("record_path", default_value="belt_drive_run.mcap",
                              description="MCAP file the node records to; '' records nothing"),
        DeclareLaunchArgument("record_overwrite", default_value="false",
                              description="replace an existing record_path"),
        DeclareLaunchArgument("scene", default_value="truck_compressor",
                              description="scene of the node and of the source's drive (a shipped name or a YAML "
                                          "path); a belt network scene (kind: network) starts the network node"),
        OpaqueFunction(function=_nodes),
    ])
