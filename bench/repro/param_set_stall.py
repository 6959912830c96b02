"""Repro (7): the CI failure of 2026-12-02, a parameter set while following faults the axis.

    python bench/repro/param_set_stall.py [--checkout DIR] [--runs 5] [--sets 5]

``tests/ros/test_follow_node.py::test_a_parameter_set_while_following_does_not_hold_up_the_loop``
failed in CI on ae98e82 with ``(11206, 5, 510.9, 'encoder position not finite (nan)', 8287)``:
the follow node was in FAULT during the parameter sets. This script plays the test's part with
its own probe (tests/support/rosnodes.py of the checkout): the sim and the follow node of
``--checkout`` with the test's 25 ms stale limit and drive watchdog (the stamp tolerance left at
the product's 10 ms, as that test had it), start follow, wait for LADRC, then ``--sets``
requests of three parameters (``law.kp`` stepped 2 % each, ``eso.w0_rad_s``, ``pid.kp_1_s``),
and reports per run: the largest tick period during the sets, the follow node's fault reason
if any, and the sim's watchdog trips.

Cause found with it (docs/follow-node.md, "Parameters"): the set's stability gate ran on the
node's parameter thread and held the interpreter lock up to ~10 ms at a stretch (numpy/LAPACK
calls inside the analysis; a 0.1 ms switch interval does not preempt a C call), so the loop
thread stalled 45-91 ms while five sets were checked; the samples that arrived meanwhile were
judged against the node clock when the loop finally took them, more than 10 ms after their
stamps, so the encoder position was rejected as implausible (NaN) and the core faulted. Fixed
by running the gate in a worker process (``node/gate_process.py``) and judging a stamp against
its middleware reception time (``node/samples.py``). Last stdout line: JSON.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import sys
import time

ROOT = Path(__file__).resolve().parents[2]


def one_run(checkout: Path, sets: int) -> dict:
    """Play the test once against ``checkout``'s nodes; return what happened."""
    sys.path[:0] = [str(checkout / 'tests' / 'support'), str(checkout / 'tests' / 'ros')]
    import conftest  # noqa: F401 - the test domain and the loopback profile
    from ladrc_msgs.msg import FollowStatus
    from ladrc_msgs.srv import StartFollow
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import GetParameters, SetParameters
    from rosnodes import NodeProcesses, Probe

    scenario = checkout / 'tests' / 'ros' / 'scenarios' / 'follow_sine.yaml'
    nodes = NodeProcesses()
    nodes.start('follow', 'ladrc_follow', 'follow_node', '-p', 'follow.stale_timeout_s:=0.025')
    nodes.start('sim', 'ladrc_sim', 'sim_node', '-p', f'scenario:={scenario}', '-p',
                'wait_for_controller_s:=0.0', '-p', 'watchdog_timeout_s:=0.025')
    probe = Probe()
    out: dict = {}
    try:
        status = probe.record(FollowStatus, 'follow/status',
                              fields=['tick', 'state', 'period_us', 'fault_reason', 'gap_seq'])
        probe.spin_until(lambda: len(status) > 200 and status[-1][4] > 0, 30.0)
        probe.call(StartFollow, 'follow/start', StartFollow.Request(target_gap_mm=1.0))
        probe.spin_until(lambda: status[-1][1] in (FollowStatus.STATE_LADRC,
                                                   FollowStatus.STATE_FAULT), 30.0)

        def set_params(values: dict) -> list:
            req = SetParameters.Request(parameters=[Parameter(
                name=n, value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE,
                                             double_value=v)) for n, v in values.items()])
            return probe.call(SetParameters, '/ladrc_follow/set_parameters', req).results

        def get(name: str) -> float:
            return probe.call(GetParameters, '/ladrc_follow/get_parameters',
                              GetParameters.Request(names=[name])).values[0].double_value

        kp, w0, pid_kp = get('law.kp'), get('eso.w0_rad_s'), get('pid.kp_1_s')
        set_params({'law.kp': kp})
        probe.spin_for(1.0)
        first = len(status)
        t0 = time.monotonic()
        for k in range(1, sets + 1):
            set_params({'law.kp': kp * (1 + 0.02 * k), 'eso.w0_rad_s': w0, 'pid.kp_1_s': pid_kp})
        sets_s = time.monotonic() - t0
        probe.spin_for(1.0)
        window = status[first:]
        faults = [s for s in window if s[1] == FollowStatus.STATE_FAULT]
        out = {'ticks': len(window), 'sets_s': round(sets_s, 2),
               'period_max_ms': round(max(s[2] for s in window) * 1e-3, 2),
               'fault': faults[0][3] if faults else ''}
    finally:
        probe.close()
        nodes.close()
        sim_log = nodes.log('sim').splitlines()
        # the trip at the end is the test's teardown (the controller is interrupted first)
        out['watchdog_trips_before_teardown'] = max(
            0, sum('watchdog:' in line for line in sim_log) - 1)
    return out


def main() -> int:
    """Run the repro; last line JSON."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--checkout', type=Path, default=ROOT,
                    help='the checkout whose nodes run (its scripts/in-env environment)')
    ap.add_argument('--runs', type=int, default=5)
    ap.add_argument('--sets', type=int, default=5)
    ap.add_argument('--one', action='store_true', help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one:
        print(json.dumps(one_run(a.checkout.resolve(), a.sets)))
        return 0
    import subprocess

    runs = []
    for i in range(a.runs):
        r = subprocess.run([str(a.checkout / 'scripts' / 'in-env'), 'python', __file__, '--one',
                            '--checkout', str(a.checkout), '--sets', str(a.sets)],
                           capture_output=True, text=True, env=dict(os.environ))
        last = (r.stdout.strip().splitlines() or ['{}'])[-1]
        run = json.loads(last) if last.startswith('{') else {'error': r.stderr[-400:]}
        print(f'run {i + 1}: {run}', file=sys.stderr)
        runs.append(run)
    print(json.dumps({'checkout': str(a.checkout), 'runs': runs,
                      'faulted': sum(bool(r.get('fault')) for r in runs)}))
    return 0


if __name__ == '__main__':
    sys.exit(main())
