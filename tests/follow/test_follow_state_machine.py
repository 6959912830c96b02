"""Follow state machine (notes §3.5 Follow_OnStep) closed loop against the sim models."""

from __future__ import annotations

import math
from pathlib import Path

from ladrc_follow.control.edge import EdgeParams
from ladrc_follow.control.follow import (
    ANSWER_KEYS,
    INTERNALS_KEYS,
    FollowController,
    FollowParams,
)
from ladrc_follow.control.params import ControllerParams, check, params_from_dict, validate
from ladrc_sim.headless import runner
from ladrc_sim.headless.scenario import scenario_from_dict
from loops import Loop
import numpy as np
import pytest

H = 0.0005
A_MAX = ControllerParams().limits.a_max_mm_s2  # the output's acceleration limit, mm/s²
DU_MAX = A_MAX * H                            # largest allowed command change per tick


class Recorder:
    """Wraps a FollowController for the runner and records state / enable per tick."""

    def __init__(self, ctrl: FollowController) -> None:
        self.c = ctrl
        self.states: list[int] = []
        self.enable: list[bool] = []
        self.answers: list[tuple[str, tuple[bool, str]]] = []

    def step(self, tick) -> float:
        u = self.c.step(tick)
        self.states.append(int(self.c.state))
        self.enable.append(self.c.enable)
        return u

    def command(self, name, **kwargs):
        ans = self.c.command(name, **kwargs)
        self.answers.append((name, ans))
        return ans


def run_scenario(ctrl: FollowController, duration_s: float, timeline: list, **extra):
    """Run the sim runner on an inline scenario; return (RunResult, Recorder)."""
    d = dict(name='follow_test', duration_s=duration_s, seed=5,
             sensor={'noise_std_mm': 0.005, 'quant_mm': 0.001}, timeline=timeline)
    d.update(extra)
    rec = Recorder(ctrl)
    res = runner.run(scenario_from_dict(d), rec)
    return res, rec


def transitions(states) -> list[tuple[int, int]]:
    """(tick, new state) of every state change, starting with the first tick."""
    s = np.asarray(states)
    idx = [0] + list(np.flatnonzero(np.diff(s)) + 1)
    return [(int(i), int(s[i])) for i in idx]


@pytest.fixture
def following_ladrc():
    """Return a loop that has reached LADRC follow at 1 mm (started at 1.5 mm)."""
    c = FollowController(ControllerParams())
    loop = Loop(c, gap0_mm=1.5)
    assert c.command('start_follow', target_gap_mm=1.0)[0]
    loop.run_until(lambda: int(c.state) == 4, 4000)
    loop.run(200)
    assert int(c.state) == 4 and abs(loop.gap[-1] - 1.0) < 0.02
    return loop


FOLLOW_STATUS_MSG = (Path(__file__).resolve().parents[2] / 'ros2_ws' / 'src' / 'ladrc_msgs'
                     / 'msg' / 'FollowStatus.msg')


# ---------------------------------------------------------------------------- approach

def test_approach_5_to_1_passes_all_states_without_velocity_steps():
    res, rec = run_scenario(FollowController(ControllerParams()), 1.5,
                            [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}],
                            initial_gap_mm=5.0)
    seq = [s for _, s in transitions(rec.states)]
    assert seq == [1, 2, 3, 4]  # LOCKING -> PREINTERPOLATE -> PID -> LADRC
    du = np.abs(np.diff(res.command_mm_s))
    # every tick, and in particular the hand-overs, moves the command by at most a_max·h
    assert du.max() <= DU_MAX + 1e-9
    assert np.abs(res.command_mm_s).max() <= ControllerParams().limits.v_max_mm_s
    # the approach moved down (4 mm) at speed, then settled at the target
    assert res.command_mm_s.min() < -20.0
    tail = res.true_gap_mm[-400:]
    assert abs(tail.mean() - 1.0) < 0.01 and np.abs(tail - 1.0).max() < 0.03
    assert res.true_gap_mm.min() > 0.8  # no dive towards the sheet at the hand-over
    assert rec.c.followed and rec.enable[-1]


