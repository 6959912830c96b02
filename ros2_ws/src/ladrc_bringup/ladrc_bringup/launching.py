"""launch / launch_ros actions for the node specs of :mod:`.bringup` (used by launch/*.py).

Kept here so that the launch files stay thin: the node specs become ``launch_ros`` ``Node``
actions with their parameters passed the launch_ros way (the parameter file, then a dict of
values), and the stop order becomes ``OnProcessExit`` handlers. Imports launch lazily: the rest
of the package runs where launch is not installed (PyPI).
"""

from __future__ import annotations

import signal
from typing import Any

from .bringup import NodeSpec

STOP_ORDER = ('ladrc_sim', 'ladrc_follow', 'ladrc_recorder')
"""Who stops whom: when one exits, the next in the list is interrupted, then launch ends."""


def declare_arguments(arguments: dict[str, tuple[str, str]]) -> list[Any]:
    """``DeclareLaunchArgument`` actions with default and description."""
    from launch.actions import DeclareLaunchArgument

    return [DeclareLaunchArgument(name, default_value=default, description=description)
            for name, (default, description) in arguments.items()]


def launch_nodes(specs: list[NodeSpec]) -> dict[str, Any]:
    """One launch_ros ``Node`` per spec, by node name."""
    import os

    from launch_ros.actions import Node

    from .bringup import loopback_settings

    env = loopback_settings(os.environ)  # this machine only (bringup.loopback_settings)
    nodes = {}
    for spec in specs:
        parameters: list[Any] = [spec.params_file] if spec.params_file else []
        if spec.parameters:
            parameters.append(dict(spec.parameters))
        nodes[spec.name] = Node(package=spec.package, executable=spec.executable,
                                name=spec.name, output='screen', parameters=parameters,
                                ros_arguments=list(spec.ros_args) or None,
                                additional_env=env or None)
    return nodes


def stop_in_order(nodes: dict[str, Any], first: str) -> list[Any]:
    """Event handlers: ``first`` exiting interrupts the next node of :data:`STOP_ORDER`, ...

    The controller stops before the recorder (the bag holds its zero command); when the last
    one has exited, launch shuts down.
    """
    from launch.actions import EmitEvent, RegisterEventHandler
    from launch.event_handlers import OnProcessExit
    from launch.events import Shutdown, matches_action
    from launch.events.process import SignalProcess

    chain = [n for n in STOP_ORDER[STOP_ORDER.index(first):] if n in nodes]
    handlers = []
    for this, nxt in zip(chain, chain[1:] + [None], strict=True):
        if nxt is None:
            then = EmitEvent(event=Shutdown(reason=f'{this} exited'))
        else:
            then = EmitEvent(event=SignalProcess(signal_number=signal.SIGINT,
                                                 process_matcher=matches_action(nodes[nxt])))
        handlers.append(RegisterEventHandler(OnProcessExit(target_action=nodes[this],
                                                           on_exit=[then])))
    return handlers
