"""The CNC partner (control/follow/cnc.py): corner lock, edge ahead, pierce, lift, hold, answers.

Closed loop against the sim's axis model (tests/support/loops.py) with a scripted CNC: each
test sets the CNC's motion per tick and checks what a wrong implementation would get wrong
(a command toward the sheet while held, a dwell before in position, a missing feed hold).
"""

from __future__ import annotations

from dataclasses import replace
import math

from ladrc_contract.codes import EventKind, Segment, SubState
from ladrc_contract.events import decode, encode
from ladrc_contract.tick import CncInput
from ladrc_follow.control.follow import FollowController, TickInput
from ladrc_follow.control.params import ControllerParams, validate
from ladrc_tools.offline.rerun import _cnc_inputs
from loops import H, Loop
import numpy as np
import pytest

DU_MAX = ControllerParams().limits.a_max_mm_s2 * H
LADRC = 4


class Cnc:
    """A scripted CNC: cutting at ``feed`` with ``ratio`` of it actually reached."""

    def __init__(self) -> None:
        self.ratio = 1.0
        self.feed = 100.0
        self.segment = int(Segment.CUT)
        self.beam = True
        self.contour = 1
        self.edge_ahead = math.inf
        self.silent = False
        self.seq = 0

    def __call__(self, i: int, t: float) -> CncInput | None:
        if self.silent:
            return None
        self.seq += 1
        return CncInput(self.seq, t, self.segment, self.beam, self.contour, self.feed,
                        self.feed * self.ratio, 50.0, self.edge_ahead)


def following(params: ControllerParams | None = None, sheet=None, gap0_mm: float = 1.5):
    """Return a loop with a scripted CNC, following in LADRC at 1 mm."""
    cnc = Cnc()
    c = FollowController(params or ControllerParams())
    loop = Loop(c, gap0_mm=gap0_mm, sheet=sheet, cnc=cnc)
    assert c.command('start_follow', target_gap_mm=1.0)[0]
    loop.run_until(lambda: int(c.state) == LADRC, 6000)
    loop.run(200)
    assert int(c.state) == LADRC and abs(loop.gap[-1] - 1.0) < 0.02
    return loop, cnc


def run(loop: Loop, seconds: float, key: str = 'substate') -> list:
    """Run ``seconds``; return the controller's ``key`` answer per tick."""
    out = []
    for _ in range(int(round(seconds / H))):
        loop.run(1)
        out.append(loop.c.internals()[key])
    return out


def falling_sheet(t0: float, rate_mm_s: float):
    """Return a sheet falling at ``rate_mm_s`` from ``t0`` on (sagging under the cut)."""
    return lambda t: -rate_mm_s * max(t - t0, 0.0)


# ------------------------------------------------------------------------------ corner lock
def test_corner_lock_never_follows_down_holds_with_hysteresis_and_resumes_bumplessly():
    loop, cnc = following(sheet=falling_sheet(1e9, 0.0))
    t_lock = loop.i * H
    loop.sheet = falling_sheet(t_lock, 2.0)  # the sheet falls away 2 mm/s from the corner on
    cnc.ratio = 0.5
    i0 = loop.i
    sub = run(loop, 0.1)
    assert set(sub) == {int(SubState.CORNER_LOCK)}
    assert min(loop.u[i0:]) >= 0.0  # held: nothing toward the sheet though the gap widens
    cnc.ratio = 0.85  # between lock (0.8) and unlock (0.9): still locked
    sub = run(loop, 0.05)
    assert set(sub) == {int(SubState.CORNER_LOCK)}
    assert min(loop.u[i0:]) >= 0.0 and loop.gap[-1] > 1.2
    # the observer kept tracking while held: it resumes from the gap as it is, no bump
    z1 = loop.c.internals()['eso_z1_mm']
    assert abs(z1 - loop.gap[-1]) < 0.05
    cnc.ratio = 0.95
    loop.sheet = falling_sheet(1e9, 0.0)  # the sheet stops 0.3 mm lower
    sub = run(loop, 1.5)
    assert sub[0] == int(SubState.NONE)
    # released: the sink is verified first (the edge guard's move up), then followed down
    assert int(loop.c.state) == LADRC and abs(loop.gap[-1] - 1.0) < 0.05


