"""The follow node with the sim node over DDS: follow, LADRC, parameters, faults, stop.

The behaviour test runs in lock step (docs/follow-node.md): the sim and the controller answer
each other step by step on the sim's clock, with the product's timeouts, so a loaded machine
makes it slower, never different. The kill test and the parameter test are real-time ones
(``realtime`` marker): they look at the ticks their subject concerns, not at a bound on how
long this machine may stall (bench/stalls.py measures that).
"""

from __future__ import annotations

import contextlib
import math
from pathlib import Path
import re
import sys

import numpy as np
import pytest

pytest.importorskip('ladrc_msgs', reason='needs the built workspace (make test)')
from ladrc_msgs.msg import (  # noqa: E402
    CapacitiveHeight,
    CncMotion,
    FollowEvent,
    FollowStatus,
    SimTruth,
    VelocityCommand,
)
from ladrc_msgs.srv import Hold, Pierce, ResetFault, StartFollow, StopFollow  # noqa: E402
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue  # noqa: E402
from rcl_interfaces.srv import GetParameters, SetParameters  # noqa: E402
from rosnodes import LATCHED, RELIABLE, NodeProcesses, Probe  # noqa: E402

SCENARIOS = Path(__file__).parent / 'scenarios'
pytestmark = pytest.mark.ros
S = FollowStatus


# the recorded fields of follow/status: (tick, state, followed, target, gap seq, velocity, reason,
# t_s, gap stamp)
STATUS = ['tick', 'state', 'followed', 'target_gap_mm', 'gap_seq', 'velocity_mm_s',
          'fault_reason', 't_s', 'gap_stamp_s']


KILL_TIMEOUT_S = 0.01  # the product's default stale limit (docs/parameters.md)
STAMP_TOLERANCE_S = 0.01  # the product's default (the node's stamp_tolerance_s)
# The real-time parameter test's stale limit, stamp tolerance and drive watchdog: the schema's
# largest (100 ms), beyond any stall, so that what it asserts is the loop's period (the sets'
# builds, BUILD_MIN_S), not whether a stall of the machine happened to trip a limit. Two
# STALL_MAX_S (25 ms) is not enough: a loaded machine preempts the FIFO loop for longer with no
# set being built (the kernel's fair server, FIFO_STALL_MAX_S).
RT_TIMEOUT_S = 0.1
# A set built on the loop thread holds the tick after the one that applies it 7.9-15.9 ms
# (measured on a quiet machine by building it there: ``set_params`` in ``_apply_accepted``);
# built on the parameter thread, that tick's period is 0.8-1.8 ms (the loop waits for the GIL).
BUILD_MIN_S = 0.005
# A bound on a hang, not on speed: lock step is slower on a loaded machine, never different.
HANG_S = 300.0


def _axis(timeout_s: float | None):
    """Sim and follow node; ``timeout_s`` None: lock step with the product's defaults."""
    nodes = NodeProcesses()
    scenario = f'scenario:={SCENARIOS / "follow_sine.yaml"}'
    if timeout_s is None:
        nodes.start('follow', 'ladrc_follow', 'follow_node', '-p', 'loop:=lockstep')
        nodes.start('sim', 'ladrc_sim', 'sim_node', '-p', scenario, '-p', 'lockstep:=true',
                    '-p', 'realtime:=false')
    else:
        nodes.start('follow', 'ladrc_follow', 'follow_node', '-p',
                    f'follow.stale_timeout_s:={timeout_s}', '-p',
                    f'stamp_tolerance_s:={max(timeout_s, STAMP_TOLERANCE_S)}')
        nodes.start('sim', 'ladrc_sim', 'sim_node', '-p', scenario, '-p',
                    'wait_for_controller_s:=0.0', '-p', f'watchdog_timeout_s:={timeout_s}')
    try:
        return nodes, Probe()
    except BaseException:
        nodes.close()
        raise


def _running(timeout_s: float | None):
    nodes, probe = _axis(timeout_s)
    try:
        yield nodes, probe
    finally:
        try:
            probe.close()  # raises with the probe's exit and output if it did not end cleanly
        finally:
            nodes.close()


@pytest.fixture()
def axis():
    yield from _running(None)


@pytest.fixture()
def axis_rt():
    yield from _running(RT_TIMEOUT_S)


