"""Launch the controller for a real Z axis: the follow node (+ recorder), no simulator.

The axis' driver node is started by the integrator (it publishes ``axis/capacitive_height``
and ``axis/feedback`` and executes ``axis/velocity_command``; ``ladrc conform`` checks one). On
Ctrl-C the follow node commands zero velocity with the drive enable off; the recorder keeps
recording for its ``stop_grace_s`` so the bag holds that command. When the follow node exits,
the recorder is stopped, then launch.

    ros2 launch ladrc_bringup axis.launch.py params:=/etc/ladrc/head1.yaml bag:=/data/shift1
    ros2 launch ladrc_bringup axis.launch.py cia402_device:=/etc/ladrc/z_drive.yaml can:=can0
"""

from ladrc_bringup.bringup import LAUNCH_ARGUMENTS, axis_node_specs, view_spec
from ladrc_bringup.launching import declare_arguments, launch_nodes, stop_in_order
from launch import LaunchDescription
from launch.actions import OpaqueFunction
from launch.substitutions import LaunchConfiguration

# no scenario, and no lock step: it is the sim node's (a drive does not wait for its controller)
ARGUMENTS = {k: v for k, v in LAUNCH_ARGUMENTS.items() if k not in ('scenario', 'lockstep')}
ARGUMENTS.update({
    'cia402_device': ('', 'a CiA 402 drive on CANopen: its device file (node id, EDS, objects, '
                      'PDOs, watchdog; docs/cia402.md); starts the shipped driver node'),
    'cia402_eds': ('', 'a CiA 402 drive with the standard objects: its EDS or DCF (without '
                   'cia402_device); empty, and no device file: your own driver'),
    'can': ('can0', 'with a CiA 402 drive: the socketcan channel (or ws://127.0.0.1:PORT/)'),
    'node_id': ('5', "with cia402_eds: the drive's CANopen node id"),
})


def _nodes(context):
    def arg(name):
        return LaunchConfiguration(name).perform(context)

    specs = axis_node_specs(arg('params') or None, arg('bag') or None, arg('loop'),
                            arg('storage'), arg('hardware_id'), arg('cia402_eds'), arg('can'),
                            int(arg('node_id')), arg('cia402_device'))
    if arg('view').strip().lower() in ('true', '1', 'yes'):  # the live view, 127.0.0.1 only
        specs.insert(0, view_spec(int(arg('view_port'))))
    nodes = launch_nodes(specs)
    return list(nodes.values()) + stop_in_order(nodes, first='ladrc_follow')


def generate_launch_description():
    return LaunchDescription(declare_arguments(ARGUMENTS) + [OpaqueFunction(function=_nodes)])
