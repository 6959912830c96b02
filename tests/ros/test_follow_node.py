"""The follow node with the sim node over DDS: follow, LADRC, parameters, faults, stop."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
from ladrc_follow.bringup import SIM_TIMEOUT_S  # noqa: E402
from ladrc_msgs.msg import FollowEvent, FollowStatus, SimTruth, VelocityCommand  # noqa: E402
from ladrc_msgs.srv import StartFollow, StopFollow  # noqa: E402
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue  # noqa: E402
from rcl_interfaces.srv import GetParameters, SetParameters  # noqa: E402
from rosnodes import LATCHED, NodeProcesses, Probe  # noqa: E402

SCENARIOS = Path(__file__).parent / 'scenarios'
pytestmark = pytest.mark.ros
S = FollowStatus


def _status(m: FollowStatus) -> tuple:
    return (m.tick, m.state, m.followed, m.target_gap_mm, m.gap_seq, m.velocity_mm_s,
            m.fault_reason)


# The timeouts bring-up uses for simulated runs (three 2 kHz Python processes share 2 cores:
# docs/follow-node.md); the product defaults are 10 ms.
TIMEOUT_S = SIM_TIMEOUT_S


@pytest.fixture()
def axis(ros_context):
    nodes = NodeProcesses()
    nodes.start('follow', 'ladrc_follow', 'follow_node', '-p',
                f'follow.stale_timeout_s:={TIMEOUT_S}')
    nodes.start('sim', 'ladrc_sim', 'sim_node', '-p',
                f'scenario:={SCENARIOS / "follow_sine.yaml"}', '-p', 'wait_for_controller_s:=0.0',
                '-p', f'watchdog_timeout_s:={TIMEOUT_S}')
    probe = Probe(ros_context)
    try:
        yield nodes, probe
    finally:
        probe.close()
        nodes.close()


def _set_param(probe: Probe, name: str, value: float):
    req = SetParameters.Request(parameters=[Parameter(
        name=name, value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE,
                                        double_value=value))])
    return probe.call(SetParameters, '/ladrc_follow/set_parameters', req).results[0]


def _get_param(probe: Probe, name: str) -> float:
    res = probe.call(GetParameters, '/ladrc_follow/get_parameters',
                     GetParameters.Request(names=[name]))
    return res.values[0].double_value


def test_follow_ladrc_parameters_and_stop(axis):
    nodes, probe = axis
    status = probe.record(FollowStatus, 'follow/status', keep=_status)
    truth = probe.record(SimTruth, 'sim/truth', keep=lambda m: (m.seq, m.true_gap_mm))
    events = probe.record(FollowEvent, 'follow/events', qos=LATCHED)
    cmds = probe.record(VelocityCommand, 'axis/velocity_command',
                        keep=lambda m: (m.velocity_mm_s, m.enable))
    # the controller receives the sim (its status shows a sample seq) before follow starts
    assert probe.spin_until(
        lambda: len(status) > 200 and status[-1][4] > 0 and len(truth) > 200, 30.0), (
        nodes.log('follow') + nodes.log('sim'))
    assert status[-1][1] == S.STATE_IDLE and cmds[-1] == (0.0, False)

    res = probe.call(StartFollow, 'follow/start', StartFollow.Request(target_gap_mm=1.0))
    assert res.accepted, res.message
    assert probe.spin_until(lambda: status[-1][1] == S.STATE_LADRC, 20.0), (
        status[-1], [s for i, s in enumerate(status) if i and s[1] != status[i - 1][1]])
    states = [s[1] for s in status]
    seen = [st for i, st in enumerate(states) if i == 0 or st != states[i - 1]]
    assert seen[-4:] == [S.STATE_LOCKING, S.STATE_PREINTERPOLATE, S.STATE_PID,
                         S.STATE_LADRC] or seen[-3:] == [S.STATE_PREINTERPOLATE, S.STATE_PID,
                                                         S.STATE_LADRC]
    assert any(s[2] for s in status)  # followed before LADRC took over

    # Holds the gap on the sine sheet (0.3 mm, 1 Hz from t = 4 s of the scenario).
    probe.spin_until(lambda: truth[-1][0] > 2000 * 6.0, 30.0)
    n = len(truth)
    probe.spin_for(2.0)
    window = np.array([g for _, g in truth[n:]])
    assert window.size > 1000
    # Headless, this scenario holds |e| < 0.02 mm; live, three 2 kHz Python processes share two
    # cores and a scheduling stall of tens of ms shows up as a short error peak (bench/
    # loop_timing.py measures the stalls), so the test bounds the 95th percentile and the RMS.
    err = np.abs(window - 1.0)
    assert np.percentile(err, 95) < 0.1
    assert np.sqrt(np.mean(err ** 2)) < 0.1
    assert status[-1][1] == S.STATE_LADRC

    # A valid parameter change applies (and is logged as an event with the new set) ...
    kp = _get_param(probe, 'law.kp')
    ok = _set_param(probe, 'law.kp', kp * 1.2)
    assert ok.successful, ok.reason
    assert probe.spin_until(lambda: any(e.kind == FollowEvent.PARAMETERS
                                        and f'kp: {kp * 1.2}' in e.text for e in events), 5.0), (
        [(e.kind, e.tick) for e in events], kp)
    # ... a bad one is rejected with its reason and the running value stays.
    bad = _set_param(probe, 'eso.b0', 0.0)
    assert not bad.successful
    assert 'b0' in bad.reason
    assert _get_param(probe, 'law.kp') == pytest.approx(kp * 1.2)
    assert _get_param(probe, 'eso.b0') != 0.0

    # Stop: zero velocity, drive enable off, IDLE.
    assert probe.call(StopFollow, 'follow/stop', StopFollow.Request()).accepted
    assert probe.spin_until(lambda: status[-1][1] == S.STATE_IDLE, 5.0), status[-1]
    probe.spin_for(0.1)
    assert cmds[-1] == (0.0, False)
    assert nodes.interrupt('follow') == 0


def test_killing_the_sim_faults_the_controller_within_a_few_ticks(axis):
    nodes, probe = axis
    status = probe.record(FollowStatus, 'follow/status', keep=_status)
    cmds = probe.record(VelocityCommand, 'axis/velocity_command',
                        keep=lambda m: (m.seq, m.velocity_mm_s, m.enable))
    # the controller receives the sim (status shows a sample seq) before follow starts
    assert probe.spin_until(lambda: len(status) > 200 and status[-1][4] > 0, 30.0), (
        nodes.log('follow'))
    assert probe.call(StartFollow, 'follow/start', StartFollow.Request(target_gap_mm=1.0)).accepted
    assert probe.spin_until(lambda: status[-1][1] in (S.STATE_PID, S.STATE_LADRC), 20.0), (
        status[-1][6], status[-1][:3], nodes.log('sim')[-800:])

    nodes.kill('sim')
    assert probe.spin_until(lambda: status[-1][1] == S.STATE_FAULT, 5.0), status[-1]
    # ticks from the first tick that saw no new sample to the fault
    last_seq = status[-1][4]
    first_stale = next(i for i, s in enumerate(status) if s[4] == last_seq)
    first_fault = next(i for i, s in enumerate(status) if s[1] == S.STATE_FAULT)
    # the stale limit in ticks, plus a margin for the sim's last samples still in flight
    assert status[first_fault][0] - status[first_stale][0] <= TIMEOUT_S / 0.0005 + 20
    assert status[first_fault][6]  # a readable reason
    probe.spin_for(0.05)
    assert all(v == 0.0 for _, v, _ in cmds[-20:])
    assert not cmds[-1][2]
