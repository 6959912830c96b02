"""The conformance rules on synthetic recordings (pure, fast).

A clean synthetic drive (2 kHz, stamps and seq right, moves as commanded, watchdog after 5 ms)
passes every rule; each defect of the live broken driver (and a few more) fails exactly the
rules that say so, with the measured figure.
"""

from __future__ import annotations

import dataclasses
import json

from ladrc_tools.commissioning.conformance import (
    AFTER_RESET,
    COMMAND_TOPIC,
    DOWN,
    ENABLE,
    FAULT_HOLDS,
    FEEDBACK_TOPIC,
    GAP_TOPIC,
    PASSIVE,
    RESET_CALL,
    RULE_NAMES,
    RULES,
    SECOND_COMMANDER,
    SILENCE,
    UP,
    WATCHDOG,
    BagCheck,
    ConformanceResult,
    Endpoint,
    FeedbackSamples,
    GapSamples,
    Graph,
    Plan,
    Recording,
    Segment,
    Tolerances,
    compatible,
    evaluate,
    markdown,
    sim_scenario_yaml,
)
import numpy as np
import pytest

H = 0.0005
T0 = 1_800_000_000 * 10**9
V = 2.0
# name, start s, end s, command mm/s, enable, commanded
PLAN = [(PASSIVE, 0.0, 1.0, 0.0, False, False), (ENABLE, 1.0, 1.3, V, False, True),
        ('settle', 1.3, 1.5, 0.0, True, True), (UP, 1.5, 2.0, V, True, True),
        (DOWN, 2.0, 2.5, -V, True, True), ('settle', 2.5, 2.7, 0.0, True, True),
        (SECOND_COMMANDER, 2.7, 2.72, 0.0, True, True), (FAULT_HOLDS, 2.72, 2.92, 0.0, True, True),
        (RESET_CALL, 2.92, 2.95, 0.0, True, True), (AFTER_RESET, 2.95, 3.2, 0.0, True, True),
        (WATCHDOG, 3.2, 3.5, V, True, True), (SILENCE, 3.5, 3.7, 0.0, False, False)]
END_S = 3.8
LAST_CMD_S = 3.5
OWNER, SECOND = '/ladrc_conform', '/ladrc_conform_second_commander'
LOCK_REASON = (f"second commander: a velocity command from '{SECOND}' (session 7) while "
               f"'{OWNER}' (session 5) commands the axis; not executed, quick stop until the "
               'drive is reset')


def _ns(t_s):
    return T0 + np.round(np.asarray(t_s) * 1e9).astype(np.int64)


