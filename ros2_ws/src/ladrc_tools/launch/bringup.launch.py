"""Launch the simulated height-follow axis on a stock Jazzy install (ros2 launch).

Equivalent to the ``bringup`` command (which works where ``launch`` is not installable): both
take their nodes and arguments from :func:`ladrc_tools.bringup.bringup.node_specs`, so they
cannot drift apart. Isolation (ROS_DOMAIN_ID, localhost discovery) is the caller's environment
here.

    ros2 launch ladrc_tools bringup.launch.py scenario:=showcase bag:=/tmp/run1
"""

from ladrc_tools.bringup.bringup import node_specs, ros_arguments
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def _nodes(context):
    def arg(name):
        return LaunchConfiguration(name).perform(context)

    specs = node_specs(arg('scenario'), arg('params') or None, arg('bag') or None,
                       arg('loop'), arg('storage'))
    return [Node(package=s.package, executable=s.executable, name=s.name, output='screen',
                 arguments=ros_arguments(s)) for s in specs]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument('scenario', default_value='showcase'),
        DeclareLaunchArgument('params', default_value=''),
        DeclareLaunchArgument('bag', default_value=''),
        DeclareLaunchArgument('loop', default_value='deadline'),
        DeclareLaunchArgument('storage', default_value='mcap'),
        OpaqueFunction(function=_nodes),
    ])