def test_corner_lock_off_follows_the_same_fall_down():
    p = ControllerParams()
    loop, cnc = following(p.replace(cnc=replace(p.cnc, corner_lock=False)))
    loop.sheet = falling_sheet(loop.i * H, 2.0)
    cnc.ratio = 0.5
    i0 = loop.i
    assert set(run(loop, 0.15)) == {int(SubState.NONE)}
    assert min(loop.u[i0:]) < -0.5 and loop.gap[-1] < 1.1  # it followed the sheet down


# ------------------------------------------------------------------------------ edge ahead
def test_edge_ahead_holds_from_the_set_distance_until_the_release_path():
    loop, cnc = following()
    p = loop.c.params.cnc
    cnc.edge_ahead = p.edge_ahead_hold_mm + 5.0
    assert set(run(loop, 0.01)) == {int(SubState.NONE)}
    cnc.edge_ahead = p.edge_ahead_hold_mm - 1.0
    sub = run(loop, 0.01)
    assert set(sub) == {int(SubState.EDGE_AHEAD)}
    reason = loop.c.internals()['hold_reason']
    assert 'ahead' in reason
    # past the edge: nothing ahead, held for edge_release_mm + the distance that was ahead
    cnc.edge_ahead = math.inf
    t_release = (p.edge_release_mm + p.edge_ahead_hold_mm - 1.0) / cnc.feed
    sub = run(loop, t_release + 0.01)
    n_held = sum(s == int(SubState.EDGE_AHEAD) for s in sub)
    assert abs(n_held * H - t_release) < 0.002 and sub[-1] == int(SubState.NONE)


# ------------------------------------------------------------------------------ pierce
def test_pierce_from_idle_approaches_dwells_in_position_and_closes_in_after_the_thc_delay():
    cnc = Cnc()
    cnc.segment, cnc.beam, cnc.feed = int(Segment.PIERCE), False, 0.0
    c = FollowController(ControllerParams())
    loop = Loop(c, gap0_mm=6.0, cnc=cnc)
    ok, msg = c.command('pierce', heights_mm=[3.0, 2.0], dwell_s=[0.2, 0.1], cut_gap_mm=1.0,
                        thc_delay_s=0.1)
    assert ok, msg
    rows = []
    for _ in range(int(6.0 / H)):
        loop.run(1)
        d = c.internals()
        rows.append((d['substate'], d['in_position'], d['ready_to_move'], loop.gap[-1],
                     loop.u[-1], d['hold_reason']))
        if rows[-1][0] == int(SubState.NONE) and len(rows) > 10 and d['state'] == LADRC:
            break
    sub = np.array([r[0] for r in rows])
    inpos = np.array([r[1] for r in rows])
    ready = np.array([r[2] for r in rows])
    gap = np.array([r[3] for r in rows])
    dwell = np.flatnonzero(np.char.find([r[5] for r in rows], 'dwell') >= 0)
    # two dwells, each at its stage height, in position throughout, as long as commanded
    first = dwell[gap[dwell] > 2.5]
    second = dwell[gap[dwell] < 2.5]
    assert abs(first.size * H - 0.2) < 2 * H and abs(second.size * H - 0.1) < 2 * H
    assert np.all(np.abs(gap[first] - 3.0) < 0.25) and np.all(np.abs(gap[second] - 2.0) < 0.25)
    assert inpos[first[:-1]].all() and inpos[second[:-1]].all()  # (the last: next stage starts)
    # no dwell before in position at the stage: the tick before the first dwell was in position
    assert inpos[first[0] - 1] or sub[first[0] - 1] == int(SubState.PIERCE)
    # the THC delay at the cut gap, then following; XY may move from the THC delay on
    thc = np.flatnonzero(sub == int(SubState.THC_DELAY))
    assert thc.size and abs(thc.size * H - 0.1) < 2 * H and thc[0] > second[-1]
    assert np.all(np.abs(gap[thc] - 1.0) < 0.1)
    assert not ready[:thc[0] - 1].any() and ready[thc[0] - 1:].all()  # from in position on
    assert int(c.state) == LADRC and abs(gap[-1] - 1.0) < 0.05


