"""Fault injection on the control core, headless: the fast subset of the safety issue's matrix.

Each test drives the FollowController in closed loop with the axis model and corrupts its
inputs the way a faulty sensor, driver or bug would; the nozzle must never reach the sheet and
no command toward the sheet may follow a fault.
"""

from __future__ import annotations

import math

from ladrc_follow.control.follow import FollowController
from ladrc_follow.control.params import ControllerParams
from loops import Loop
import pytest

FAULT, LADRC = 5, 4


@pytest.fixture
def loop():
    """Return a loop following at 1.5 mm with the LADRC (started at 2.5 mm)."""
    c = FollowController(ControllerParams())
    lp = Loop(c, gap0_mm=2.5)
    assert c.command('start_follow', target_gap_mm=1.5)[0]
    lp.run_until(lambda: int(c.state) == LADRC, 6000)
    lp.run(200)
    return lp


def first_fault(lp: Loop, start: int) -> int:
    return next(i for i in range(start, len(lp.states)) if lp.states[i] == FAULT)


def test_frozen_reading_with_fresh_stamps_faults_before_contact(loop):
    """The issue's fault 1: the value freezes above the target, the stamps stay fresh."""
    c, start = loop.c, len(loop.u)
    frozen = loop.gap[-1] + 0.089   # reads 0.09 mm too wide: the law drives the nozzle down

    def freeze(i, d):
        d['gap_mm'] = frozen

    loop.run(400, freeze)
    assert int(c.state) == FAULT and 'frozen gap reading' in c.fault_reason
    assert c.counts['frozen'] == 1
    k = first_fault(loop, start)
    assert min(loop.gap[start:]) > 0.7 * 1.5            # no dive toward the sheet
    assert all(u >= 0.0 for u in loop.u[k:])             # nothing downward after the fault


def test_no_new_sample_runs_on_the_encoder_prediction(loop):
    """A sample is never used twice: ticks without a new one run on gap + Δencoder."""
    c = loop.c
    before = c.counts['predicted']
    sheet_t = {}

    def hold_every_other(i, d):
        if i % 2:  # the sensor sends at 1 kHz: every other tick brings no new sample
            d['gap_mm'], d['gap_stamp_s'] = sheet_t['gap'], sheet_t['stamp']
        else:
            sheet_t['gap'], sheet_t['stamp'] = d['gap_mm'], d['gap_stamp_s']

    loop.run(400, hold_every_other)
    assert int(c.state) == LADRC
    assert c.counts['predicted'] - before == 200
    assert abs(loop.gap[-1] - 1.5) < 0.02


def test_a_fault_stops_motion_toward_the_sheet_at_once():
    """An approach from 10 mm at speed; a sensor fault status: no ramp-down toward the sheet."""
    c = FollowController(ControllerParams())
    lp = Loop(c, gap0_mm=10.0)
    c.command('start_follow', target_gap_mm=1.0)
    lp.run_until(lambda: c.velocity_mm_s < -30.0, 4000)
    start = len(lp.u)

    def sensor_fault(i, d):
        d['gap_valid'], d['gap_status'] = False, 3  # STATUS_FAULT

    lp.run(40, sensor_fault)
    assert int(c.state) == FAULT
    assert all(u >= 0.0 for u in lp.u[start:])   # from the first invalid sample on


@pytest.mark.parametrize('bad', [math.nan, math.inf])
def test_non_finite_command_ends_in_fault_and_zero(loop, monkeypatch, bad):
    c = loop.c
    monkeypatch.setattr(c, '_ladrc_step', lambda *a: bad)
    loop.run(3)
    assert loop.u[-3:] == [0.0, 0.0, 0.0]
    assert int(c.state) == FAULT and 'non-finite command' in c.fault_reason
    assert c.counts['nonfinite'] == 1


def test_exception_in_the_tick_ends_in_fault_and_zero(loop, monkeypatch):
    c = loop.c

    def boom(*a):
        raise ZeroDivisionError('injected')

    monkeypatch.setattr(c, '_ladrc_step', boom)
    loop.run(2)
    assert loop.u[-2:] == [0.0, 0.0]
    assert int(c.state) == FAULT and 'ZeroDivisionError: injected' in c.fault_reason


def test_collision_evidence_retracts_in_fault(loop):
    """Already in FAULT (stale input), then the reading shows contact: retract anyway."""
    c = loop.c

    def stale(i, d):
        d['gap_stamp_s'] = d['t_s'] - 1.0

    loop.run(2, stale)
    assert int(c.state) == FAULT and 'stale' in c.fault_reason
    loop.run(20)
    assert loop.u[-1] == 0.0

    def contact(i, d):
        d['gap_mm'], d['gap_valid'], d['gap_status'] = 0.0, False, 2  # STATUS_COLLISION

    loop.run(40, contact)
    assert 'collision while in FAULT' in c.fault_reason
    assert loop.u[-1] > 0.0 and c.enable   # moving up, away from the sheet


def test_invalid_samples_interleaved_with_valid_ones_still_fault(loop):
    """Every other sample invalid: no single run is long, the share is; and it is counted."""
    c = loop.c

    def every_other(i, d):
        if i % 2:
            d['gap_valid'], d['gap_status'], d['gap_mm'] = False, 3, float('nan')

    loop.run(200, every_other)
    assert int(c.state) == FAULT and 'invalid too often' in c.fault_reason
    assert c.counts['invalid'] > 10


