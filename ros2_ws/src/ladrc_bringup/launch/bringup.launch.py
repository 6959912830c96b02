"""Launch the simulated height-follow axis on a stock Jazzy install (ros2 launch).

The same nodes and parameters as the ``bringup`` command (which works where ``launch`` is not
installable): both take them from :func:`ladrc_bringup.bringup.node_specs`. When the
scenario ends the node set stops in the safe order: the controller first (it commands zero
velocity), then the recorder (so the bag holds that command), then launch itself. On Ctrl-C
launch interrupts every node at once; the recorder keeps recording for its ``stop_grace_s``
before it closes the bag, so the zero command is in the bag then too. Isolation
(ROS_DOMAIN_ID, localhost discovery) is the caller's environment here.

    ros2 launch ladrc_bringup bringup.launch.py scenario:=showcase bag:=/tmp/run1
    ros2 launch ladrc_bringup bringup.launch.py scenario:=showcase lockstep:=true
    ros2 launch ladrc_bringup bringup.launch.py scenario:=showcase view:=true   # + live view
    ros2 launch ladrc_bringup bringup.launch.py --show-args
"""

from ladrc_bringup.bringup import LAUNCH_ARGUMENTS, node_specs, view_spec
from ladrc_bringup.launching import declare_arguments, launch_nodes, stop_in_order
from launch import LaunchDescription
from launch.actions import OpaqueFunction
from launch.substitutions import LaunchConfiguration


def _nodes(context):
    def arg(name):
        return LaunchConfiguration(name).perform(context)

    specs = node_specs(arg('scenario'), arg('params') or None, arg('bag') or None,
                       arg('loop'), arg('storage'),
                       lockstep=arg('lockstep').strip().lower() in ('true', '1', 'yes'))
    for spec in specs:
        if spec.name == 'ladrc_follow':
            spec.parameters['hardware_id'] = arg('hardware_id')
        elif spec.name == 'ladrc_recorder':  # the bag's machine id (bags/provenance.py)
            spec.parameters['machine_id'] = arg('hardware_id')
    if arg('view').strip().lower() in ('true', '1', 'yes'):  # the live view, 127.0.0.1 only
        specs.insert(0, view_spec(int(arg('view_port'))))
    nodes = launch_nodes(specs)
    return list(nodes.values()) + stop_in_order(nodes, first='ladrc_sim')


def generate_launch_description():
    return LaunchDescription(declare_arguments(LAUNCH_ARGUMENTS)
                             + [OpaqueFunction(function=_nodes)])