def test_a_cnc_moving_before_the_pierce_is_complete_is_asked_to_hold_its_feed():
    cnc = Cnc()
    cnc.segment, cnc.beam, cnc.feed = int(Segment.PIERCE), False, 0.0
    c = FollowController(ControllerParams())
    loop = Loop(c, gap0_mm=4.0, cnc=cnc)
    assert c.command('pierce', heights_mm=[3.0], dwell_s=[0.5], cut_gap_mm=1.0,
                     thc_delay_s=0.0)[0]
    loop.run_until(lambda: 'dwell' in c.internals()['hold_reason'], 8000)
    assert not c.internals()['feed_hold_request']
    cnc.segment, cnc.beam, cnc.feed = int(Segment.CUT), True, 50.0  # the CNC does not wait
    i0 = loop.i
    loop.run(20)
    d = c.internals()
    assert d['feed_hold_request'] and not d['ready_to_move']
    assert 'before the pierce is complete' in d['hold_reason']
    assert min(loop.u[i0:]) >= 0.0


# ------------------------------------------------------------------------------ lift, hold
def test_lift_to_a_height_never_moves_down_holds_there_and_set_target_resumes():
    loop, cnc = following()
    c = loop.c
    ok, msg = c.command('lift', mode=0, value_mm=5.0, velocity_mm_s=0.0)
    assert ok, msg
    i0 = loop.i
    inpos = run(loop, 1.0, 'in_position')
    assert min(loop.u[i0:]) >= 0.0
    assert abs(loop.gap[-1] - 5.0) < 0.05 and inpos[-1]
    assert c.internals()['substate'] == int(SubState.LIFT)
    assert c.command('set_target', target_gap_mm=1.0)[0]
    loop.run_until(lambda: int(c.state) == LADRC, 10000)
    loop.run(400)
    assert abs(loop.gap[-1] - 1.0) < 0.03 and c.internals()['substate'] == int(SubState.NONE)


def test_a_lift_to_below_the_gap_does_not_move_toward_the_sheet():
    loop, _ = following()
    assert loop.c.command('lift', mode=0, value_mm=0.5, velocity_mm_s=0.0)[0]
    i0 = loop.i
    run(loop, 0.2)
    assert min(loop.u[i0:]) >= 0.0 and loop.gap[-1] >= 0.99


def test_hold_at_the_next_segment_waits_for_the_segment_and_release_now_ends_it():
    loop, cnc = following()
    c = loop.c
    assert c.command('hold', hold=True, at_next_segment=True, reason='part drops out')[0]
    assert set(run(loop, 0.02)) == {int(SubState.NONE)}
    cnc.contour = 2  # the CNC's next segment
    sub = run(loop, 0.02)
    assert set(sub) == {int(SubState.HOLD)} and c.internals()['hold_reason'] == 'part drops out'
    assert c.command('hold', hold=False, at_next_segment=False, reason='')[0]
    assert run(loop, 0.01)[-1] == int(SubState.NONE)


def test_a_cnc_gone_silent_lifts_the_head_once_and_holds_it_there():
    """cnc.stale_lift_s (the CNC's bridge killed): held first, then lifted, never down."""
    loop, cnc = following()
    c = loop.c
    p = c.params.cnc
    cnc.silent = True
    i0 = loop.i
    sub = run(loop, p.stale_lift_s + 0.6)
    lift_at = sub.index(int(SubState.LIFT))
    assert abs(lift_at * H - p.stale_lift_s) < 3 * H  # held until then (HOLD, stale)
    assert set(sub[int(p.stale_timeout_s / H) + 2:lift_at]) == {int(SubState.HOLD)}
    held = i0 + sub.index(int(SubState.HOLD))
    assert min(loop.u[held:]) >= 0.0  # nothing toward the sheet, held or lifting
    assert sub[-1] == int(SubState.LIFT) and c.internals()['in_position']
    assert loop.gap[-1] == pytest.approx(1.0 + p.stale_lift_mm, abs=0.15)
    rise = loop.gap[-1]
    run(loop, 0.5)  # still silent: no second lift, the head stays
    assert loop.gap[-1] == pytest.approx(rise, abs=0.05)
    off = ControllerParams()
    loop, cnc = following(replace(off, cnc=replace(off.cnc, stale_lift_s=0.0)))
    cnc.silent = True
    assert int(SubState.LIFT) not in run(loop, 1.0)  # 0: hold only