def _set_params(probe: Probe, values: dict[str, float]) -> list:
    req = SetParameters.Request(parameters=[Parameter(
        name=name, value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE,
                                        double_value=value)) for name, value in values.items()])
    return probe.call(SetParameters, '/ladrc_follow/set_parameters', req).results


def _set_param(probe: Probe, name: str, value: float):
    return _set_params(probe, {name: value})[0]


def _get_param(probe: Probe, name: str) -> float:
    res = probe.call(GetParameters, '/ladrc_follow/get_parameters',
                     GetParameters.Request(names=[name]))
    return res.values[0].double_value


def test_follow_ladrc_parameters_and_stop(axis):
    nodes, probe = axis
    # reliable readers of lock step's reliable writers: every message, in order
    status = probe.record(FollowStatus, 'follow/status', fields=STATUS, qos=RELIABLE)
    truth = probe.record(SimTruth, 'sim/truth', fields=['seq', 'true_gap_mm'], qos=RELIABLE)
    events = probe.record(FollowEvent, 'follow/events', qos=LATCHED)
    cmds = probe.record(VelocityCommand, 'axis/velocity_command',
                        fields=['velocity_mm_s', 'enable'], qos=RELIABLE)
    # the controller receives the sim (its status shows a sample seq) before follow starts
    assert probe.spin_until(
        lambda: len(status) > 200 and status[-1][4] > 0 and len(truth) > 200, HANG_S), (
        nodes.log('follow') + nodes.log('sim'))
    assert status[-1][1] == S.STATE_IDLE and cmds[-1] == (0.0, False)

    res = probe.call(StartFollow, 'follow/start', StartFollow.Request(target_gap_mm=1.0))
    assert res.accepted, res.message
    assert probe.spin_until(lambda: status[-1][1] == S.STATE_LADRC, HANG_S), status[-1]

    # Hold the gap on the sine sheet (0.3 mm, 1 Hz from t = 4 s of the scenario), 6 s to 8 s of
    # the sim's time. The test decodes the recorded messages only after the run.
    assert probe.spin_until(lambda: truth[-1][0] > 2000 * 8.0, HANG_S), truth[-1]
    seqs = [s for s, _ in truth]
    n, m = seqs.index(2000 * 6), seqs.index(2000 * 8)
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
    # ... and a valid one whose loop fails the stability gate too, with its numbers.
    unstable = _set_param(probe, 'law.kp', 60.0)
    assert not unstable.successful
    assert 'stability gate' in unstable.reason and 'phase margin' in unstable.reason
    assert _get_param(probe, 'law.kp') == pytest.approx(kp * 1.2)

    # Stop: zero velocity, drive enable off, IDLE.
    assert probe.call(StopFollow, 'follow/stop', StopFollow.Request()).accepted
    assert probe.spin_until(lambda: status[-1][1] == S.STATE_IDLE, HANG_S), status[-1]
    tick = status[-1][0]
    assert probe.spin_until(lambda: status[-1][0] > tick + 20, HANG_S)
    assert cmds[-1] == (0.0, False)
    assert all(s[1] == S.STATE_IDLE for s in status if s[0] > tick)  # and it stays IDLE
    assert nodes.interrupt('follow') == 0
    nodes.interrupt('sim')

    # The state sequence of the start: LOCKING -> PREINTERPOLATE -> PID -> LADRC, followed first.
    states = [s[1] for s in status]
    seen = [st for i, st in enumerate(states) if i == 0 or st != states[i - 1]]
    assert seen[:5] == [S.STATE_IDLE, S.STATE_LOCKING, S.STATE_PREINTERPOLATE, S.STATE_PID,
                        S.STATE_LADRC], seen
    first_ladrc = states.index(S.STATE_LADRC)
    assert status[first_ladrc][2]  # LADRC takes over at the tick the follow is reached
    assert not any(s[2] for s in status[:first_ladrc])
    # The gap held on the sine: in lock step the loop is the headless runner's, |e| < 0.02 mm
    # at every tick (headless holds the same), whatever the machine's load
    err = np.abs(np.array([g for _, g in truth[n:m]]) - 1.0)
    assert err.size == 2000 * 2
    assert err.max() < 0.02, (err.max(), [s for s in seen if s != S.STATE_LADRC])



CNC_STATUS = ['tick', 'state', 'substate', 'hold_reason', 'in_position', 'ready_to_move',
              'cnc_seq', 'gap_mm', 'feed_hold_request']