def test_pid_only_configuration_never_enters_ladrc():
    p = ControllerParams(follow=FollowParams(controller='pid'))
    res, rec = run_scenario(FollowController(p), 1.5,
                            [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}],
                            initial_gap_mm=4.0)
    assert 4 not in rec.states
    assert [s for _, s in transitions(rec.states)] == [1, 2, 3]
    assert rec.c.followed
    assert abs(res.true_gap_mm[-400:].mean() - 1.0) < 0.02


# ---------------------------------------------------------------------------- wavy sheet

LAW_ONLY = {'edge': {'verify_sink': 0.0, 'verify_start_mm': 0.0}}
"""The edge verification's moves up off: what the law alone tracks."""
LIFT_MM = 0.1
"""The verification's move up (edge.verify_mm_s x verify_move_s), a deliberate excursion."""


def _verify_excursion_mm(sheet_speed_mm_s: float) -> float:
    """Largest gap error one verification adds: the move up, and the sheet's motion meanwhile.

    The law is overridden for the whole window (pre, move, settle), so the sheet moves
    unfollowed for that long.
    """
    e = EdgeParams()
    return LIFT_MM + sheet_speed_mm_s * (e.verify_pre_s + e.verify_move_s + e.verify_settle_s)


@pytest.mark.parametrize('overrides', [LAW_ONLY, {}])
def test_holds_gap_on_sine_sheet_in_ladrc(overrides):
    amp, f_hz = 0.5, 1.0
    res, rec = run_scenario(
        FollowController(params_from_dict(overrides)), 3.0,
        [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}], initial_gap_mm=1.0,
        sheet={'profiles': [{'kind': 'sine', 'amp_mm': amp, 'freq_hz': f_hz, 't_start_s': 0.5}]})
    st = np.asarray(rec.states)
    sel = np.arange(len(st)) * H >= 0.5
    assert (st[sel] == 4).all()  # LADRC throughout the waviness
    # a loop without disturbance estimate (kp = 10 /s) lags a surface moving at A·ω by
    # A·ω/kp = 0.31 mm; the ESO cancels the surface motion, so the error must be far smaller
    lag_bound = amp * 2 * math.pi * f_hz / ControllerParams().law.kp
    err = np.abs(res.true_gap_mm[sel] - 1.0)
    # shipped: the falling half of each period is verified by short moves up (docs/safety.md)
    assert err.max() < 0.1 < lag_bound or not overrides
    assert err.max() < 0.1 + _verify_excursion_mm(amp * 2 * math.pi * f_hz)
    assert res.metrics.collisions == 0
    e = EdgeParams()
    start = round((e.verify_pre_s + e.verify_move_s + e.verify_settle_s) / H)
    assert (rec.c.counts['verify'] > start) == (not overrides)  # beyond the start's one


@pytest.mark.parametrize('overrides', [LAW_ONLY, {}])
def test_holds_gap_on_random_waviness_in_ladrc(overrides):
    res, rec = run_scenario(
        FollowController(params_from_dict(overrides)), 3.0,
        [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0}], initial_gap_mm=1.0,
        sheet={'profiles': [{'kind': 'waviness', 'rms_mm': 0.3, 'cutoff_hz': 2.0}]})
    st = np.asarray(rec.states)
    sel = np.arange(len(st)) * H >= 0.3
    assert (st[sel] == 4).all()
    err = res.true_gap_mm[sel] - 1.0
    # shipped: a few ~0.1 mm excursions (falling stretches verified) add to the RMS
    rms_bound, max_bound = (0.05, 0.15) if overrides else (0.07, 0.15 + _verify_excursion_mm(3.0))
    assert np.sqrt(np.mean(err ** 2)) < rms_bound and np.abs(err).max() < max_bound


# ---------------------------------------------------------------------------- faults

def _ramped_to_zero(u: list[float]) -> bool:
    return u[-1] == 0.0 and float(np.abs(np.diff(u)).max()) <= DU_MAX + 1e-9


def test_stale_gap_input_faults_and_ramps_to_zero(following_ladrc):
    loop = following_ladrc
    c = loop.c
    frozen = loop.i * H

    def hold_stamp(i, d):
        d['gap_stamp_s'] = frozen

    limit = FollowParams().stale_timeout_s
    n = int(round(limit / H))
    loop.run(n, hold_stamp)  # ages 0 .. limit - h: still within the limit
    assert int(c.state) == 4
    loop.run(1, hold_stamp)   # age limit + h/2 > limit
    assert int(c.state) == 5 and 'stale' in c.fault_reason and 'gap age' in c.fault_reason
    loop.run(200, hold_stamp)
    assert _ramped_to_zero(loop.u[-220:]) and not c.enable
    assert int(c.state) == 5  # latched