def test_a_reading_that_jumps_wider_is_not_followed_down(loop):
    """One sample 1 mm too wide: rejected, counted, no command toward the sheet from it."""
    c = loop.c
    u_before = loop.u[-1]

    def spike(i, d):
        if i == loop.i:  # the first tick of this run only
            d['gap_mm'] += 1.0

    start = len(loop.u)
    loop.run(1, spike)
    assert c.counts['jump'] == 1 and int(c.state) == LADRC
    assert loop.u[start] == max(u_before, 0.0)
    loop.run(50)
    assert int(c.state) == LADRC and abs(loop.gap[-1] - 1.5) < 0.02


def test_a_persistent_step_of_the_sheet_is_taken_after_confirmation():
    """The sheet really drops 1 mm: held for jump_confirm_s, then followed down."""
    c = FollowController(ControllerParams())
    lp = Loop(c, gap0_mm=2.5, sheet=lambda t: -1.0 if t >= 4.0 else 0.0)
    c.command('start_follow', target_gap_mm=1.5)
    lp.run_until(lambda: int(c.state) == LADRC, 6000)
    lp.run_until(lambda: lp.i * 0.0005 >= 4.0, 8000)
    k = len(lp.u)
    lp.run(4000)
    assert c.counts['jump'] >= 1 and int(c.state) == LADRC
    assert all(u >= 0.0 for u in lp.u[k:k + 19])      # held 10 ms (20 ticks)
    assert abs(lp.gap[-1] - 1.5) < 0.02               # then followed to the new level


def test_commands_that_could_hang_or_overflow_the_tick_are_refused(loop):
    c = loop.c
    for kwargs in ({'accel_mm_s2': 1e-40, 'velocity_mm_s': 10.0},
                   {'accel_mm_s2': 1000.0, 'velocity_mm_s': 1e-9},
                   {'delay_s': math.inf}, {'delay_s': 1e308}):
        ok, msg = c.command('gradient_follow', target_gap_mm=2.0, **kwargs)
        assert not ok and 'gradient_follow' in msg, kwargs
    ok, msg = c.command('height_compensation', offset_mm=0.1, delay_s=1e308)
    assert not ok and 'delay_s' in msg
    loop.run(10)
    assert int(c.state) == LADRC


def test_a_sensor_stuck_low_in_fault_retracts_once_not_forever(loop):
    c = loop.c
    loop.run(2, lambda i, d: d.update(gap_stamp_s=d['t_s'] - 1.0))   # stale: FAULT
    assert int(c.state) == FAULT
    z0 = loop.axis.position_mm

    def stuck_low(i, d):
        d['gap_mm'] = 0.1  # valid, at the collision limit, forever

    loop.run(6000, stuck_low)
    assert 'collision while in FAULT' in c.fault_reason
    assert len(c.fault_reason) < 300                     # reasons do not nest
    travel = loop.axis.position_mm - z0
    assert 1.9 < travel < 2.2                             # one retract of 2 mm, then still

    def stuck_invalid(i, d):
        d['gap_mm'], d['gap_valid'], d['gap_status'] = 0.0, False, 3  # sensor fault

    c2 = FollowController(ControllerParams())
    lp = Loop(c2, gap0_mm=1.5)
    lp.run(2, lambda i, d: d.update(gap_stamp_s=d['t_s'] - 1.0))
    c2.command('start_follow', target_gap_mm=1.0)
    lp.run(3000, stuck_invalid)
    assert 'collision' not in c2.fault_reason   # an invalid 0 is no evidence of contact


def test_stop_follow_during_a_fast_approach_stops_moving_down_at_once():
    c = FollowController(ControllerParams())
    lp = Loop(c, gap0_mm=10.0)
    c.command('start_follow', target_gap_mm=1.0)
    lp.run_until(lambda: c.velocity_mm_s < -30.0, 4000)
    c.command('stop_follow')
    k = len(lp.u)
    lp.run(40)
    assert all(u >= 0.0 for u in lp.u[k:]) and int(c.state) == 0


def test_jump_hold_also_covers_ticks_without_a_new_sample(loop):
    """Sensor at 1 kHz, one reading 1 mm too wide: no tick of the hold moves down."""
    c = loop.c
    held = {}
    start = loop.i

    def glitch_1khz(i, d):
        if (i - start) % 2:
            d['gap_mm'], d['gap_stamp_s'] = held['gap'], held['stamp']
        else:
            if i == start + 4:
                d['gap_mm'] += 1.0
            held['gap'], held['stamp'] = d['gap_mm'], d['gap_stamp_s']

    k = len(loop.u)
    loop.run(12, glitch_1khz)
    assert c.counts['jump'] == 1 and c.counts['predicted'] >= 6
    # the glitched sample's tick and the following tick without a new sample both hold; the
    # next (good) sample ends the hold and the law resumes (its command may be downward)
    assert loop.u[k + 3] < 0.0 and loop.u[k + 4] == 0.0 and loop.u[k + 5] == 0.0