def test_a_silent_cnc_holds_with_its_reason_and_any_fault_asks_for_a_feed_hold():
    loop, cnc = following()
    c = loop.c
    cnc.silent = True
    i0 = loop.i
    sub = run(loop, 0.05)
    assert sub[-1] == int(SubState.HOLD) and 'stale' in c.internals()['hold_reason']
    held = i0 + sub.index(int(SubState.HOLD))
    assert abs((held - i0) * H - c.params.cnc.stale_timeout_s) < 2 * H
    assert min(loop.u[held:]) >= 0.0
    c.fail('test fault')
    loop.run(1)
    d = c.internals()
    assert d['feed_hold_request'] and not d['ready_to_move']


def test_without_a_cnc_in_position_follows_followed():
    c = FollowController(ControllerParams())
    loop = Loop(c, gap0_mm=1.5)
    assert c.internals()['ready_to_move']  # idle: nothing of the controller's holds XY
    assert c.command('start_follow', target_gap_mm=1.0)[0]
    loop.run(1)
    assert not c.internals()['in_position'] and not c.internals()['ready_to_move']
    loop.run_until(lambda: int(c.state) == LADRC, 6000)
    d = c.internals()
    assert d['in_position'] and d['ready_to_move'] and d['cnc_seq'] == 0


# ------------------------------------------------------------------------------ contract
@pytest.mark.parametrize('name, kwargs', [
    ('pierce', dict(heights_mm=(3.0, 2.0), dwell_s=(0.2, 0.1), cut_gap_mm=1.0,
                    thc_delay_s=0.1, locked=False)),
    ('lift', dict(mode=1, value_mm=4.0, velocity_mm_s=20.0)),
    ('hold', dict(hold=True, at_next_segment=True, reason='part drops out')),
    ('hold', dict(hold=False, at_next_segment=False, reason='')),
    ('leapfrog', dict(lift_mm=8.0, rapid_length_mm=200.0, rapid_feed_mm_s=500.0,
                      arrive_height_mm=3.0)),
    ('pierce', dict(heights_mm=(3.0,), dwell_s=(0.1,), cut_gap_mm=1.0, thc_delay_s=0.0,
                    locked=True)),
])
def test_cnc_commands_survive_the_event_codec(name, kwargs):
    ev = encode(name, kwargs)
    assert ev.kind in (EventKind.PIERCE, EventKind.LIFT, EventKind.HOLD, EventKind.LEAPFROG)
    assert decode(ev) == (name, kwargs)


@pytest.mark.parametrize('name, kwargs, why', [
    ('pierce', dict(heights_mm=(), dwell_s=(), cut_gap_mm=1.0, thc_delay_s=0.0), 'stages'),
    ('pierce', dict(heights_mm=(3.0,), dwell_s=(0.1, 0.2), cut_gap_mm=1.0, thc_delay_s=0.0),
     'stages'),
    ('pierce', dict(heights_mm=(300.0,), dwell_s=(0.1,), cut_gap_mm=1.0, thc_delay_s=0.0),
     'outside'),
    ('pierce', dict(heights_mm=(3.0,), dwell_s=(math.nan,), cut_gap_mm=1.0, thc_delay_s=0.0),
     'dwell'),
    ('lift', dict(mode=2, value_mm=1.0, velocity_mm_s=0.0), 'mode'),
    ('lift', dict(mode=0, value_mm=-1.0, velocity_mm_s=0.0), 'value_mm'),
    ('lift', dict(mode=0, value_mm=1.0, velocity_mm_s=math.inf), 'velocity_mm_s'),
    ('hold', dict(hold='yes', at_next_segment=False, reason=''), 'true or false'),
    ('leapfrog', dict(lift_mm=8.0, rapid_length_mm=200.0, rapid_feed_mm_s=500.0,
                      arrive_height_mm=9.0), 'arrive_height_mm'),
    ('leapfrog', dict(lift_mm=8.0, rapid_length_mm=0.0, rapid_feed_mm_s=500.0,
                      arrive_height_mm=3.0), 'positive'),
    ('leapfrog', dict(lift_mm=math.nan, rapid_length_mm=1.0, rapid_feed_mm_s=500.0,
                      arrive_height_mm=3.0), 'finite'),
])
def test_bad_cnc_commands_are_rejected_with_their_reason(name, kwargs, why):
    loop, _ = following()
    ok, msg = loop.c.command(name, **kwargs)
    assert not ok and why in msg