def test_nan_reading_never_reaches_the_control_law(following_ladrc):
    loop = following_ladrc
    c = loop.c
    seen = []
    real = c._ladrc_step

    def spy(gap, enc, target):
        seen.append(gap)
        return real(gap, enc, target)

    c._ladrc_step = spy

    def nan(i, d):
        d['gap_mm'] = math.nan

    loop.run(5, nan)
    assert int(c.state) == 5 and 'not finite' in c.fault_reason
    assert seen == [] and all(math.isfinite(u) for u in loop.u)


def test_collision_retracts_then_stops_and_reset_fault_clears(following_ladrc):
    loop = following_ladrc
    c = loop.c
    k0 = loop.i

    def touch(i, d):
        if i == k0:
            d['gap_status'] = 2  # CapacitiveHeight.STATUS_COLLISION
            d['gap_valid'] = False

    loop.run(1, touch)
    assert int(c.state) == 5 and 'collision' in c.fault_reason
    assert c.enable  # the drive must execute the retract
    ok, msg = c.command('reset_fault')
    assert not ok and 'retract' in msg
    loop.run_until(lambda: not c._retracting, 4000)
    loop.run(5)
    u = np.asarray(loop.u[k0:])
    assert u.max() > 0.0 and u.min() > -1.0  # a positive (upward) command ...
    fp = c.follow_params
    assert u.max() <= fp.retract_velocity_mm_s + 1e-9
    # ... for the retract distance (planned travel ∑u·h), then zero
    assert abs(u.sum() * H - fp.retract_distance_mm) < 0.05
    assert loop.u[-1] == 0.0 and not c.enable
    assert np.abs(np.diff(u)).max() <= DU_MAX + 1e-9
    ok, msg = c.command('reset_fault')
    assert ok, msg
    loop.run(1)
    assert int(c.state) == 0 and c.fault_reason == ''


def test_collision_by_reading_below_limit(following_ladrc):
    loop = following_ladrc
    c = loop.c

    def low(i, d):
        d['gap_mm'] = 0.15  # valid reading below the 0.2 mm collision limit

    loop.run(1, low)
    assert int(c.state) == 5 and 'collision' in c.fault_reason and '0.150' in c.fault_reason


def test_miss_panel_holds_then_faults(following_ladrc):
    loop = following_ladrc
    c = loop.c
    u_before = loop.u[-1]

    def off_sheet(i, d):
        d['gap_valid'] = False
        d['gap_status'] = 1  # STATUS_OUT_OF_RANGE
        d['gap_mm'] = 20.0

    loop.run(5, off_sheet)  # 2.5 ms < miss_panel_s: still LADRC; an upward command is held,
    # motion toward the sheet stops at once (safety: no downward command on invalid data)
    assert int(c.state) == 4 and loop.u[-5:] == [max(u_before, 0.0)] * 5
    loop.run(10, off_sheet)
    assert int(c.state) == 5 and 'miss-panel' in c.fault_reason
    loop.run(100, off_sheet)
    assert loop.u[-1] == 0.0 and not c.enable


def test_miss_panel_inferred_without_status_as_from_the_sim_runner(following_ladrc):
    loop = following_ladrc
    c = loop.c

    def off_sheet(i, d):
        d['gap_valid'] = False
        d['gap_mm'] = 20.0  # the sim sensor saturates at the range top, no status

    loop.run(20, off_sheet)
    assert int(c.state) == 5 and 'miss-panel' in c.fault_reason


def test_sensor_fault_status_faults_after_invalid_timeout(following_ladrc):
    loop = following_ladrc
    c = loop.c

    def bad(i, d):
        d['gap_valid'] = False
        d['gap_status'] = 3

    loop.run(9, bad)
    assert int(c.state) == 4
    loop.run(2, bad)
    assert int(c.state) == 5 and 'invalid' in c.fault_reason


