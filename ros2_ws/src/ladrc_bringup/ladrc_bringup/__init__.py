"""Bring-up: the product's node processes, started and stopped in order on an isolated DDS domain.

:mod:`.bringup` (the node specs, the process supervision, the ``bringup`` command),
:mod:`.launching` (the same specs as launch_ros actions for ``launch/*.launch.py``),
:mod:`.demo` (``make demo``: a bring-up and its report), :mod:`.linuxcnc_run` (``bringup --cnc
linuxcnc``), :mod:`.cia402_stack` (the emulated CiA 402 drive and its driver node), and the
commissioning runs that start node processes: :mod:`.conform_run` with its probe
:mod:`.conform_node` (``ladrc conform``), :mod:`.calibrate_node` (``ladrc calibrate``), both
registered with ``ladrc`` by :mod:`.cli`. The shipped configuration is in ``config/``
(installed to ``share/ladrc_bringup/config``).
"""

from __future__ import annotations

from .bringup import (
    MIDDLEWARE_KEYS,
    Bringup,
    NodeSpec,
    axis_node_specs,
    default_params_file,
    executable_path,
    interrupt_process,
    isolated_env,
    loopback_settings,
    node_specs,
    view_spec,
)

__all__ = ['MIDDLEWARE_KEYS', 'Bringup', 'NodeSpec', 'axis_node_specs', 'default_params_file',
           'executable_path', 'interrupt_process', 'isolated_env', 'loopback_settings',
           'node_specs', 'view_spec']