def test_corner_unlock_below_lock_is_rejected():
    p = ControllerParams()
    bad = p.replace(cnc=replace(p.cnc, corner_lock_ratio=0.9, corner_unlock_ratio=0.8))
    assert any('corner_unlock_ratio' in r for r in validate(bad))


def test_a_cnc_run_replays_bit_for_bit_from_its_status_fields():
    """Replay's path (FollowStatus cnc_* columns -> CncInput) reproduces every command."""
    loop, cnc = following()
    c = loop.c
    ticks, rows = [], []
    orig = c.step

    def recording_step(tick, cnc_in=None):
        u = orig(tick, cnc_in)
        ticks.append(tuple(tick))
        rows.append(c.internals())
        return u

    c.step = recording_step
    cnc.ratio = 0.5
    loop.run(100)
    cnc.ratio = 1.0
    cnc.edge_ahead = 5.0
    loop.run(100)
    cnc.edge_ahead = math.inf
    cnc.silent = True
    loop.run(100)
    status = {k: np.array([r[k] for r in rows]) for k in (
        'cnc_seq', 'cnc_stamp_s', 'cnc_segment', 'cnc_beam_on', 'cnc_contour',
        'cnc_commanded_feed_mm_s', 'cnc_actual_feed_mm_s', 'cnc_segment_left_mm',
        'cnc_edge_ahead_mm')}
    cnc_in = _cnc_inputs(status, len(rows))
    # a twin controller, brought to the same state the same way, stepped on the recorded inputs
    twin, _ = following()
    got = [twin.c.step(TickInput(*t), x) for t, x in zip(ticks, cnc_in, strict=True)]
    assert got == [r['velocity_mm_s'] for r in rows]
    assert {r['substate'] for r in rows} >= {int(SubState.CORNER_LOCK),
                                              int(SubState.EDGE_AHEAD), int(SubState.HOLD)}


# ------------------------------------------------------------------------------ leapfrog
def leapfrog_run(loop: Loop, seconds: float, hook=None) -> list[dict]:
    rows = []
    for _ in range(int(round(seconds / H))):
        loop.run(1, hook)
        rows.append(loop.c.internals())
    return rows