def test_drive_fault_commands_zero_at_once(following_ladrc):
    loop = following_ladrc
    c = loop.c

    def fault(i, d):
        d['drive_fault'] = True

    loop.run(1, fault)
    assert int(c.state) == 5 and 'drive fault' in c.fault_reason
    assert loop.u[-1] == 0.0 and not c.enable
    ok, msg = c.command('reset_fault')
    assert not ok and 'drive' in msg
    loop.run(1)
    ok, msg = c.command('reset_fault')
    assert ok, msg
    loop.run(1)
    assert int(c.state) == 0


def test_locking_waits_for_enabled_drive_then_times_out():
    c = FollowController(ControllerParams())
    loop = Loop(c, gap0_mm=3.0)
    c.command('start_follow', target_gap_mm=1.0)

    def disabled(i, d):
        d['drive_enabled'] = False

    loop.run(100, disabled)
    assert int(c.state) == 1 and not c.enable and set(loop.u) == {0.0}
    loop.run(2000, disabled)
    assert int(c.state) == 5
    assert 'not enabled' in c.fault_reason and 'LOCKING' in c.fault_reason


def test_not_followed_alarm_after_widened_tolerance():
    # a sensor gain that oscillates faster than the loop can follow: never within tolerance
    # (the edge verification off: it would fault first, unable to tell the 40 Hz wobble from
    # an edge, "could not be verified before closing in")
    c = FollowController(ControllerParams(follow=FollowParams(followed_widen_s=0.3,
                                                               followed_timeout_s=0.5,
                                                               followed_wide_tol_mm=0.06),
                                          edge=EdgeParams(verify_sink=0.0, verify_start_mm=0.0)))
    loop = Loop(c, gap0_mm=1.0)
    c.command('start_follow', target_gap_mm=1.0)

    def wobble(i, d):
        d['gap_mm'] += 0.3 * math.sin(2 * math.pi * 40.0 * i * H)

    loop.run(1200, wobble)
    assert int(c.state) == 5 and 'not followed within 0.5 s' in c.fault_reason
    fault_tick = loop.states.index(5)
    assert abs(fault_tick * H - 0.5) < 0.01


# ---------------------------------------------------------------------------- commands

def test_small_target_change_stays_in_ladrc_large_reinterpolates():
    res, rec = run_scenario(
        FollowController(ControllerParams()), 3.0,
        [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0},
         {'t_s': 0.8, 'do': 'set_target', 'target_gap_mm': 1.5},
         {'t_s': 1.8, 'do': 'set_target', 'target_gap_mm': 4.5}], initial_gap_mm=1.0)
    tr = transitions(rec.states)
    k_small, k_large = round(0.8 / H), round(1.8 / H)
    st = np.asarray(rec.states)
    assert (st[k_small - 10:k_large] == 4).all()  # 0.5 mm <= 1 mm threshold: TD/LADRC
    assert abs(res.true_gap_mm[k_large - 200:k_large].mean() - 1.5) < 0.01
    after = [s for k, s in tr if k >= k_large]
    assert after == [2, 3, 4] and tr[[k for k, _ in tr].index(k_large)] == (k_large, 2)
    assert abs(res.true_gap_mm[-200:].mean() - 4.5) < 0.01
    assert np.abs(np.diff(res.command_mm_s)).max() <= DU_MAX + 1e-9


