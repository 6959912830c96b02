"""The controller's own topology: who else publishes on its command and sensor topics.

One commander (docs/interfaces.md): the drive refuses a second commander's messages; the
controller checks from its side too, from the ROS graph. Another publisher on its command topic
(besides this node's own), or more than one publisher on a sensor topic, is a problem with the
publishers' names. Graph queries, checked by the parameter thread every ``TOPOLOGY_PERIOD_S``
(never on the tick path); the follow node turns a problem into a FAULT at its next tick.
"""

from __future__ import annotations

from typing import Any

TOPOLOGY_PERIOD_S = 0.2
"""How often the graph is checked (discovery itself takes longer: a new publisher is seen once
its participant is discovered)."""


def _names(infos: list[Any]) -> list[str]:
    return sorted('/'.join((i.node_namespace.rstrip('/'), i.node_name)) for i in infos)


def topology_problems(node: Any, command_topic: str, sensor_topics: list[str]) -> list[str]:
    """Return what is wrong with the publishers around ``node`` (empty: nothing).

    ``node``: the controller's rclpy node, which publishes on ``command_topic`` itself.
    """
    out = []
    topic = node.resolve_topic_name(command_topic)
    publishers = node.get_publishers_info_by_topic(topic)
    if len(publishers) > 1:
        names = _names(publishers)
        own = node.get_fully_qualified_name()
        if own in names:
            names.remove(own)  # one of them is this controller's
        out.append(f'another publisher on {topic}: {", ".join(names)} (besides this '
                   'controller; the drive executes one commander)')
    for sensor in sensor_topics:
        topic = node.resolve_topic_name(sensor)
        publishers = node.get_publishers_info_by_topic(topic)
        if len(publishers) > 1:
            out.append(f'{len(publishers)} publishers on {topic}: '
                       f'{", ".join(_names(publishers))} (one driver only)')
    return out