def test_leapfrog_lifts_over_the_rapid_and_arrives_at_the_pierce_height_in_time():
    loop, cnc = following()
    c = loop.c
    cnc.segment, cnc.beam = int(Segment.RAPID), False
    ok, msg = c.command('leapfrog', lift_mm=8.0, rapid_length_mm=200.0, rapid_feed_mm_s=500.0,
                        arrive_height_mm=3.0)
    assert ok, msg
    i0 = loop.i

    def over_a_hole(i, d):  # the middle of the rapid crosses a hole: out of range, no sheet
        if i0 + 200 <= i < i0 + 500:
            d['gap_valid'], d['gap_status'], d['gap_mm'] = False, 1, math.inf

    rows = leapfrog_run(loop, 0.6, over_a_hole)
    gap = np.array(loop.gap[i0:])
    sub = [r['substate'] for r in rows]
    assert set(sub) == {int(SubState.LEAPFROG)} and int(c.state) == LADRC
    assert abs(gap.max() - 8.0) < 0.3  # the peak, lift_mm above the sheet
    k_end = int(round(0.4 / H))  # the rapid's end: 200 mm at 500 mm/s
    assert 2.98 < gap[k_end] < 3.1, gap[k_end]  # there in time: the rapid never waits
    assert abs(gap[-1] - 3.0) < 0.05 and rows[-1]['in_position'] and rows[-1]['ready_to_move']
    assert not rows[k_end // 2]['in_position'] and not rows[k_end // 2]['ready_to_move']
    v_cap = c.params.cnc.leapfrog_velocity_mm_s
    assert max(abs(u) for u in loop.u[i0:]) <= v_cap * 1.05 + 2.0
    # the CNC stops at the pierce point and pierces: the follow approaches from where it is
    cnc.segment, cnc.feed = int(Segment.PIERCE), 0.0
    assert c.command('pierce', heights_mm=[3.0], dwell_s=[0.05], cut_gap_mm=1.0,
                     thc_delay_s=0.0)[0]
    loop.run_until(lambda: int(c.state) == LADRC and c.internals()['substate'] == 0
                   and c.internals()['in_position'], 8000)
    assert abs(loop.gap[-1] - 1.0) < 0.03


def test_leapfrog_on_a_short_rapid_lowers_its_peak_and_never_descends_below_the_arrival():
    loop, _ = following()
    c = loop.c
    assert c.command('leapfrog', lift_mm=10.0, rapid_length_mm=30.0, rapid_feed_mm_s=500.0,
                     arrive_height_mm=2.0)[0]
    i0 = loop.i
    leapfrog_run(loop, 0.3)
    gap = np.array(loop.gap[i0:])
    assert 2.0 < gap.max() < 9.0  # a lower peak in 60 ms
    assert gap[int(0.06 / H):].min() > 1.9  # never below the arrival height


def test_leapfrog_stops_descending_where_the_sheet_is_higher_than_at_the_start():
    loop, _ = following()
    c = loop.c
    t0 = loop.i * H
    loop.sheet = lambda t: 1.5 * min(max(t - t0, 0.0) / 0.2, 1.0)  # 1.5 mm higher at the end
    assert c.command('leapfrog', lift_mm=6.0, rapid_length_mm=150.0, rapid_feed_mm_s=500.0,
                     arrive_height_mm=3.0)[0]
    i0 = loop.i
    leapfrog_run(loop, 0.6)
    gap = np.array(loop.gap[i0:])
    assert gap.min() > 0.9 and gap[-1] >= 3.0 - 0.05  # by the reading, not the start's level


def test_going_down_is_limited_apart_from_going_up():
    p = ControllerParams()
    slow_down = p.replace(limits=replace(p.limits, v_down_max_mm_s=5.0))
    loop, _ = following(slow_down)
    c = loop.c
    assert c.command('set_target', target_gap_mm=0.6)[0]  # down, by the law (< 1 mm change)
    i0 = loop.i
    loop.run(600)
    assert min(loop.u[i0:]) >= -5.0 - 1e-9 and min(loop.u[i0:]) < -4.0
    assert c.command('set_target', target_gap_mm=1.4)[0]  # up: the full speed
    i1 = loop.i
    loop.run(600)
    assert max(loop.u[i1:]) > 10.0


# ------------------------------------------------------------------------------ adaptive feed
def _partner(**cnc):
    from ladrc_follow.control.follow.cnc import CncPartner

    p = ControllerParams()
    p = p.replace(cnc=replace(p.cnc, **cnc))
    partner = CncPartner()
    partner.configure(p, H)
    return partner


def _request(partner, t: float, gap: float, seq: int, segment=Segment.CUT) -> float:
    partner.begin(False)
    partner.motion(t, CncInput(seq, t, int(segment), True, 1, 100.0, 100.0, 50.0, math.inf))
    partner.judge(t, gap, 1.0, True)
    return partner.answers(LADRC, True, False)['feed_override_request']


def test_adaptive_feed_asks_less_feed_only_when_too_close_and_recovers_at_its_rate():
    assert _request(_partner(), 0.0, 0.5, 1) == 1.0  # off by default: never asked
    partner = _partner(feed_override_min=0.5, feed_override_error=0.1,
                       feed_override_recover_s=0.2)
    assert _request(partner, 0.0, 0.95, 1) == 1.0   # within the error: nothing asked
    assert _request(partner, H, 1.5, 2) == 1.0      # too wide (a kerf, a falling sheet): nothing
    assert _request(partner, 2 * H, 0.85, 3) == pytest.approx(0.75)  # 15 %: halfway down
    assert _request(partner, 3 * H, 0.6, 4) == 0.5  # never below the minimum
    # back at the target: up again by (1 - min) per recover_s, not at once
    got = [_request(partner, (4 + k) * H, 1.0, 5 + k) for k in range(500)]
    assert np.all(np.diff(got) >= 0.0) and got[0] < 0.51
    k_one = int(np.argmax(np.asarray(got) >= 1.0))
    assert abs(k_one * H - 0.2) <= 2 * H
    assert _request(partner, 1.0, 0.6, 600, Segment.RAPID) == 1.0  # only while cutting


def test_the_job_planner_runs_at_the_override_share_of_the_feed():
    from ladrc_sim.job.motion import PathMotion

    full = PathMotion(np.array([[0.0, 0.0], [100.0, 0.0]]), 200.0, 2000.0, 0.05, H)
    half = PathMotion(np.array([[0.0, 0.0], [100.0, 0.0]]), 200.0, 2000.0, 0.05, H)
    for _ in range(400):
        full.step()
        half.step(override=0.5)
    assert full.v == pytest.approx(200.0) and half.v == pytest.approx(100.0)


# ------------------------------------------------------------------------------ locked pierce
LOCKED = dict(heights_mm=(3.0, 2.0), dwell_s=(0.05, 0.05), cut_gap_mm=1.0, thc_delay_s=0.02,
              locked=True)


def void_reading(wide_mm: float):
    """Return a hook: the reading ``wide_mm`` wider than the gap (the field over voids)."""
    def hook(i, d):
        d['gap_mm'] += wide_mm
    return hook


def test_a_locked_pierce_holds_heights_above_the_level_followed_last_by_the_encoder():
    loop, _ = following()
    c = loop.c
    level = loop.axis.position_mm - loop.gap[-1]  # the sheet at 0: followed at 1 mm
    assert c.command('pierce', **LOCKED)[0]
    subs, inpos = [], []
    i0 = loop.i
    for _ in range(int(0.6 / H)):
        loop.run(1, void_reading(1.5))  # voids around: the reading 1.5 mm too wide throughout
        d = c.internals()
        subs.append(d['substate'])
        inpos.append(d['in_position'])
    gap = np.array(loop.gap[i0:])
    # up to the first stage, then down to the second and the cut gap, by the encoder: the wide
    # reading never drew it toward the sheet (a follow would have closed in by 1.5 mm)
    assert gap.max() == pytest.approx(3.0, abs=0.06) and gap.min() > 0.95
    assert abs(gap[-1] - 1.0) < 0.01 and abs(level) < 0.02
    assert subs[0] == int(SubState.PIERCE) and subs[-1] == int(SubState.HOLD)
    d = c.internals()
    assert d['ready_to_move'] and d['in_position'] and int(c.state) == LADRC
    assert 'height locked' in d['hold_reason']


def test_a_locked_pierce_moves_up_where_the_sheet_is_nearer_and_a_collision_still_faults():
    loop, _ = following()
    c = loop.c
    assert c.command('pierce', **LOCKED)[0]
    loop.run(int(0.4 / H))
    t0 = loop.i * H
    loop.sheet = lambda t: 0.6 * min(max(t - t0, 0.0) / 0.1, 1.0)  # 0.6 mm higher in 0.1 s
    i0 = loop.i
    loop.run(int(0.3 / H))
    assert min(loop.gap[i0:]) > 0.75 and abs(loop.gap[-1] - 1.0) < 0.05  # level raised
    # a real fault still faults: collision evidence (the reading shorted) retracts

    def short(i, d):
        d['gap_valid'], d['gap_status'], d['gap_mm'] = False, 2, 0.0
    loop.run(20, short)
    assert c.state.name == 'FAULT' and max(loop.u[-20:]) > 0.0


def test_a_locked_pierce_needs_a_level_followed_first_and_the_next_command_ends_it():
    c = FollowController(ControllerParams())
    ok, msg = c.command('pierce', **LOCKED)
    assert not ok and 'no sheet level followed' in msg  # IDLE: nothing followed yet
    loop, _ = following()
    assert loop.c.command('pierce', **LOCKED)[0]
    loop.run(int(0.8 / H))
    assert loop.c.internals()['substate'] == int(SubState.HOLD)
    assert loop.c.command('leapfrog', lift_mm=6.0, rapid_length_mm=100.0,
                          rapid_feed_mm_s=500.0, arrive_height_mm=3.0)[0]
    loop.run(2)
    assert loop.c.internals()['substate'] == int(SubState.LEAPFROG)