def test_gradient_follow_moves_after_its_delay_at_its_speed():
    v_g = 20.0
    res, rec = run_scenario(
        FollowController(ControllerParams()), 2.0,
        [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 3.0},
         {'t_s': 0.5, 'do': 'gradient_follow', 'target_gap_mm': 1.0, 'delay_s': 0.3}],
        initial_gap_mm=3.0)
    k_start = round(0.8 / H)
    st = np.asarray(rec.states)
    assert (st[round(0.5 / H):k_start] == 4).all()  # waiting out the delay in LADRC
    assert st[k_start] == 2
    assert abs(res.true_gap_mm[-200:].mean() - 1.0) < 0.01
    # with an explicit speed, the move is bounded by it until followed
    c = FollowController(ControllerParams())
    loop = Loop(c, gap0_mm=3.0)
    c.command('start_follow', target_gap_mm=3.0)
    loop.run_until(lambda: int(c.state) == 4, 4000)
    ok, msg = c.command('gradient_follow', target_gap_mm=1.0, delay_s=0.1, velocity_mm_s=v_g,
                        accel_mm_s2=500.0)
    assert ok, msg
    k0 = loop.i
    loop.run(round(0.1 / H))
    assert int(c.state) == 4
    loop.run(1)
    assert int(c.state) == 2
    loop.run_until(lambda: c.followed, 4000)
    # from the gradient's start (before it, the level reached at start_follow is verified by
    # the edge guard's move up, at the controller's own limits)
    moving = np.asarray(loop.u[k0 + round(0.1 / H):])
    assert np.abs(moving).max() <= v_g + 1e-9
    assert np.abs(np.diff(moving)).max() <= 500.0 * H + 1e-9
    loop.run(400)
    assert abs(loop.gap[-1] - 1.0) < 0.01


def test_height_compensation_applies_after_its_delay(following_ladrc):
    loop = following_ladrc
    c = loop.c
    ok, msg = c.command('height_compensation', offset_mm=0.3, delay_s=0.05)
    assert ok, msg
    k0 = loop.i
    n_delay = round(0.05 / H)
    targets = []
    for _ in range(n_delay + 2):
        loop.run(1)
        targets.append(c.target_gap_mm)
    # the command acts from tick k0 on; the offset is due n_delay ticks later
    assert targets[n_delay - 1] == 1.0 and targets[n_delay] == 1.3
    loop.run(1000)
    assert int(c.state) == 4 and abs(loop.gap[-1] - 1.3) < 0.01
    assert loop.i > k0


def test_height_compensation_rejected_outside_pid_or_ladrc():
    c = FollowController(ControllerParams())
    ok, msg = c.command('height_compensation', offset_mm=0.2)
    assert not ok and 'PID or LADRC' in msg
    c.command('start_follow', target_gap_mm=1.0)
    ok, msg = c.command('height_compensation', offset_mm=0.2)
    assert not ok and 'LOCKING' in msg


def test_stop_follow_goes_idle_and_zero(following_ladrc):
    loop = following_ladrc
    c = loop.c

    def push(i, d):
        d['gap_mm'] -= 0.5  # make the command clearly non-zero (upward) first

    loop.run(20, push)
    assert loop.u[-1] > 1.0
    assert c.command('stop_follow')[0]
    loop.run(1)
    assert int(c.state) == 0 and math.isnan(c.target_gap_mm)
    loop.run(100)
    assert _ramped_to_zero(loop.u[-101:]) and not c.enable


def test_commands_with_bad_values_are_rejected_with_reasons():
    c = FollowController(ControllerParams())
    for name, kw, word in (('start_follow', {'target_gap_mm': math.nan}, 'finite'),
                           ('start_follow', {'target_gap_mm': 0.1}, 'outside'),
                           ('start_follow', {}, 'missing'),
                           ('set_target', {'target_gap_mm': 1.0}, 'not following'),
                           ('machining', {'on': 'yes'}, 'true or false'),
                           ('reset_fault', {}, 'no fault'),
                           ('fly', {}, 'unknown command'),
                           ('stop_follow', {'now': True}, 'unknown argument')):
        ok, msg = c.command(name, **kw)
        assert not ok and word in msg, (name, msg)
    assert int(c.state) == 0


# ---------------------------------------------------------------------------- determinism

def test_same_inputs_and_commands_give_bit_identical_commands():
    timeline = [{'t_s': 0.0, 'do': 'start_follow', 'target_gap_mm': 1.0},
                {'t_s': 0.4, 'do': 'machining', 'on': True},
                {'t_s': 0.6, 'do': 'set_target', 'target_gap_mm': 1.4},
                {'t_s': 0.7, 'do': 'machining', 'on': False},
                {'t_s': 0.9, 'do': 'height_compensation', 'offset_mm': 0.2},
                {'t_s': 1.1, 'do': 'gradient_follow', 'target_gap_mm': 3.0, 'delay_s': 0.1}]
    sheet = {'profiles': [{'kind': 'waviness', 'rms_mm': 0.2, 'cutoff_hz': 3.0}]}
    a, ra = run_scenario(FollowController(ControllerParams()), 1.6, timeline,
                         initial_gap_mm=2.0, sheet=sheet)
    b, rb = run_scenario(FollowController(ControllerParams()), 1.6, timeline,
                         initial_gap_mm=2.0, sheet=sheet)
    assert a.command_mm_s.tobytes() == b.command_mm_s.tobytes()
    assert ra.states == rb.states
    assert {3, 4, 2} <= set(ra.states)  # the run exercised the hand-overs


