"""Starts the armctl-ros2 bridge with a config, and robot_state_publisher with the example
arm (urdf/arm.urdf.xacro) for MoveIt.

    ros2 launch armctl_ros2 bridge.launch.py                      # config/bridge.json
    ros2 launch armctl_ros2 bridge.launch.py config:=/path/my-arm.json controller:=192.168.1.30:8510
    ros2 launch armctl_ros2 bridge.launch.py robot_description:=false   # your own URDF

The bridge binary is not built by colcon: `cargo install --path ros2-bridge` (from the
armctl repository) puts `armctl-ros2` on PATH, or pass bridge:=/path/to/armctl-ros2.
ROS_DISTRO picks the message layouts (control_msgs 5.x for humble/jazzy, 6.x for
kilted/rolling) unless the config sets ros_distro.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess, OpaqueFunction
from launch.conditions import IfCondition
from launch.substitutions import Command, LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare


def bridge_process(context):
    cmd = [
        LaunchConfiguration("bridge").perform(context),
        LaunchConfiguration("config").perform(context),
    ]
    controller = LaunchConfiguration("controller").perform(context)
    if controller:
        cmd += ["--controller", controller]
    return [ExecuteProcess(cmd=cmd, name="armctl_bridge", output="screen")]


def generate_launch_description():
    share = FindPackageShare("armctl_ros2")
    description = Command(["xacro ", PathJoinSubstitution([share, "urdf", "arm.urdf.xacro"])])
    return LaunchDescription([
        DeclareLaunchArgument(
            "config", default_value=PathJoinSubstitution([share, "config", "bridge.json"]),
            description="the bridge's JSON config (docs/ROS2.md): controller, names, rates, joints"),
        DeclareLaunchArgument(
            "controller", default_value="",
            description="HOST:PORT of the controller; empty: the config's `controller`"),
        DeclareLaunchArgument(
            "bridge", default_value="armctl-ros2",
            description="the armctl-ros2 binary (cargo install --path ros2-bridge)"),
        DeclareLaunchArgument(
            "robot_description", default_value="true",
            description="also run robot_state_publisher with the example arm's URDF"),
        OpaqueFunction(function=bridge_process),
        Node(
            package="robot_state_publisher",
            executable="robot_state_publisher",
            parameters=[{"robot_description": ParameterValue(description, value_type=str)}],
            condition=IfCondition(LaunchConfiguration("robot_description")),
            output="screen",
        ),
    ])