def synthetic(*, sign=1.0, gap_scale=1.0, future_s=0.0, watchdog=True, seq_skip=0,
              reliable=False, ignore_enable=False, speed_scale=1.0, velocity_scale=1.0,
              rate_hz=2000.0, age_s=1e-4, fault_delay_s=0.0055, fault_reason='watchdog: no '
              'command for 11 cycles', bag_missing=0, commander_lock=True,
              lock_reason=LOCK_REASON, lock_clears_s=None, reset='accepted: drive reset',
              seed=0):
    """Return a Recording of a synthetic drive (clean unless a defect is asked for)."""
    rng = np.random.default_rng(seed)
    h = 1.0 / rate_hz
    t = np.arange(0.0, END_S, h)
    n = len(t)
    v_cmd = np.zeros(n)
    for _name, a, b, v, en, commanded in PLAN:
        if commanded and (en or ignore_enable):
            v_cmd[(t >= a) & (t < b)] = v
    last_cmd = LAST_CMD_S
    t_fault = last_cmd + fault_delay_s
    v_act = sign * speed_scale * v_cmd
    if watchdog:
        v_act[(t >= last_cmd) & (t < t_fault)] = sign * speed_scale * V  # the ZOH until the trip
    else:
        v_act[t >= last_cmd] = sign * speed_scale * V
    pos = 5.0 + np.concatenate(([0.0], np.cumsum(v_act[:-1]) * h))
    pos = np.round(pos / 0.001) * 0.001  # 1 µm encoder
    gap = (pos - 5.0 + 5.0 + rng.normal(0.0, 0.003, n)) * gap_scale
    stamp = _ns(t + future_s)
    recv = _ns(t + age_s + rng.exponential(5e-5, n))
    seq = np.arange(n) + 100
    seq = seq + (seq // seq_skip if seq_skip else 0)
    fault = (t >= t_fault) if watchdog else np.zeros(n, dtype=bool)
    reasons = np.where(fault, fault_reason, '').astype(object)
    second = (t >= 2.7) & (t < 2.72)
    if commander_lock:  # faulted from the drive cycle after the first foreign command to reset
        lock = (t >= 2.7 + h) & (t < (2.95 if lock_clears_s is None else 2.7 + lock_clears_s))
        fault |= lock
        reasons[lock] = lock_reason
    else:  # executed: the second commander's upward command is the latest in each cycle
        v_act[second] = sign * speed_scale * V
        pos = 5.0 + np.concatenate(([0.0], np.cumsum(v_act[:-1]) * h))
        pos = np.round(pos / 0.001) * 0.001
        gap = (pos - 5.0 + 5.0 + rng.normal(0.0, 0.003, n)) * gap_scale
    fb = FeedbackSamples(recv_ns=recv, stamp_ns=stamp, seq=seq, pub_seq=np.arange(n) + 1,
                         position_mm=pos, velocity_mm_s=v_act * velocity_scale,
                         drive_enabled=np.ones(n, bool), drive_fault=fault,
                         fault_reason=list(reasons))
    gp = GapSamples(recv_ns=recv + 1000, stamp_ns=stamp, seq=seq, pub_seq=np.arange(n) + 1,
                    gap_mm=gap, valid=np.ones(n, bool), status=np.zeros(n, int))
    rel = 'RELIABLE' if reliable else 'BEST_EFFORT'
    graph = Graph(
        publishers={GAP_TOPIC: [Endpoint('/drive', 'ladrc_msgs/msg/CapacitiveHeight', rel,
                                          'VOLATILE')],
                    FEEDBACK_TOPIC: [Endpoint('/drive', 'ladrc_msgs/msg/AxisFeedback', rel,
                                              'VOLATILE')],
                    COMMAND_TOPIC: []},
        subscriptions={COMMAND_TOPIC: [Endpoint('/drive', 'ladrc_msgs/msg/VelocityCommand',
                                                rel, 'VOLATILE')]})
    segments = [Segment(name, int(_ns(a)), int(_ns(b)), v, en, commanded)
                for name, a, b, v, en, commanded in PLAN]
    tc = np.arange(1.0, LAST_CMD_S, H)
    en = ~((tc >= 1.0) & (tc < 1.3))
    counts = {'/' + GAP_TOPIC: n, '/' + FEEDBACK_TOPIC: n, '/' + COMMAND_TOPIC: len(tc)}
    bag = BagCheck('bag', True, counts={k: c - (bag_missing if k.endswith('feedback') else 0)
                                        for k, c in counts.items()}, expected=counts)
    plan = dataclasses.replace(Plan(), excitation=None)
    return Recording(graph, gp, fb, _ns(tc), np.interp(tc, t, v_cmd), en, segments, plan,
                     bag=bag, commander=OWNER, second_commander=SECOND,
                     second_send_ns=_ns(np.arange(2.7, 2.72, H)), reset_answer=reset)


def failed(rec, tol=None):
    return set(evaluate(rec, tol).rules_failed)


def test_a_clean_drive_passes_every_rule_with_its_figures():
    result = evaluate(synthetic())
    assert result.passed, result.summary()
    assert [r.name for r in result.results] == list(RULE_NAMES)
    assert result['rate'].figure == pytest.approx(2000.0, rel=1e-3)
    assert result['motion_speed'].figure == pytest.approx(1.0, abs=0.01)
    assert result['gap_tracks_encoder'].figure == pytest.approx(1.0, abs=0.02)
    assert result['enable_false_holds'].figure == 0.0
    # 5.5 ms after the last command: 11 or 12 drive cycles of 0.5 ms
    assert 5.4 <= result['watchdog_fault'].figure <= 6.6
    assert result['watchdog_stop'].figure <= 7.0
    assert 0.5 <= result['one_commander'].figure <= 1.5  # the second cycle after the first send
    assert result['stamp_age'].figure < 1.0


@pytest.mark.parametrize('defect, kwargs, expected', [
    ('wrong_sign', {'sign': -1.0}, {'motion_direction'}),
    ('gap_um', {'gap_scale': 1000.0}, {'gap_tracks_encoder'}),
    ('future_stamps', {'future_s': 0.05}, {'stamps_not_future'}),
    ('no_watchdog', {'watchdog': False}, {'watchdog_fault', 'watchdog_stop'}),
    ('seq_gaps', {'seq_skip': 200}, {'seq_increments'}),
    ('reliable_only', {'reliable': True}, {'qos_publishers', 'qos_command_input'}),
    ('ignore_enable', {'ignore_enable': True}, {'enable_false_holds'}),
    ('any_commander', {'commander_lock': False}, {'one_commander'}),
])
def test_each_defect_fails_exactly_its_rules(defect, kwargs, expected):
    assert failed(synthetic(**kwargs)) == expected, defect


def test_figures_of_the_defects():
    r = evaluate(synthetic(sign=-1.0))
    assert r['motion_direction'].figure == pytest.approx(-1.0, abs=0.01)
    assert 'WRONG' in r['motion_direction'].reason
    r = evaluate(synthetic(gap_scale=1000.0))
    assert r['gap_tracks_encoder'].figure == pytest.approx(1000.0, rel=0.02)
    assert 'µm' in r['gap_tracks_encoder'].reason
    r = evaluate(synthetic(future_s=0.05))
    assert r['stamps_not_future'].figure == pytest.approx(50.0, abs=0.5)
    r = evaluate(synthetic(watchdog=False))
    assert 'no drive_fault' in r['watchdog_fault'].reason
    assert 'still moving' in r['watchdog_stop'].reason
    r = evaluate(synthetic(seq_skip=200))
    assert r['seq_increments'].figure > 0
    r = evaluate(synthetic(ignore_enable=True))
    assert r['enable_false_holds'].figure == pytest.approx(0.6, abs=0.02)
    r = evaluate(synthetic(reliable=True))
    assert 'never arrive' in r['qos_command_input'].reason
    r = evaluate(synthetic(commander_lock=False))
    assert 'no drive_fault' in r['one_commander'].reason
    assert 'moved 40 µm' in r['one_commander'].reason  # 20 ms at 2 mm/s, executed


@pytest.mark.parametrize('kwargs, why', [
    ({'lock_reason': 'drive fault'}, "does not name '/ladrc_conform' and "
                                     "'/ladrc_conform_second_commander'"),
    ({'lock_reason': LOCK_REASON.replace(SECOND, '/other')}, 'does not name '
                                                             "'/ladrc_conform_second_commander'"),
    ({'lock_clears_s': 0.1}, 'the fault cleared by itself 100 ms after'),
    ({'reset': ''}, 'axis/reset_drive: not called'),
    ({'reset': 'no axis/reset_drive service'}, 'axis/reset_drive: no axis/reset_drive service'),
    ({'reset': 'refused: no'}, 'axis/reset_drive: refused: no'),
    ({'lock_clears_s': 0.48}, 'still faulted 50 ms before the end of the 250 ms after the reset'),
])
def test_one_commander_fails_with_its_reason(kwargs, why):
    r = evaluate(synthetic(**kwargs))
    assert r.rules_failed == ['one_commander']
    assert why in r['one_commander'].reason


@pytest.mark.parametrize('kwargs, expected', [
    ({'speed_scale': 0.5}, {'motion_speed'}),               # b0 = 0.5: half the speed
    # command taken as µm/s: nothing moves, so nothing that needs motion can be judged
    ({'speed_scale': 0.001}, {'motion_speed', 'motion_direction', 'gap_tracks_encoder',
                              'velocity_feedback'}),
    ({'velocity_scale': 1000.0}, {'velocity_feedback'}),    # velocity in µm/s
    ({'velocity_scale': -1.0}, {'velocity_feedback'}),      # velocity sign
    ({'gap_scale': -1.0}, {'gap_tracks_encoder', 'drive_ready'}),  # reading falls as z rises
    ({'rate_hz': 1000.0}, {'rate'}),
    ({'age_s': 0.02}, {'stamp_age'}),
    ({'fault_delay_s': 0.02}, {'watchdog_fault', 'watchdog_stop'}),
    ({'fault_reason': ''}, {'watchdog_fault'}),
    ({'bag_missing': 3}, {'motion_bag'}),
])
def test_more_defects(kwargs, expected):
    assert failed(synthetic(**kwargs)) == expected


def test_jitter_and_stamp_order():
    rec = synthetic()
    fb = rec.feedback
    # a driver that publishes in bursts of 10 every 5 ms: right rate, wrong arrival
    fb.recv_ns = fb.recv_ns - (fb.recv_ns - fb.recv_ns[0]) % 5_000_000
    assert 'jitter' in failed(rec)
    rec = synthetic()
    rec.gap.stamp_ns[500] = rec.gap.stamp_ns[499]
    assert failed(rec) == {'stamps_monotonic'}


def test_a_backlog_after_a_stall_is_tolerated_a_late_driver_is_not():
    rec = synthetic()
    fb = rec.feedback
    # the host stalls 250 ms once: 2 % of the samples arrive at once, late
    i0, n = 2000, len(fb) // 50
    fb.recv_ns[i0:i0 + n] = fb.recv_ns[i0 + n]
    assert not failed(rec)
    rec = synthetic()
    rec.feedback.recv_ns[::10] += 20_000_000  # one sample in ten 20 ms late
    assert 'stamp_age' in failed(rec)
    rec = synthetic(age_s=0.003)  # 3 ms latch-to-arrival, always
    r = evaluate(rec)
    assert r.rules_failed == ['stamp_age']
    assert r['stamp_age'].figure == pytest.approx(3.05, abs=0.1)


def test_seq_without_the_dds_sequence_counts_every_jump():
    rec = synthetic()
    rec.feedback.pub_seq = None
    assert not failed(rec)
    keep = np.ones(len(rec.feedback), bool)
    keep[1000] = False  # one sample lost in transport: with pub_seq it is not the driver's
    rec2 = synthetic()
    for s in (rec2.feedback,):
        s.recv_ns, s.stamp_ns, s.seq, s.pub_seq = (s.recv_ns[keep], s.stamp_ns[keep],
                                                   s.seq[keep], s.pub_seq[keep])
        s.position_mm, s.velocity_mm_s = s.position_mm[keep], s.velocity_mm_s[keep]
        s.drive_enabled, s.drive_fault = s.drive_enabled[keep], s.drive_fault[keep]
        s.fault_reason = [r for r, k in zip(s.fault_reason, keep, strict=True) if k]
    rec2.bag.expected['/' + FEEDBACK_TOPIC] -= 1
    rec2.bag.counts['/' + FEEDBACK_TOPIC] -= 1
    r = evaluate(rec2)
    assert r.passed, r.summary()
    assert '1 lost in transport' in r['rate'].reason
    rec2.feedback.pub_seq = None
    assert failed(rec2) == {'seq_increments'}


def test_graph_rules():
    rec = synthetic()
    rec.graph.publishers[FEEDBACK_TOPIC] = [Endpoint('/drive', 'std_msgs/msg/Float64',
                                                     'BEST_EFFORT', 'VOLATILE')]
    rec.graph.publishers[COMMAND_TOPIC] = [Endpoint('/ladrc_follow',
                                                    'ladrc_msgs/msg/VelocityCommand',
                                                    'BEST_EFFORT', 'VOLATILE')]
    r = evaluate(rec)
    assert r.rules_failed == ['topics_types']
    assert 'std_msgs/msg/Float64' in r['topics_types'].reason
    assert '/ladrc_follow' in r['topics_types'].reason
    rec = synthetic()
    rec.graph.subscriptions[COMMAND_TOPIC] = [Endpoint('/drive', 'ladrc_msgs/msg/'
                                                       'VelocityCommand', 'BEST_EFFORT',
                                                       'TRANSIENT_LOCAL')]
    assert failed(rec) == {'qos_command_input'}
    rec = synthetic()
    rec.graph.publishers[GAP_TOPIC] = [Endpoint('/drive', 'ladrc_msgs/msg/CapacitiveHeight',
                                                'BEST_EFFORT', 'TRANSIENT_LOCAL')]
    assert failed(rec) == {'qos_publishers'}
    rec = synthetic()
    rec.graph = Graph()
    assert {'topics_types', 'qos_publishers', 'qos_command_input'} <= failed(rec)


def test_compatibility_is_the_dds_request_vs_offered_rule():
    be, rel = 'BEST_EFFORT', 'RELIABLE'
    vol, tl = 'VOLATILE', 'TRANSIENT_LOCAL'

    def ep(r, d):
        return Endpoint('n', 't', r, d)

    assert compatible(ep(rel, vol), ep(be, vol))[0]       # best-effort reader, reliable writer
    assert not compatible(ep(be, vol), ep(rel, vol))[0]   # reliable reader, best-effort writer
    assert compatible(ep(be, tl), ep(be, vol))[0]
    assert not compatible(ep(be, vol), ep(be, tl))[0]


def test_a_run_without_motion_fails_the_motion_rules_with_the_reason():
    rec = synthetic()
    rec.segments = rec.segments[:1]
    rec.not_run = 'the drive reports a fault: e-stop'
    r = evaluate(rec)
    motion = {'enable_false_holds', 'motion_direction', 'motion_speed', 'velocity_feedback',
              'gap_tracks_encoder', 'one_commander', 'watchdog_fault', 'watchdog_stop'}
    assert set(r.rules_failed) == motion
    assert all('e-stop' in r[n].reason for n in motion)
    rec = synthetic()
    rec.segments = rec.segments[:6]
    rec.aborted = 'speed beyond the bound'
    assert failed(rec) == {'one_commander', 'watchdog_fault', 'watchdog_stop'}


def test_drive_ready_and_fault_during_the_run():
    rec = synthetic()
    rec.feedback.drive_fault[:100] = True
    assert failed(rec) == {'drive_ready'}
    rec = synthetic()
    rec.gap.gap_mm[:] -= 4.0  # 1 mm above the sheet: below the minimum
    assert failed(rec) == {'drive_ready'}
    rec = synthetic()
    i = np.flatnonzero(rec.feedback.window(rec.segment(WATCHDOG).start_ns,
                                           rec.segment(WATCHDOG).end_ns))[10]
    rec.feedback.drive_fault[i] = True
    r = evaluate(rec)
    assert r.rules_failed == ['watchdog_fault']
    assert 'still coming' in r['watchdog_fault'].reason


def test_a_rule_that_raises_is_a_failure_not_a_crash():
    rec = synthetic()
    rec.feedback.position_mm = rec.feedback.position_mm[:10]  # inconsistent lengths
    r = evaluate(rec)
    assert not r.passed
    assert any('could not be evaluated' in x.reason for x in r.results)


def test_tolerances_are_the_documented_ones():
    tol = Tolerances()
    assert tol.watchdog_timeout_s == 0.005  # docs/safety.md
    assert tol.age_limit_s == 0.010         # the controller's stamp_tolerance_s
    texts = {r.name: r.tolerance(tol, Plan()) for r in RULES}
    assert texts['rate'] == '2000 Hz ± 5 %'
    assert texts['watchdog_fault'].startswith('≤ 7 ms')
    # a tighter tolerance turns a pass into a fail
    assert failed(synthetic(speed_scale=1.05)) == set()
    assert failed(synthetic(speed_scale=1.05), Tolerances(speed_rel=0.02)) == {'motion_speed'}


def test_plan_problems():
    assert Plan().problems() == []
    assert any('half of max_speed' in p for p in Plan(test_speed_mm_s=5.0).problems())
    assert any('half of max_travel' in p for p in Plan(test_travel_mm=1.5).problems())
    assert any('finite number' in p for p in Plan(min_gap_mm=float('nan')).problems())
    ex = dataclasses.replace(Plan().excitation, amplitude_mm_s=7.0)
    assert any('excitation amplitude' in p for p in Plan(excitation=ex).problems())
    ex = dataclasses.replace(Plan().excitation, f_high_hz=5000.0)
    assert any('Nyquist' in p for p in Plan(excitation=ex).problems())


def test_result_round_trip_and_report():
    r = evaluate(synthetic(sign=-1.0))
    data = json.loads(json.dumps(r.as_dict()))
    assert data['rules_failed'] == ['motion_direction']
    assert data['rules_passed'] == len(RULES) - 1
    back = ConformanceResult.from_dict(data)
    assert back.rules_failed == ['motion_direction']
    assert back['motion_direction'].figure == pytest.approx(r['motion_direction'].figure)
    text = markdown(r, 'synthetic', ['driver: synthetic'], synthetic().segments)
    assert '**FAIL**' in text and '| `motion_direction` | **FAIL** |' in text
    assert '| up | 1.500 | 2.000 | +2 | true |' in text


def test_the_sim_scenario_is_a_plain_drive():
    yaml = pytest.importorskip('yaml')
    from ladrc_sim.headless.scenario import scenario_from_dict

    sc = scenario_from_dict(yaml.safe_load(sim_scenario_yaml(6.0)))
    assert sc.initial_gap_mm == 6.0
    assert sc.timeline == ()          # no follow commands: the sim node waits for no one
    assert sc.sheet.profiles == ()    # flat, resting sheet


def test_the_speed_bound_ignores_one_late_sample_and_stops_a_runaway(monkeypatch):
    """The prober's speed bound (conform_node.SpeedGuard), fed 2 kHz encoder samples.

    A true 6 mm/s under an 8 mm/s bound, the driver stalled for 8 ms between taking sample 100
    and sending it (as a loaded machine does): sample 100 arrives 8 ms late with its
    old position, the cycles of the stall send nothing (the driver catches up silently), and the
    one window that starts on sample 100 reads 10.8 mm/s. The run goes on; a judge of single
    windows (persistence 0) aborts there. An axis at 12 mm/s is
    stopped within 10 + 2 ms + a sample.
    """
    from ladrc_bringup import conform_node
    from ladrc_bringup.conform_node import SPEED_PERSIST_NS, SPEED_WINDOW_NS, SpeedGuard

    def feed(speed_mm_s, stall_at=None, n=400):
        guard = SpeedGuard(8.0)
        for k in range(n):
            t_ns = k * 500_000
            if stall_at is not None and stall_at < k <= stall_at + 16:
                continue  # the stall's cycles: nothing sent
            recv = t_ns + (8_000_000 if k == stall_at else 0)
            why = guard.feed(recv, speed_mm_s * t_ns * 1e-9)
            if why:
                return k, why
        return None, ''

    assert feed(6.0, stall_at=100) == (None, '')
    assert feed(6.0) == (None, '')
    k, why = feed(12.0)
    assert why.startswith('speed beyond the bound: 12.00 mm/s') and k is not None
    assert k * 500_000 <= SPEED_WINDOW_NS + SPEED_PERSIST_NS + 500_000
    monkeypatch.setattr(conform_node, 'SPEED_PERSIST_NS', 0)
    k, why = feed(6.0, stall_at=100)
    assert why.startswith('speed beyond the bound: 10.8'), why