def test_the_cnc_interface_over_dds_pierce_hold_and_motion(axis):
    """Pierce from IDLE, a commanded hold and a CNC motion sample, through the node's services."""
    nodes, probe = axis
    status = probe.record(FollowStatus, 'follow/status', fields=CNC_STATUS, qos=RELIABLE)
    events = probe.record(FollowEvent, 'follow/events', qos=LATCHED)
    assert probe.spin_until(lambda: len(status) > 200 and status[-1][1] == S.STATE_IDLE,
                            HANG_S), nodes.log('follow') + nodes.log('sim')
    bad = probe.call(Pierce, 'follow/pierce', Pierce.Request(
        heights_mm=[], dwell_s=[], cut_gap_mm=1.0, thc_delay_s=0.0))
    assert not bad.accepted and 'stages' in bad.message
    res = probe.call(Pierce, 'follow/pierce', Pierce.Request(
        heights_mm=[2.0], dwell_s=[0.1], cut_gap_mm=1.0, thc_delay_s=0.05))
    assert res.accepted, res.message
    assert probe.spin_until(lambda: status[-1][1] == S.STATE_LADRC and status[-1][2] == 0
                            and status[-1][4], HANG_S), status[-1]
    assert any(e.kind == FollowEvent.PIERCE and e.value_mm == 1.0 for e in events)
    rows = list(status)
    dwell = [r for r in rows if 'dwell' in r[3]]
    thc = [r for r in rows if r[2] == S.SUB_THC_DELAY]
    assert abs(len(dwell) - 200) <= 2 and abs(len(thc) - 100) <= 2, (len(dwell), len(thc))
    assert all(abs(r[7] - 2.0) < 0.25 and r[4] for r in dwell[:-1])
    assert all(abs(r[7] - 1.0) < 0.1 for r in thc)
    assert not any(r[5] for r in rows if r[2] == S.SUB_PIERCE and 'dwell' in r[3])
    # a commanded hold, and its release
    ok = probe.call(Hold, 'follow/hold', Hold.Request(hold=True, at_next_segment=False,
                                                      reason='test hold'))
    assert ok.accepted, ok.message
    assert probe.spin_until(lambda: status[-1][2] == S.SUB_HOLD, HANG_S), status[-1]
    assert status[-1][3] == 'test hold'
    assert probe.call(Hold, 'follow/hold', Hold.Request(hold=False)).accepted
    assert probe.spin_until(lambda: status[-1][2] == S.SUB_NONE, HANG_S), status[-1]
    # a CNC motion sample reaches the tick; stamped 0, it is stale at once: held, with why
    probe.publish(CncMotion, 'cnc/motion', {'seq': 7, 'segment': CncMotion.SEGMENT_CUT,
                                             'beam_on': True, 'commanded_feed_mm_s': 100.0,
                                             'actual_feed_mm_s': 100.0,
                                             'edge_ahead_mm': math.inf}, qos=10)
    assert probe.spin_until(lambda: status[-1][6] == 7 and status[-1][2] == S.SUB_HOLD,
                            HANG_S), status[-1]
    assert 'stale' in status[-1][3] and status[-1][1] == S.STATE_LADRC