# ---------------------------------------------------------------------------- interface

def _msg_fields(path: Path) -> set[str]:
    names = set()
    for line in path.read_text().splitlines():
        line = line.split('#', 1)[0].strip()
        if not line or '=' in line:
            continue
        names.add(line.split()[1])
    return names


def test_internals_keys_are_follow_status_fields(following_ladrc):
    c = following_ladrc.c
    fields_ = _msg_fields(FOLLOW_STATUS_MSG)
    for _ in range(3):
        d = c.internals()
        assert tuple(d) == INTERNALS_KEYS + ANSWER_KEYS and set(d) <= fields_
        assert isinstance(d['state'], int) and isinstance(d['limit_flags'], int)
        assert isinstance(d['followed'], bool) and isinstance(d['fault_reason'], str)
        assert d['velocity_mm_s'] == c.velocity_mm_s
        following_ladrc.run(1)
    assert d['state'] == 4 and d['eso_z1_mm'] != 0.0


def test_internals_in_pid_state_show_the_reinitialised_ladrc():
    c = FollowController(ControllerParams())
    loop = Loop(c, gap0_mm=1.3)
    c.command('start_follow', target_gap_mm=1.0)
    loop.run_until(lambda: int(c.state) == 3, 2000)
    loop.run(3)
    d = c.internals()
    b0 = ControllerParams().eso.b0
    # InitLADRC(height, height, pidOut): TD and ESO at the reading, z2 = -b0·u (at rest)
    assert d['td_x1_mm'] == d['eso_z1_mm'] == loop.gap[-1]
    assert d['td_x2_mm_s'] == 0.0 and d['eso_z2'] == -b0 * loop.u[-1]


def test_follow_params_validation_messages():
    with pytest.raises(ValueError, match='controller'):
        params_from_dict({'follow': {'controller': 'fuzzy'}})
    with pytest.raises(ValueError, match="unknown key 'follow.speed'"):
        params_from_dict({'follow': {'speed': 1.0}})
    with pytest.raises(ValueError, match='collision_gap_mm'):
        params_from_dict({'follow': {'collision_gap_mm': 0.5}})
    assert 'stale_timeout_s' in ' '.join(FollowParams(stale_timeout_s=-1.0).problems())
    # whole-set checks (the follow section against the PID's tolerance)
    bad = ControllerParams(follow=FollowParams(followed_wide_tol_mm=0.01))
    assert 'followed_wide_tol_mm' in ' '.join(validate(bad))
    with pytest.raises(ValueError, match='followed_wide_tol_mm'):
        FollowController(bad)
    check(ControllerParams())
    with pytest.raises(ValueError, match='followed_wide_tol_mm'):
        check(bad)  # the set's own validation sees the follow section too
    with pytest.raises(ValueError, match='follow'):
        FollowController(ControllerParams(follow=FollowParams(controller=1)))


def test_set_params_takes_effect_at_next_tick_bumplessly(following_ladrc):
    loop = following_ladrc
    c = loop.c
    c.set_params(ControllerParams(follow=FollowParams(controller='pid')))
    assert int(c.state) == 4
    loop.run(1)
    assert int(c.state) == 3
    loop.run(400)
    assert np.abs(np.diff(loop.u)).max() <= DU_MAX + 1e-9
    assert abs(loop.gap[-1] - 1.0) < 0.02 and 4 not in loop.states[-400:]
    with pytest.raises(ValueError):
        c.set_params(ControllerParams(edge=EdgeParams(drop_mm=-1.0)))


def test_mode_overrides_the_configured_controller():
    c = FollowController(ControllerParams(), mode='pid')
    assert c.follow_params.controller == 'pid'
    with pytest.raises(ValueError, match='controller'):
        FollowController(ControllerParams(), mode='fuzzy')
