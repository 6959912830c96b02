"""The follow commands as services, one table (docs/interfaces.md, "Follow commands").

The controller serves them, the sim plays a scenario's commands through them. Each follow
command of ``FollowController.command`` is a service on the controller: its type, its name, and
which request field carries each keyword argument. The types are named, not imported, so the
table reads without ROS; a node resolves them (:func:`service_class`).
"""

from __future__ import annotations

import importlib
from typing import Any

FOLLOW_SERVICES: dict[str, tuple[str, str, dict[str, str]]] = {
    'start_follow': ('ladrc_msgs/srv/StartFollow', 'follow/start',
                     {'target_gap_mm': 'target_gap_mm'}),
    'stop_follow': ('ladrc_msgs/srv/StopFollow', 'follow/stop', {}),
    'set_target': ('ladrc_msgs/srv/SetTarget', 'follow/set_target',
                   {'target_gap_mm': 'target_gap_mm'}),
    'machining': ('ladrc_msgs/srv/SetMachining', 'follow/set_machining', {'on': 'machining'}),
    'height_compensation': ('ladrc_msgs/srv/HeightCompensation', 'follow/height_compensation',
                            {'offset_mm': 'offset_mm', 'delay_s': 'delay_s'}),
    'gradient_follow': ('ladrc_msgs/srv/GradientFollow', 'follow/gradient_follow',
                        {'target_gap_mm': 'target_gap_mm', 'delay_s': 'delay_s',
                         'velocity_mm_s': 'velocity_mm_s', 'accel_mm_s2': 'accel_mm_s2'}),
    'reset_fault': ('ladrc_msgs/srv/ResetFault', 'follow/reset_fault', {}),
    'target_wave': ('ladrc_msgs/srv/TargetWave', 'follow/target_wave',
                    {'amp_mm': 'amp_mm', 'kind': 'kind', 'freq_hz': 'freq_hz',
                     'freq_end_hz': 'freq_end_hz', 'duration_s': 'duration_s'}),
    # the CNC interface (docs/interfaces.md, "CNC interface")
    'pierce': ('ladrc_msgs/srv/Pierce', 'follow/pierce',
               {'heights_mm': 'heights_mm', 'dwell_s': 'dwell_s', 'cut_gap_mm': 'cut_gap_mm',
                'thc_delay_s': 'thc_delay_s', 'locked': 'locked'}),
    'lift': ('ladrc_msgs/srv/Lift', 'follow/lift',
             {'mode': 'mode', 'value_mm': 'value_mm', 'velocity_mm_s': 'velocity_mm_s'}),
    'hold': ('ladrc_msgs/srv/Hold', 'follow/hold',
             {'hold': 'hold', 'at_next_segment': 'at_next_segment', 'reason': 'reason'}),
    'leapfrog': ('ladrc_msgs/srv/Leapfrog', 'follow/leapfrog',
                 {'lift_mm': 'lift_mm', 'rapid_length_mm': 'rapid_length_mm',
                  'rapid_feed_mm_s': 'rapid_feed_mm_s', 'arrive_height_mm': 'arrive_height_mm'}),
}
"""command name -> (service type, service name, {keyword argument: request field})."""


def service_class(typename: str) -> Any:
    """Return the generated class of ``pkg/srv/Name``."""
    pkg, _, name = typename.split('/')
    return getattr(importlib.import_module(f'{pkg}.srv'), name)


def command_args(name: str, request: Any) -> dict[str, Any]:
    """Return the keyword arguments of command ``name`` from its service ``request``.

    An array field (a pierce's stages) comes as a tuple of floats.
    """
    args = {kw: getattr(request, f) for kw, f in FOLLOW_SERVICES[name][2].items()}
    return {kw: tuple(float(x) for x in v) if hasattr(v, '__len__') and not isinstance(v, str)
            else v for kw, v in args.items()}


def fill_request(name: str, args: dict[str, Any]) -> Any:
    """Return the service request of command ``name`` with keyword arguments ``args``."""
    typename, _, fields = FOLLOW_SERVICES[name]
    request = service_class(typename).Request()
    for kw, value in args.items():
        f = fields[kw]
        if isinstance(value, (list, tuple)):
            setattr(request, f, [float(x) for x in value])  # an array field
        else:
            setattr(request, f, type(getattr(request, f))(value))
    return request