@pytest.mark.realtime
def test_a_parameter_set_while_following_does_not_hold_up_the_loop(axis_rt):
    """A set is checked (stability gate ~10 ms) and built on the parameter thread, not the loop.

    On the loop thread each parameter of a set held it 10-21 ms (docs/safety.md), one
    request of three 30 ms or more: beyond the drive's 5 ms watchdog and a stall of this machine
    class (STALL_MAX_S, bench/stalls.py). rclpy checks a request's parameters one by one.
    """
    nodes, probe = axis_rt
    status = probe.record(FollowStatus, 'follow/status',
                          fields=['tick', 'state', 'period_us', 'fault_reason', 'gap_seq'])
    events = probe.record(FollowEvent, 'follow/events', qos=LATCHED)
    # the controller receives the sim (status shows a sample seq) before follow starts
    assert probe.spin_until(lambda: len(status) > 200 and status[-1][4] > 0, 30.0), (
        nodes.log('follow'))
    assert probe.call(StartFollow, 'follow/start', StartFollow.Request(target_gap_mm=1.0)).accepted
    assert probe.spin_until(lambda: status[-1][1] in (S.STATE_LADRC, S.STATE_FAULT), HANG_S)
    assert status[-1][1] == S.STATE_LADRC, (status[-1], nodes.log('sim')[-800:])
    # the probe's parameter clients exist before the measured sets (discovery is not the
    # subject here: the fault matrix's parameter-clients row is)
    kp, w0, pid_kp = (_get_param(probe, n) for n in ('law.kp', 'eso.w0_rad_s', 'pid.kp_1_s'))
    assert _set_param(probe, 'law.kp', kp).successful
    probe.spin_for(1.0)
    first = len(status)
    values = [kp * (1.0 + 0.02 * k) for k in range(1, 6)]
    for value in values:
        results = _set_params(probe, {'law.kp': value, 'eso.w0_rad_s': w0,
                                      'pid.kp_1_s': pid_kp})
        assert all(r.successful for r in results), [r.reason for r in results]
    # each applies (the last one's set is published with the tick that applies it)
    assert probe.spin_until(lambda: any(e.kind == FollowEvent.PARAMETERS
                                        and f'kp: {values[-1]}' in e.text for e in events), 5.0)
    probe.spin_for(0.5)
    window = status[first:]
    assert len(window) > 1000
    assert all(s[1] == S.STATE_LADRC for s in window), next(
        s for s in window if s[1] != S.STATE_LADRC)
    # A build on the loop holds the tick that applies a set or the next one (BUILD_MIN_S).
    # rclpy checks a request's parameters one by one: each is a set, applied at a tick of its
    # own. Only those ticks are looked at, and most must be clear: another process on a loaded
    # machine stalls the loop 14-55 ms now and then (FIFO_STALL_MAX_S), at ticks of its own
    # choosing; that it lands on most applying ticks is not a risk.
    period_s = {s[0]: s[2] * 1e-6 for s in window}
    applied = [e.tick for e in events if e.kind == FollowEvent.PARAMETERS
               and any(f'kp: {v}' in e.text for v in values)]
    held = {t: (period_s.get(t), period_s.get(t + 1)) for t in applied}
    known = {t: max(p) for t, p in held.items() if None not in p}
    # (a best-effort status the probe missed is not known)
    assert len(known) >= len(values), held
    assert sum(p >= BUILD_MIN_S for p in known.values()) <= len(known) // 2, known
    assert 'watchdog:' not in nodes.log('sim')
    assert _get_param(probe, 'law.kp') == pytest.approx(values[-1])


# The longest a SCHED_FIFO loop is held up on a loaded machine: the kernel's fair server (Linux
# 6.12 on) runs starved normal tasks up to 50 ms a second over real-time ones, so tick periods
# reach 51-55 ms. Only a fallback bound: the kill test checks the tick before.
FIFO_STALL_MAX_S = 0.055
ATTEMPTS = 3


@pytest.mark.realtime
def test_killing_the_sim_faults_the_controller_within_a_few_ticks():
    """The sim SIGKILLed while following: stale input, FAULT at the first tick past the limit.

    The product's 10 ms limits, free-running: a stall of this machine past them before the
    kill trips the drive's watchdog first (the controller's FAULT is then the drive's fault
    report, not stale input). Such a run says nothing of the kill: the test
    starts again (ATTEMPTS at most), the sim's log naming the trip.
    """
    for attempt in range(1, ATTEMPTS + 1):
        with _axis_running(KILL_TIMEOUT_S) as (nodes, probe):
            fault = _kill_the_sim_while_following(nodes, probe)
            print(f'attempt {attempt}: {fault[6] if fault else "watchdog before the kill"}',
                  file=sys.stderr)
            if fault is not None:
                break
    assert fault is not None, f'the drive watchdog tripped before the kill in {ATTEMPTS} runs'


_axis_running = contextlib.contextmanager(_running)


