"""The follow node's ROS parameters: its own and the controller's, as ROS declares them.

:class:`NodeParams` are the node's start-up settings; ``descriptor`` and ``ros_value``
(``ladrc_contract/ros_params.py``) turn the one declaration of each controller parameter
(``ladrc_contract/schema.py``) into its ROS descriptor and value; :func:`params_file_problem`
reads ``--params-file`` before rcl does.
"""

from __future__ import annotations

from dataclasses import dataclass

from ladrc_contract.ros_params import descriptor, ros_value
from ladrc_contract.schema import param
import yaml

__all__ = ['LOOP_MODES', 'NodeParams', 'descriptor', 'ros_value', 'params_file_problem']

LOOP_MODES = ('sync', 'deadline', 'lockstep')


@dataclass(frozen=True)
class NodeParams:
    """Parameters of the node itself (not of the controller), fixed at start-up."""

    loop: str = param('deadline', '', "tick source: 'sync' (one tick per new sensor sample "
                      "pair, own deadline when one is late), 'deadline' (own 0.5 ms deadline "
                      "loop) or 'lockstep' (one tick per step of the sim node, on its clock; "
                      "the sim node only)",
                      choices=LOOP_MODES, runtime=False)
    sync_wait_s: float = param(0.00025, 's', "loop 'sync': a tick waits for a new sample of "
                               'both inputs at most one period plus this long after the '
                               'previous tick, then runs on its own deadline with what it '
                               'has (docs/follow-node.md)', gt=0.0, le=0.005, runtime=False)
    sample_period_tolerance: float = param(0.25, '1', "loop 'sync': the senders' sample "
                                           'period, measured from their seq over 2 s of '
                                           'receive time, may differ from h_s by this '
                                           'fraction; more is a FAULT (the core is '
                                           'discretised at h_s)', gt=0.0, le=0.9,
                                           runtime=False)
    lockstep_timeout_s: float = param(10.0, 's', "loop 'lockstep': no step from the sim for "
                                      'this long (wall clock) after the first one is a FAULT',
                                      gt=0.0, le=600.0, runtime=False)
    stamp_tolerance_s: float = param(0.01, 's', 'a sample whose sender stamp differs from '
                                     'its receive time by more than this (either way) is '
                                     'invalid: transport delay plus the clock offset of driver '
                                     'and controller must stay below it (docs/follow-node.md)',
                                     gt=0.0, le=1.0, runtime=False)
    diagnostics_period_s: float = param(1.0, 's', 'period of /diagnostics', ge=0.05, le=60.0,
                                        runtime=False)
    thread_priority: int = param(50, '1', 'SCHED_FIFO priority of the loop thread; 0 = the '
                                 'normal scheduler (a refusal is a warning, node/realtime.py)',
                                 ge=0, le=99, runtime=False)
    cpu: int = param(-1, '1', 'pin the process to this CPU; -1 = any', ge=-1, le=1023,
                     runtime=False)
    lock_memory: bool = param(True, '', 'mlockall: no page faults on the tick path',
                              runtime=False)
    hardware_id: str = param('z_axis', '', 'hardware_id of the /diagnostics status (named '
                             'after the node: <namespace/name>: follow loop)', runtime=False)
    summary_file: str = param('', '', 'at exit, write the run (faults with reason and input '
                              'ages, holds, time per state, final state) as JSON to this file; '
                              "'' writes none (the log line is always written)", runtime=False)


def params_file_problem(args: list[str]) -> str:
    """Return why a ``--params-file`` of the command line cannot be read ('' when all can).

    rcl would refuse a malformed file with a log line of its own and an exception; reading the
    files first gives the user one line that names the file.
    """
    for flag, path in zip(args, args[1:], strict=False):
        if flag != '--params-file':
            continue
        try:
            with open(path, encoding='utf-8') as f:
                yaml.safe_load(f)
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
            return f'parameter file {path}: ' + ' '.join(str(exc).split())
    return ''