def _kill_the_sim_while_following(nodes: NodeProcesses, probe: Probe) -> tuple | None:
    """Return the first FAULT status after the kill (None: the drive faulted before it)."""
    status = probe.record(FollowStatus, 'follow/status', fields=STATUS)
    cmds = probe.record(VelocityCommand, 'axis/velocity_command',
                        fields=['seq', 'velocity_mm_s', 'enable'])
    # the controller receives the sim (status shows a sample seq) before follow starts
    assert probe.spin_until(lambda: len(status) > 200 and status[-1][4] > 0, 30.0), (
        nodes.log('follow'))
    assert probe.call(StartFollow, 'follow/start', StartFollow.Request(target_gap_mm=1.0)).accepted
    assert probe.spin_until(lambda: status[-1][1] in (S.STATE_PID, S.STATE_LADRC, S.STATE_FAULT),
                            HANG_S), (status[-1][6], status[-1][:3], nodes.log('sim')[-800:])

    nodes.kill('sim')
    assert probe.spin_until(lambda: status[-1][1] == S.STATE_FAULT, HANG_S), status[-1]
    i, fault = next((i, s) for i, s in enumerate(status) if s[1] == S.STATE_FAULT)
    if 'stale input' not in fault[6] and 'watchdog:' in nodes.log('sim'):
        print(f'the drive watchdog tripped before the kill: {fault[6]}', file=sys.stderr)
        probe.spin_for(3.0)  # (the teardown after a SIGKILL, below)
        return None
    assert 'stale input' in fault[6]  # a readable reason
    # The fault comes at the first tick whose older input is past the limit. The probe may
    # miss status messages (best effort); where it has the fault tick and the one before, the
    # ages at that one (the fault's, less the time between the two ticks) were within the
    # limit (0.1 ms: the reason's 3 digits). Else: the limit, one own-deadline tick (the
    # sync loop's 0.75 ms) and one stall of the loop (FIFO_STALL_MAX_S).
    ages_s = [float(a) * 1e-3 for a in re.search(
        r'gap age ([0-9.eE+-]+) ms, encoder age ([0-9.eE+-]+) ms', fault[6]).groups()]
    assert max(ages_s) > KILL_TIMEOUT_S - 0.0001, fault[6]
    before = status[i - 1] if i > 0 else None
    if before is not None and before[0] == fault[0] - 1:
        ages_before_s = [a - (fault[7] - before[7]) for a in ages_s]
        assert max(ages_before_s) <= KILL_TIMEOUT_S + 0.0001, (ages_before_s, fault[6])
    else:
        assert max(ages_s) < KILL_TIMEOUT_S + 0.00075 + FIFO_STALL_MAX_S, fault[6]
    probe.spin_for(0.05)
    assert all(v == 0.0 for _, v, _ in cmds[-20:])
    assert not cmds[-1][2]
    # the sim was SIGKILLed: Fast DDS 2.14 replaces the shared-memory port it may have left
    # locked about a second later; the probe's teardown waits for that (a teardown inside the
    # window can crash: tests/support/probe_node.py)
    probe.spin_for(3.0)
    return fault


@pytest.mark.parametrize('topic, msg_type, fields, expect', [
    ('axis/velocity_command', VelocityCommand, {}, 'another publisher on /axis/velocity_command'),
    # a reading nobody can use (NaN, invalid, out of range): a loaded machine may let a tick
    # take it before the sim's next sample (seen once: a default 0.0 mm reading was a
    # collision, rightly, after the topology fault)
    ('axis/capacitive_height', CapacitiveHeight,
     {'gap_mm': math.nan, 'valid': False, 'status': CapacitiveHeight.STATUS_OUT_OF_RANGE},
     '2 publishers on /axis/capacitive_height'),
])
def test_a_second_publisher_on_a_contract_topic_faults_the_controller(axis, topic, msg_type,
                                                                      fields, expect):
    """The controller's topology check (node/topology.py): a FAULT naming the publishers."""
    nodes, probe = axis
    status = probe.record(FollowStatus, 'follow/status', fields=STATUS, qos=RELIABLE)
    assert probe.spin_until(lambda: len(status) > 200 and status[-1][4] > 0, HANG_S), (
        nodes.log('follow') + nodes.log('sim'))
    assert status[-1][1] == S.STATE_IDLE
    # one message, at rest (zero velocity, enable false): who publishes is the fault, not what
    probe.publish(msg_type, topic, fields, qos=10)
    assert probe.spin_until(lambda: status[-1][1] == S.STATE_FAULT, 20.0), (
        status[-1], nodes.log('sim')[-1500:], nodes.log('follow')[-1500:])
    reason = status[-1][6]
    # the topology fault, as such or inside a later one's reason ('... while in FAULT (...)')
    assert 'topology: ' in reason and expect in reason, reason
    assert '/ladrc_probe' in reason or 'probe' in reason, reason
    # while it lasts, a reset does not clear it
    probe.call(ResetFault, 'follow/reset_fault', ResetFault.Request())
    tick = status[-1][0]
    assert probe.spin_until(lambda: status[-1][0] > tick + 50, HANG_S)
    assert status[-1][1] == S.STATE_FAULT
